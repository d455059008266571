"""Whole-bridge latency: SERVO_OUTPUT_RAW on the socket -> AA-55 bytes written on the serial port.

A raw UDP socket plays the autopilot: a HEARTBEAT, then SERVO_OUTPUT_RAW every ``--period`` with
a new PWM each time (so every sample is a change the bridge must act on). The bridge runs for real:
MAVLink side, servo backend, scheduler, the ``aa55`` interface on the adapter emulator's pty, a
simulated RMD-X servo. A scheduler observer stamps the moment ``bus.send`` returned for the
command carrying each new angle (the bytes are in the pty). Both stamps are ``time.monotonic`` in
one process, so their difference is the host-side latency the issue asks for. ``immediate`` mode
sends a new setpoint at once; ``periodic`` waits for the next command tick (up to T_c).

The run log's per-stage tracer (accept, T_tx, round trip to the reply, publication as MAVLink)
is reported too, from the same runs.

    python bench/bench_bridge_latency.py --samples 300 --runs 5
"""

from __future__ import annotations

import argparse
import os
import platform
import socket
import statistics
import tempfile
import time
from typing import Any

os.environ.setdefault("MAVLINK20", "1")

from pymavlink.dialects.v20 import ardupilotmega as mavlink2  # noqa: E402

from mavservo.app.bridge import Bridge, free_udp_port  # noqa: E402
from mavservo.config import load_config_text  # noqa: E402

CONFIG = """
mavlink: {{url: "udpin:127.0.0.1:{port}", telemetry: {{actuator_output_status_hz: 50}}}}
can: {{buses: [{{name: bus0, interface: aa55, channel: sim}}]}}
servos:
  - {{name: s1, profile: rmd-x, can_id: 1, limits_deg: [-90, 90], command_mode: {mode},
     telemetry_hz: 11}}
channels:
  - {{servo: s1, source: servo_output, channel: 1, input: {{min: 1000, max: 2000}},
     output_deg: [-90, 90]}}
logging: {{can_formats: [blf], tlog: false}}
"""


class TxStamps:
    """Scheduler observer: when did the command for each new angle leave through bus.send?"""

    def __init__(self) -> None:
        self.angle_by_seq: dict[int, float] = {}
        self.tx_by_angle: dict[float, float] = {}

    def on_setpoint(self, servo: str, seq: int, angle_deg: float, source: str, t: float) -> None:
        self.angle_by_seq[seq] = round(angle_deg, 6)

    def on_tx(self, bus: str, msg: Any, t: float, kind: str, servo: str, seq: int | None) -> None:
        if kind == "command" and seq in self.angle_by_seq:
            self.tx_by_angle.setdefault(self.angle_by_seq[seq], t)


def pwm_to_angle(pwm: int) -> float:
    return round((pwm - 1500) / 500 * 90, 6)


def one_run(samples: int, period: float, mode: str) -> dict[str, Any]:
    port = free_udp_port()
    config = load_config_text(CONFIG.format(port=port, mode=mode), "bench.yaml")
    stamps = TxStamps()
    with tempfile.TemporaryDirectory() as logs:
        bridge = Bridge(config, log_dir=logs, observers=[stamps], status=lambda line: None)
        bridge.start()
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        try:
            hb = mav.heartbeat_encode(1, 3, 0, 0, 4, 3).pack(mav)
            sock.sendto(hb, ("127.0.0.1", port))
            time.sleep(1.0)  # the link is up, the scheduler running
            sent: dict[float, float] = {}
            next_t = time.monotonic()
            for i in range(samples):
                pwm = 1100 + (i * 37) % 800  # a new value every time
                if i % 50 == 0:
                    sock.sendto(hb, ("127.0.0.1", port))
                channels = [pwm] + [0] * 15
                msg = mav.servo_output_raw_encode(i * 20_000, 0, *channels).pack(mav)
                t_send = time.monotonic()
                sock.sendto(msg, ("127.0.0.1", port))
                sent.setdefault(pwm_to_angle(pwm), t_send)
                next_t += period
                time.sleep(max(0.0, next_t - time.monotonic()))
            time.sleep(0.5)
        finally:
            sock.close()
            summary = bridge.stop()
        stages = bridge.runlog.latency.summary() if bridge.runlog is not None else {}
    latencies = [
        (stamps.tx_by_angle[a] - t0) * 1000 for a, t0 in sent.items() if a in stamps.tx_by_angle
    ]
    latencies.sort()
    servo = summary["servos"]["s1"]
    return {
        "n": len(latencies),
        "sent": len(sent),
        "p50": statistics.median(latencies),
        "p99": latencies[int(0.99 * (len(latencies) - 1))],
        "max": latencies[-1],
        "L_mean": servo["latency_s"]["mean"] * 1000,
        "L_sigma": servo["latency_s"]["sigma"] * 1000,
        "stages": stages,
    }


def _stage(stages: dict[str, Any], name: str, key: str) -> float | None:
    value = stages.get("stages", stages).get(name, {}).get(key) if stages else None
    return None if value is None else value * 1000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--samples", type=int, default=300)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--period", type=float, default=0.02, help="s between SERVO_OUTPUT_RAW")
    args = parser.parse_args()
    machine = f"{platform.machine()}, {os.cpu_count()} cpus"
    print(f"machine: {machine}, python {platform.python_version()}")
    print(
        "| mode | socket -> bytes on port p50 [ms] | p99 [ms] | max [ms] | matched | "
        "L mean [ms] | sigma_L [ms] | stage round trip p50 [ms] | stage publish p50 [ms] |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for mode in ("immediate", "periodic"):
        runs = [one_run(args.samples, args.period, mode) for _ in range(args.runs)]

        def med(key: str, runs: list[dict[str, Any]] = runs) -> float:
            return statistics.median(r[key] for r in runs)

        rt = [_stage(r["stages"], "round_trip", "p50") for r in runs]
        pub = [_stage(r["stages"], "publish", "p50") for r in runs]
        rt_med = statistics.median([x for x in rt if x is not None]) if any(rt) else float("nan")
        pub_med = statistics.median([x for x in pub if x is not None]) if any(pub) else float("nan")
        print(
            f"| {mode} | {med('p50'):.2f} | {med('p99'):.2f} | {med('max'):.2f} | "
            f"{int(med('n'))}/{int(med('sent'))} | {med('L_mean'):.2f} | {med('L_sigma'):.2f} | "
            f"{rt_med:.2f} | {pub_med:.2f} |"
        )


if __name__ == "__main__":
    main()
