"""A DO_SET_SERVO flood over real UDP against the whole bridge (finding 10), run by hand.

    PYTHONPATH=. python bench/bench_command_flood.py --rate 5000 --seconds 10 --runs 3
    PYTHONPATH=. python bench/bench_command_flood.py --lookup   # handler alone, table filled
    cd /tmp && PYTHONPATH=/path/to/old/checkout python /path/to/bench/bench_command_flood.py ...

The bridge (in this process: the MAVLink thread, the scheduler's two threads and the in-process
AA-55 adapter emulator with one simulated RMD-X servo, ``channel: sim``) listens on a udpin
port; a flooder in a child process (its own interpreter, so it does not share the bridge's GIL)
sends COMMAND_LONG DO_SET_SERVO on the one mapped channel at ``--rate`` per second, every
command a different PWM (so none is a retry), paced in 5 ms batches, plus an autopilot
heartbeat every second. The same runs without the flood (heartbeats only) come first, as the
baseline of the same session. Reports per run, and the median over runs:

* ``handled_per_s``: commands the bridge decided (ACK results and retries counted by the
  command handler) per second of flood;
* ``command_period_sigma_ms`` / ``longest_bus_gap_ms``: sigma and maximum of the intervals
  between the scheduler's command-slot writes during the flood (the first frame of each slot
  on the bus, 50 ms nominal), i.e. how long the bus went without a command;
* ``missed_command_slots`` and, where the bridge has them, ``late_command_slots`` and the
  command lateness max (slot due -> written, or -> wake-up on code that times it there).

It runs against whatever ``mavservo`` is importable: for a before/after comparison, run it
with ``PYTHONPATH`` pointing at a checkout of the old commit and at this one, in the same
session. Not a test: no thresholds, just figures.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("MAVLINK20", "1")

BATCH_S = 0.005


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def flood(port: int, rate: float, seconds: float) -> None:
    """The flooder (child process): DO_SET_SERVO at ``rate``/s for ``seconds``, all distinct."""
    from pymavlink import mavutil

    gcs = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{port}", source_system=255, source_component=190
    )
    autopilot = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{port}", source_system=1, source_component=1
    )
    start = time.monotonic()
    sent = 0
    next_beat = start
    while (now := time.monotonic()) < start + seconds:
        if now >= next_beat:
            autopilot.mav.heartbeat_send(1, 3, 0, 0, 4)
            next_beat += 1.0
        due = int((now - start) * rate)
        while sent < due:
            pwm = 1100 + (sent % 8000) * 0.1  # distinct within any retry horizon
            gcs.mav.command_long_send(1, 140, 183, 0, 1, pwm, 0, 0, 0, 0, 0)
            sent += 1
        time.sleep(BATCH_S)
    print(json.dumps({"sent": sent, "seconds": time.monotonic() - start}))


def config_text(port: int) -> str:
    return f"""
mavlink: {{url: "udpin:127.0.0.1:{port}", system_id: 1, heartbeat_timeout_s: 30}}
can:
  buses: [{{name: bus0, interface: aa55, channel: sim}}]
servos:
  - {{name: s1, profile: rmd-x, can_id: 1, limits_deg: [-30, 30],
     failsafe: {{action: hold, timeout_s: 30}}}}
channels:
  - {{servo: s1, source: servo_output, channel: 1, input: {{min: 1000, max: 2000}},
     output_deg: [-30, 30]}}
"""


def udp_drops(port: int) -> int | None:
    """Datagrams the kernel dropped at the bridge's socket (its receive buffer was full):
    commands that never reached the bridge, so never got an ACK. None off Linux."""
    try:
        lines = Path("/proc/net/udp").read_text().splitlines()[1:]
    except OSError:
        return None
    for line in lines:
        fields = line.split()
        if int(fields[1].split(":")[1], 16) == port:
            return int(fields[-1])
    return None


def decided(stats: dict[str, Any]) -> int:
    counters = stats.get("commands", {})
    return sum(v for k, v in counters.items() if k.startswith("result_")) + counters.get(
        "retry_not_reapplied", 0
    )


def run_once(rate: float, seconds: float) -> dict[str, Any]:
    from mavservo.app.bridge import Bridge
    from mavservo.config.loader import load_config_text

    port = free_udp_port()
    bridge = Bridge(load_config_text(config_text(port)), log_dir=False).start()
    try:
        scheduler = bridge.schedulers["bus0"]
        time.sleep(1.0)  # servo online, slots running
        store = scheduler.metrics_store
        ticks = store.command_ticks.intervals
        first_tick = ticks.count
        missed0 = store.missed_command_slots
        late0 = getattr(store, "late_command_slots", None)
        assert bridge.mavlink is not None
        decided0 = decided(bridge.mavlink.stats())
        child = subprocess.run(
            [sys.executable, __file__, "--flooder", str(port), str(rate), str(seconds)],
            capture_output=True,
            text=True,
            timeout=seconds + 30,
            check=True,
        )
        flooder = json.loads(child.stdout.strip().splitlines()[-1])
        time.sleep(0.5)  # the last datagrams decided
        handled = decided(bridge.mavlink.stats()) - decided0
        metrics = scheduler.metrics()
        during = list(ticks.recent)[-(ticks.count - first_tick) :]
        drops = udp_drops(port)
    finally:
        bridge.stop()
    late = getattr(store, "late_command_slots", None)
    return {
        "sent": flooder["sent"],
        "sent_per_s": flooder["sent"] / flooder["seconds"],
        "handled_per_s": handled / flooder["seconds"],
        "udp_dropped": drops,
        "command_period_sigma_ms": statistics.pstdev(during) * 1e3,
        "longest_bus_gap_ms": max(during) * 1e3,
        "slots": len(during),
        "missed_command_slots": store.missed_command_slots - missed0,
        "late_command_slots": None if late is None else late - late0,
        "command_lateness_max_ms": metrics["command_lateness_s"]["max"] * 1e3,
    }


def lookup_cost(prior: int, measured: int = 2000) -> float:
    """Microseconds per DO_SET_SERVO through the command handler alone (no I/O, no logging),
    after ``prior`` distinct commands within one retry window: what the retry lookup costs
    when a flood has filled the table."""
    from mavservo.mavlink.commands import Command, CommandHandler
    from mavservo.mavlink.mavlink_core import MavlinkCore
    from mavservo.mavlink.settings import MavlinkSettings

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from tests.support.mavlink_doubles import RecordingBackend

    handler: CommandHandler = MavlinkCore(MavlinkSettings(system_id=1), RecordingBackend()).commands

    def command(k: int) -> Command:
        return Command((255, 190), 1, 140, 183, (1.0, 1000.0 + k * 1e-3, 0, 0, 0, 0, 0))

    for k in range(prior):
        handler.handle(command(k), 1e-6 * k)
    start = time.perf_counter()
    for k in range(prior, prior + measured):
        handler.handle(command(k), 1e-6 * k)
    return (time.perf_counter() - start) / measured * 1e6


def main() -> None:
    if len(sys.argv) == 5 and sys.argv[1] == "--flooder":
        flood(int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4]))
        return
    if len(sys.argv) == 2 and sys.argv[1] == "--lookup":
        logging.basicConfig(level=logging.ERROR)
        costs = {
            n: statistics.median(lookup_cost(n) for _ in range(3)) for n in (0, 10_000, 30_000)
        }
        print(json.dumps({f"us_per_command_after_{n}": round(c, 1) for n, c in costs.items()}))
        return
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rate", type=float, default=5000.0)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    logging.basicConfig(level=logging.ERROR)
    import mavservo

    report: dict[str, Any] = {"mavservo": os.path.dirname(mavservo.__file__)}
    for label, rate in (("no_flood", 0.0), ("flood", args.rate)):  # baseline in the same run
        runs = [run_once(rate, args.seconds) for _ in range(args.runs)]
        keys = [k for k in runs[0] if all(isinstance(r[k], (int, float)) for r in runs)]
        report[label] = {
            "runs": runs,
            "median": {k: statistics.median(r[k] for r in runs) for k in keys},
        }
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
