"""What ``logging.can_frames: all`` costs against ``servos`` on a busy bus.

The whole bridge runs on the simulated AA-55 adapter with two RMD-X servos while a foreign node
puts ``--rate`` frames/s (default 2,500: a shared bus at 2,000-3,000 frames/s) of its own on
the bus; each run lasts ``--seconds``. Measured per mode, in the same command (A/B interleaved,
``--runs`` each, medians): the process CPU time per second of run (the simulator's own work is
the same in both modes, so the difference is the logging), the frames in can.asc, the events
the run log dropped, and the scheduler's missed command slots and lost replies.

    PYTHONPATH=. python bench/bench_log_every_frame.py --runs 5 --seconds 6
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import can

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from mavservo.app.bridge import Bridge, free_udp_port  # noqa: E402
from mavservo.config import load_config_text  # noqa: E402
from mavservo.records.runlog import read_can_log  # noqa: E402
from mavservo.sim.canbus import FOREIGN  # noqa: E402

FOREIGN_FRAMES = [
    can.Message(arbitration_id=0x300 + k, data=bytes([k] * 8), is_extended_id=False)
    for k in range(10)
]


def one_run(mode: str, rate: float, seconds: float) -> dict[str, float]:
    config = load_config_text(
        f"mavlink: {{url: 'udpin:127.0.0.1:{free_udp_port()}'}}\n"
        "servos:\n  - {name: a, profile: rmd-x, can_id: 1}\n  - {name: b, profile: rmd-x, "
        f"can_id: 2}}\nlogging: {{can_frames: {mode}, can_formats: [asc, blf]}}\n",
        "<bench>",
    )
    with tempfile.TemporaryDirectory() as tmp:
        bridge = Bridge(config, log_dir=tmp)
        bridge.start()
        emulator = bridge.emulators["bus0"]
        period = 0.01
        cpu0, t0 = time.process_time(), time.monotonic()
        next_t = t0
        sent = 0
        while time.monotonic() - t0 < seconds:
            due = int(rate * (time.monotonic() - t0)) - sent  # the frames owed by now
            with emulator._lock:
                now = emulator.clock()
                for k in range(max(0, due)):
                    emulator.canbus.submit(FOREIGN_FRAMES[k % len(FOREIGN_FRAMES)], now, FOREIGN)
                sent += max(0, due)
            next_t += period
            time.sleep(max(0.0, next_t - time.monotonic()))
        cpu = time.process_time() - cpu0
        wall = time.monotonic() - t0
        summary = bridge.stop()
        assert bridge.run_dir is not None and bridge.runlog is not None
        frames = len(read_can_log(bridge.run_dir, "asc"))
        counters = bridge.runlog.counters()
        bus = summary["buses"]["bus0"]
        lost = sum(s["frames"]["lost"] for s in summary["servos"].values())
    return {
        "cpu_per_s": cpu / wall,
        "foreign_per_s": sent / wall,
        "asc_frames": frames,
        "dropped": counters["dropped_total"],
        "missed_slots": bus.get("missed_command_slots", 0),
        "lost": lost,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--seconds", type=float, default=6.0)
    parser.add_argument("--rate", type=float, default=2500.0)
    args = parser.parse_args()
    runs: dict[str, list[dict[str, float]]] = {"servos": [], "all": []}
    for _ in range(args.runs):
        for mode in ("servos", "all"):  # interleaved: machine load hits both alike
            runs[mode].append(one_run(mode, args.rate, args.seconds))
    medians = {
        mode: {key: statistics.median(r[key] for r in rs) for key in rs[0]}
        for mode, rs in runs.items()
    }
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=False
    ).stdout.strip()
    print(
        json.dumps(
            {
                "bench": "run log can_frames all vs servos, busy bus",
                "machine": f"{platform.machine()} {os.cpu_count()} CPUs, "
                f"Python {platform.python_version()}",
                "commit": commit,
                "runs": args.runs,
                "seconds": args.seconds,
                "medians": medians,
                "cpu_ratio_all_over_servos": medians["all"]["cpu_per_s"]
                / medians["servos"]["cpu_per_s"],
                "extra_cpu_per_1000_frames_ms": 1000
                * (medians["all"]["cpu_per_s"] - medians["servos"]["cpu_per_s"])
                / medians["all"]["foreign_per_s"]
                * 1000,
                "all_runs": runs,
            },
            indent=2,
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
