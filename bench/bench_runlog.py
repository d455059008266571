"""What a RunLog costs the scheduler thread that calls it, and how fast its writer drains.

Run by hand: ``PYTHONPATH=. python bench/bench_runlog.py [--runs R]``.

* paced: command/reply pairs (``on_setpoint`` + ``on_tx`` + ``on_rx``, latency tracing included)
  at a bridge-like rate (``--rate`` pairs/s) for ``--seconds``; per-pair cost seen by the caller
  (p50, p99, max) against a no-op observer, with a normal and with a slow writer (1 ms/event,
  a slow SD card: the caller's cost must not grow, the excess must show up as drops);
* drain: events/s the writer thread turns into files (ASC + BLF + CSV), i.e. the sustained
  frame rate it can log without dropping.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from types import SimpleNamespace

import can

from mavservo.records.runlog import RunLog

CMD = can.Message(
    arbitration_id=0x141, is_extended_id=False, data=b"\xa4\x00\x68\x01\x10\x27\x00\x00"
)
REPLY = can.Message(
    arbitration_id=0x241, is_extended_id=False, data=b"\xa4\x1e\x10\x00\x00\x00\x0a\x00"
)
STATE = SimpleNamespace(
    position_deg=1.0, velocity_dps=0.0, current_a=0.1, temperature_c=30.0, faults=None
)


class NoOp:
    def on_setpoint(self, *a): ...
    def on_tx(self, *a): ...
    def on_rx(self, *a): ...


def pair(observer, seq: int, t: float) -> None:
    observer.on_setpoint("s1", seq, 1.0, "bench", t)
    observer.on_tx("bus0", CMD, t, "command", "s1", seq)
    observer.on_rx("bus0", REPLY, t, "s1", STATE)


def paced(observer, rate: float, seconds: float) -> list[float]:
    """Per-pair cost (s) seen by the caller, calls spaced on absolute deadlines."""
    costs = []
    period = 1.0 / rate
    next_due = time.monotonic()
    for seq in range(int(rate * seconds)):
        next_due += period
        start = time.perf_counter()
        pair(observer, seq, time.monotonic())
        costs.append(time.perf_counter() - start)
        delay = next_due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    return costs


def slowed(log: RunLog) -> RunLog:
    files = log._files  # the writer thread's side: one event at a time
    original = files.write

    def slow_write(item, _original=original):
        time.sleep(0.001)
        _original(item)

    files.write = slow_write
    return log


def drain_rate(events: int = 40_000) -> float:
    """Events per second the writer turns into files, from a pre-filled queue."""
    with tempfile.TemporaryDirectory() as tmp:
        log = RunLog(tmp, queue_size=events + 10, autostart=False)
        t = time.monotonic()
        for seq in range(events // 4):
            pair(log, seq, t)
        start = time.perf_counter()
        log.close()
        return log.counters()["written"].get("can", 0) / (time.perf_counter() - start)


def q(values: list[float], pct: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(pct / 100 * len(ordered)))]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--rate", type=float, default=500.0, help="command/reply pairs per s")
    parser.add_argument("--seconds", type=float, default=2.0)
    args = parser.parse_args()
    rows = {"no-op observer": [], "RunLog": [], "RunLog, slow writer": []}
    drops = []
    for _ in range(args.runs):
        rows["no-op observer"].append(paced(NoOp(), args.rate, args.seconds))
        for label, make in (
            ("RunLog", lambda d: RunLog(d)),
            ("RunLog, slow writer", lambda d: slowed(RunLog(d, queue_size=500))),
        ):
            with tempfile.TemporaryDirectory() as tmp:
                log = make(tmp)
                rows[label].append(paced(log, args.rate, args.seconds))
                if label.endswith("slow writer"):
                    drops.append(sum(log.dropped.values()))
                log.close()
    base = statistics.median(q(c, 50) for c in rows["no-op observer"])
    for label, runs in rows.items():
        p50 = statistics.median(q(c, 50) for c in runs)
        p99 = statistics.median(q(c, 99) for c in runs)
        worst = statistics.median(max(c) for c in runs)
        print(
            f"{label:22s} per pair p50 {p50 * 1e6:7.1f} us  p99 {p99 * 1e6:7.1f} us  "
            f"max {worst * 1e6:8.1f} us  (p50 ratio {p50 / base:5.1f}x)"
        )
    print(
        f"slow writer: dropped events median {statistics.median(drops):.0f} "
        f"of {int(4 * args.rate * args.seconds)} per run"
    )
    rates = [drain_rate() for _ in range(args.runs)]
    print(
        f"writer drain: median {statistics.median(rates):.0f} CAN frames/s "
        f"(ASC + BLF + trace + latency CSV)"
    )


if __name__ == "__main__":
    main()
