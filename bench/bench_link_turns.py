"""Does each periodic stream get the turns the link budget planned for it? Run by hand.

    PYTHONPATH=. python bench/bench_link_turns.py [--seconds 40] [--config ardupilot-sitl.yaml]

Runs the bridge on a shipped config (built-in CAN simulation) with MAVLink on
``udpin:127.0.0.1`` and the default 1,000 B/s budget; a peer plays the autopilot (a HEARTBEAT
every 0.5 s) and a second socket takes the monitor output, which carries every message at the
configured rates. For each periodic message type it prints what reached the autopilot's socket
against the plan (the plan's ratio for the stream times what the monitor output got), the
longest gap between two of them on the link, and the busiest sliding 1-s window of bytes.

Why: the plan fitted the budget on average, yet against ArduPlane SITL the link carried 25 of
144 planned ACTUATOR_OUTPUT_STATUS (docs/engineering/sitl.md); this measures the same thing without
SITL. ESC_INFO and ESC_STATUS are not in pymavlink's ArduPilot dialect, so they are not counted
here.
"""

from __future__ import annotations

import argparse
import collections
import socket
import time
from pathlib import Path

import yaml
from bench_link_budget import Counter  # the same receiving thread (run from bench/)
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.app.bridge import Bridge, free_udp_port
from mavservo.config import load_config_text
from mavservo.records.metrics import peak_window_bytes

CONFIGS = Path(__file__).resolve().parent.parent / "config"
STREAM_OF = {
    "NAMED_VALUE_FLOAT": "NAMED_VALUE_FLOAT",
    "ACTUATOR_OUTPUT_STATUS": "ACTUATOR_OUTPUT_STATUS",
    "GIMBAL_DEVICE_ATTITUDE_STATUS": "GIMBAL_DEVICE_ATTITUDE_STATUS",
}


class Listener(Counter):
    """Counts per message type, and the bytes of each datagram with its time, while
    ``counting`` (the receiving thread is bench_link_budget's)."""

    def __init__(self, sock: socket.socket) -> None:
        self.counts: collections.Counter[str] = collections.Counter()
        self.times: dict[str, list[float]] = collections.defaultdict(list)
        self.sizes: list[tuple[float, int]] = []
        self._parser = mavlink2.MAVLink(None)
        self._parser.robust_parsing = True
        super().__init__(sock)

    def take(self, data: bytes) -> None:
        super().take(data)
        try:
            messages = self._parser.parse_buffer(data) or []
        except Exception:  # noqa: BLE001 - a message of another dialect: not counted
            return
        now = time.monotonic()
        self.sizes.append((now, len(data)))
        for msg in messages:
            self.counts[msg.get_type()] += 1
            self.times[msg.get_type()].append(now)


def stream_of(kind: str) -> str | None:
    if kind.startswith("ESC_TELEMETRY_"):
        return "ESC_TELEMETRY"
    return STREAM_OF.get(kind)


def run(config_name: str, seconds: float) -> None:
    raw = yaml.safe_load((CONFIGS / config_name).read_text())
    port, monitor_port = free_udp_port(), free_udp_port()
    raw["mavlink"]["url"] = f"udpin:127.0.0.1:{port}"
    raw["mavlink"]["monitor_outputs"] = [f"udpout:127.0.0.1:{monitor_port}"]
    raw["mavlink"]["link_budget_bytes_s"] = 1000
    raw["mavlink"].pop("request_streams", None)
    config = load_config_text(yaml.safe_dump(raw), f"<{config_name}>")
    monitor_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    monitor_sock.bind(("127.0.0.1", monitor_port))
    monitor = Listener(monitor_sock)
    autopilot_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    autopilot_sock.bind(("127.0.0.1", 0))
    link = Listener(autopilot_sock)
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    beat = mavlink2.MAVLink_heartbeat_message(1, 3, 0, 0, 4, 3)
    bridge = Bridge(config, log_dir=False).start()
    try:
        started = time.monotonic()
        for beat_number in range(int((3 + seconds) / 0.5) + 2):
            autopilot_sock.sendto(beat.pack(mav), ("127.0.0.1", port))
            if beat_number == 6:  # 3 s in: the bridge found the autopilot
                link.counting = monitor.counting = True
                started = time.monotonic()
            if beat_number > 6 and time.monotonic() - started >= seconds:
                break
            time.sleep(0.5)
        link.counting = monitor.counting = False
        elapsed = time.monotonic() - started
        plan = bridge.mavlink.core.budget.plan
    finally:
        bridge.stop()
        link.close()
        monitor.close()
    print(f"{config_name}, {elapsed:.0f} s, budget 1,000 B/s")
    print("| message | on the link | planned | share | longest gap on the link |")
    print("|---|---:|---:|---:|---:|")
    for kind in sorted(monitor.counts):
        stream = stream_of(kind)
        if stream is None:
            continue
        planned = monitor.counts[kind] * plan.ratios.get(stream, 1.0)
        times = link.times[kind]
        gap = max((b - a for a, b in zip(times, times[1:], strict=False)), default=0.0)
        print(
            f"| {kind} | {link.counts[kind]} | {planned:.0f} | "
            f"{link.counts[kind] / max(planned, 1):.0%} | {gap:.2f} s |"
        )
    mean = sum(size for _, size in link.sizes) / max(elapsed, 1e-9)
    print(f"busiest 1-s window {peak_window_bytes(link.sizes):,} B, mean {mean:,.0f} B/s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=40.0)
    parser.add_argument(
        "--config",
        action="append",
        help="shipped config(s) (default: sim.yaml, ardupilot-sitl.yaml)",
    )
    args = parser.parse_args()
    for name in args.config or ["sim.yaml", "ardupilot-sitl.yaml"]:
        run(name, args.seconds)


if __name__ == "__main__":
    main()
