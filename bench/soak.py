"""Soak run: 16 servos, 50 Hz mirroring, 10 Hz telemetry, faults injected, memory watched.

The whole Bridge runs on its simulated autopilot and adapter (``bench_faults.bridge_config``:
16 RMD-X servos, SERVO_OUTPUT_RAW at 50 Hz, each servo polled at 10 Hz, 20 ms command period).
The run alternates windows of ``--window-s`` seconds: clean, line corruption (bit flips at
1e-3 per byte both ways), clean, a USB unplug of 1 s, clean, one servo silent. Every window
records the deltas of the counters that matter; clean windows are where "no frame loss" and
"no missed command slots" are judged. Resident memory (VmRSS) and Python heap (tracemalloc,
optional) are sampled at every window boundary: "memory flat" means the last third of the run
does not grow beyond the noise of the first third.

    python bench/soak.py --minutes 30 > soak.json
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
import tracemalloc
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_faults import Recorder, bridge_config  # noqa: E402

from mavservo.bridge import Bridge  # noqa: E402
from mavservo.config.loader import load_config_text  # noqa: E402
from mavservo.sim.adapter import LineCorrupter, LineFaults  # noqa: E402

PHASES = ("clean", "line_1e-3", "clean", "unplug", "clean", "servo_silent")


def rss_kib() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


def counters(bridge: Bridge, recorder: Recorder) -> dict[str, int]:
    summary = bridge.summary()
    bus = summary["buses"]["bus0"]
    frames = [s["frames"] for s in summary["servos"].values()]
    return {
        "missed_command_slots": int(bus["missed_command_slots"]),
        "sent": sum(f["sent"] for f in frames),
        "received": sum(f["received"] for f in frames),
        "lost": sum(f["lost"] for f in frames),
        "late": sum(f["late_replies"] for f in frames),
        "rejected_bytes": int(bus["transport"].get("bytes_discarded", 0)),
        "commands_arrived": recorder.arrived,
        "wrong_commands": recorder.wrong_count,
    }


def delta(after: dict[str, int], before: dict[str, int]) -> dict[str, int]:
    return {k: after[k] - before[k] for k in after}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=30.0)
    parser.add_argument("--window-s", type=float, default=20.0)
    parser.add_argument("--servos", type=int, default=16)
    parser.add_argument("--tracemalloc", action="store_true", help="also sample the Python heap")
    args = parser.parse_args()
    if args.tracemalloc:
        tracemalloc.start()
    bridge = Bridge(load_config_text(bridge_config(args.servos, "variable")), log_dir=False)
    bridge.start()
    recorder = Recorder(bridge)
    emulator = bridge.emulators["bus0"]
    clean_line = emulator.line
    started = time.monotonic()
    end = started + args.minutes * 60
    windows: list[dict[str, Any]] = []
    memory: list[tuple[float, int, int]] = []
    index = 0
    baseline: tracemalloc.Snapshot | None = None
    try:
        time.sleep(2.0)  # servos come online
        while time.monotonic() + args.window_s <= end:
            phase = PHASES[index % len(PHASES)]
            before = counters(bridge, recorder)
            t0 = time.monotonic()
            if phase == "line_1e-3":
                emulator.line = LineCorrupter(LineFaults(flip_prob=1e-3, direction="both"),
                                              seed=index)
            elif phase == "unplug":
                emulator.unplug()
                time.sleep(1.0)
                emulator.replug()
            elif phase == "servo_silent":
                emulator.servos[1].faults.silent = True
            time.sleep(max(0.0, args.window_s - (time.monotonic() - t0)))
            emulator.line = clean_line
            emulator.servos[1].faults.silent = False
            windows.append({"phase": phase, "t_s": round(t0 - started, 1),
                            **delta(counters(bridge, recorder), before)})
            heap = tracemalloc.get_traced_memory()[0] if args.tracemalloc else 0
            memory.append((round(time.monotonic() - started, 1), rss_kib(), heap))
            if args.tracemalloc and index == len(PHASES) - 1:
                baseline = tracemalloc.take_snapshot()  # after one full cycle of phases
            index += 1
        growth = []
        if baseline is not None:
            diff = tracemalloc.take_snapshot().compare_to(baseline, "lineno")
            growth = [str(stat) for stat in diff[:8]]
    finally:
        summary = bridge.stop()
    clean = [w for w in windows if w["phase"] == "clean"]
    third = max(1, len(memory) // 3)
    out = {
        "machine": f"{platform.machine()} python {platform.python_version()}",
        "minutes_requested": args.minutes,
        "seconds_run": round(time.monotonic() - started, 1),
        "servos": args.servos,
        "windows": windows,
        "memory_samples": memory,
        "rss_kib_first_third_max": max(m[1] for m in memory[:third]) if memory else None,
        "rss_kib_last_third_max": max(m[1] for m in memory[-third:]) if memory else None,
        "clean_windows": {
            "count": len(clean),
            "lost": sum(w["lost"] for w in clean),
            "late": sum(w["late"] for w in clean),
            "missed_command_slots": sum(w["missed_command_slots"] for w in clean),
            "frames_sent": sum(w["sent"] for w in clean),
        },
        "wrong_commands_total": recorder.wrong_count,
        "missed_command_slots_total": summary["buses"]["bus0"]["missed_command_slots"],
        "heap_growth_top": growth,
        "events": summary.get("events", []),
    }
    print(json.dumps(out, indent=1, default=str))


if __name__ == "__main__":
    main()
