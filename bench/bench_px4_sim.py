"""What asking PX4 for its gimbal setpoints buys: command to servo setpoint, simulated PX4.

Run by hand (docs/engineering/px4-sitl.md)::

    python bench/bench_px4_sim.py [--runs 3] [--targets 60]

The simulated PX4 (mavservo/sim/autopilot/px4.py: GIMBAL_DEVICE_SET_ATTITUDE at 5 Hz on its
onboard link unless asked) drives the bridge's MAVLink side over UDP on 127.0.0.1. A new gimbal
target every 0.3 s; for each, the time from the target set in PX4 to the backend's setpoint
with that pitch. Twice per run: with the bridge's stream requests (it asks 1 / command period,
20 Hz) and with them off (PX4's default 5 Hz). Prints p50/p95 per run and the medians over runs.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from mavservo.mavlink.backend import ACCEPTED  # noqa: E402
from mavservo.mavlink.gimbal import GimbalDevice  # noqa: E402
from mavservo.mavlink.gimbal_settings import GimbalSettings  # noqa: E402
from mavservo.mavlink.settings import MavlinkSettings, StreamRequestSettings  # noqa: E402
from mavservo.mavlink.side import MavlinkSide  # noqa: E402
from mavservo.sim.autopilot.px4 import Px4Stream  # noqa: E402
from tests.support.mavlink_doubles import RecordingBackend  # noqa: E402
from tests.support.waiting import free_udp_port  # noqa: E402

PERIOD_S = 0.05


class Timed(RecordingBackend):
    def __init__(self) -> None:
        super().__init__()
        self.gimbal: list[tuple[float, float]] = []

    def apply_gimbal(self, gimbal: str, roll: Any, pitch: Any, yaw: Any, source: str, now: float):
        self.gimbal.append((time.monotonic(), pitch))
        return ACCEPTED


def one_run(ask: bool, targets: int) -> list[float]:
    port = free_udp_port()
    backend = Timed()
    settings = MavlinkSettings(
        url=f"udpin:127.0.0.1:{port}",
        system_id=1,
        mirror_servo_output_raw=False,
        command_period_s=PERIOD_S,
        link_budget_bytes_s=None,
        stream_request=dataclasses.replace(
            StreamRequestSettings.for_mirror((), PERIOD_S, gimbals=True), enabled=ask
        ),
    )
    gimbal = GimbalDevice(
        GimbalSettings(
            name="cam",
            component_id=154,
            axis_servos={"pitch": "aileron"},
            limits_deg={"pitch": (-90.0, 30.0)},
            system_id=1,
        ),
        backend,
    )
    lags = []
    side = MavlinkSide(settings, backend, gimbals=[gimbal])
    px4 = Px4Stream(f"udpout:127.0.0.1:{port}", "hold", gimbal=True)
    with side, px4.start():
        time.sleep(3.0)  # found, asked
        for k in range(targets):
            pitch = -80.0 + (k % 50) * 1.5
            start = len(backend.gimbal)
            t0 = time.monotonic()
            px4.set_gimbal(pitch=pitch)
            time.sleep(0.3)
            hit = next(
                (t for t, p in backend.gimbal[start:] if p is not None and abs(p - pitch) < 0.01),
                None,
            )
            if hit is not None:
                lags.append(hit - t0)
    return lags


def pct(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(round(q * (len(ordered) - 1))))]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--targets", type=int, default=60)
    args = parser.parse_args()
    figures: dict[str, list[tuple[float, float, int]]] = {"asked 20 Hz": [], "PX4 default 5 Hz": []}
    for _ in range(args.runs):
        for label, ask in (("asked 20 Hz", True), ("PX4 default 5 Hz", False)):
            lags = one_run(ask, args.targets)
            p50, p95 = 1000 * statistics.median(lags), 1000 * pct(lags, 0.95)
            figures[label].append((p50, p95, len(lags)))
            print(f"{label}: p50 {p50:.0f} ms, p95 {p95:.0f} ms ({len(lags)}/{args.targets})")
    for label, runs in figures.items():
        p50 = statistics.median(r[0] for r in runs)
        p95 = statistics.median(r[1] for r in runs)
        print(f"median of {args.runs} runs, {label}: p50 {p50:.0f} ms, p95 {p95:.0f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
