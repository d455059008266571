"""Latency of the MAVLink side: SERVO_OUTPUT_RAW on the socket -> setpoint call on the backend.

A raw UDP sender plays the autopilot (HEARTBEAT first, then SERVO_OUTPUT_RAW with a new PWM each
time, so every sample is a change that must reach the backend). The time from just before
``sendto`` to the backend's ``apply_servo_output`` is measured with ``time.monotonic_ns``. The lead
extends this to "AA-55 bytes written on the serial port" once the bridge is wired.

    PYTHONPATH=. python bench/bench_mavlink_latency.py --samples 1000 --runs 5
"""

from __future__ import annotations

import argparse
import os
import socket
import statistics
import sys
import time

os.environ.setdefault("MAVLINK20", "1")

from pymavlink.dialects.v20 import ardupilotmega as mavlink2  # noqa: E402

from mavservo.mavlink.backend import ACCEPTED, ServoStatus  # noqa: E402
from mavservo.mavlink.settings import MavlinkSettings  # noqa: E402
from mavservo.mavlink.side import MavlinkSide  # noqa: E402


class TimingBackend:
    """Maps servo output channel 1; records when each PWM arrived."""

    def __init__(self) -> None:
        self.arrivals: dict[int, int] = {}

    def mapped_servo_channels(self) -> set[int]:
        return {1}

    def mapped_actuator_indices(self) -> set[int]:
        return set()

    def apply_servo_output(self, channel, pwm_us, source, now):
        self.arrivals[int(pwm_us)] = time.monotonic_ns()
        return ACCEPTED

    def apply_actuator(self, index, value, source, now):
        return ACCEPTED

    def apply_gimbal(self, *args):
        return ACCEPTED

    def servo_statuses(self) -> list[ServoStatus]:
        return []

    def enter_failsafe(self, reason, now):
        pass

    def leave_failsafe(self, now):
        pass

    def health(self) -> dict[str, float]:
        return {}


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def one_run(samples: int, period_s: float) -> list[float]:
    port = free_port()
    backend = TimingBackend()
    side = MavlinkSide(MavlinkSettings(url=f"udpin:127.0.0.1:{port}", system_id=1), backend)
    side.start()
    encoder = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    target = ("127.0.0.1", port)
    sock.sendto(mavlink2.MAVLink_heartbeat_message(1, 3, 0, 0, 4, 3).pack(encoder), target)
    sent: dict[int, int] = {}
    try:
        time.sleep(0.2)
        for k in range(samples):
            pwm = 1000 + k  # every sample is a new value (samples <= 999 keeps PWM <= 1999)
            buf = mavlink2.MAVLink_servo_output_raw_message(0, 0, pwm, *([0] * 15)).pack(encoder)
            if k % 100 == 0:
                sock.sendto(
                    mavlink2.MAVLink_heartbeat_message(1, 3, 0, 0, 4, 3).pack(encoder), target
                )
            sent[pwm] = time.monotonic_ns()
            sock.sendto(buf, target)
            time.sleep(period_s)
        time.sleep(0.2)
    finally:
        side.stop()
        sock.close()
    latencies: list[float] = []
    collect(sent, backend, latencies)
    return latencies


def collect(sent: dict[int, int], backend: TimingBackend, out: list[float]) -> None:
    for pwm, t_sent in list(sent.items()):
        t_arrived = backend.arrivals.pop(pwm, None)
        if t_arrived is not None and t_arrived >= t_sent:
            out.append((t_arrived - t_sent) / 1e6)
        sent.pop(pwm)


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=999)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--period", type=float, default=0.005, help="s between samples")
    args = parser.parse_args(argv)
    p50s, p99s = [], []
    for run in range(args.runs):
        lat = one_run(min(args.samples, 999), args.period)
        if not lat:
            print(f"run {run}: no samples arrived", file=sys.stderr)
            return 1
        p50s.append(percentile(lat, 0.50))
        p99s.append(percentile(lat, 0.99))
        print(
            f"run {run}: n={len(lat)} p50={p50s[-1]:.3f} ms p99={p99s[-1]:.3f} ms "
            f"max={max(lat):.3f} ms"
        )
    print(
        f"median over {args.runs} runs: p50={statistics.median(p50s):.3f} ms "
        f"p99={statistics.median(p99s):.3f} ms"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
