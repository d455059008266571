"""Bytes per second the bridge sends on the autopilot link, with and without the link budget.

Runs the bridge on config/sim.yaml's servos and gimbal (built-in CAN simulation) with MAVLink on
``udpin:127.0.0.1``; a peer plays the autopilot (HEARTBEAT every 0.5 s, as the bridge's watchdog
needs) and a second socket takes the monitor output. Both count the MAVLink bytes they receive
from the bridge over the same window. Four runs: budget off/on x unsigned/signed.

    python bench/bench_link_budget.py [--seconds 20]
"""

from __future__ import annotations

import argparse
import socket
import threading
import time
from pathlib import Path

import yaml
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.app.bridge import Bridge, free_udp_port
from mavservo.config import load_config_text

SIM = Path(__file__).resolve().parent.parent / "config" / "sim.yaml"
KEY = "5a" * 32


class Counter:
    """Counts MAVLink bytes arriving on a UDP socket (bounded by a stop event)."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.bytes = 0
        self.frames = 0
        self.counting = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        self.sock.settimeout(0.05)
        while not self._stop.is_set():
            try:
                data = self.sock.recv(65536)
            except (TimeoutError, OSError):
                continue
            if self.counting:
                self.take(data)

    def take(self, data: bytes) -> None:
        """One datagram while counting (``bench_link_turns.py`` also reads what is in it)."""
        self.bytes += len(data)
        self.frames += 1

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.sock.close()


def run(budget: bool, signed: bool, seconds: float) -> tuple[float, float, float]:
    raw = yaml.safe_load(SIM.read_text())
    port, monitor_port = free_udp_port(), free_udp_port()
    raw["mavlink"]["url"] = f"udpin:127.0.0.1:{port}"
    raw["mavlink"]["monitor_outputs"] = [f"udpout:127.0.0.1:{monitor_port}"]
    raw["mavlink"]["link_budget_bytes_s"] = 1000 if budget else None
    raw["mavlink"]["signing"] = {"key": KEY} if signed else None
    raw["mavlink"].pop("request_streams", None)
    config = load_config_text(yaml.safe_dump(raw), "<bench>")
    monitor_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    monitor_sock.bind(("127.0.0.1", monitor_port))
    monitor = Counter(monitor_sock)
    peer_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer_sock.bind(("127.0.0.1", 0))
    link = Counter(peer_sock)
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    if signed:
        mav.signing.secret_key = bytes.fromhex(KEY)
        mav.signing.sign_outgoing = True
        mav.signing.timestamp = int((time.time() - 1420070400) * 100_000)
    bridge = Bridge(config, log_dir=False).start()
    try:
        beat = mavlink2.MAVLink_heartbeat_message(1, 3, 0, 0, 4, 3)
        deadline = time.monotonic() + 3 + seconds
        started = None
        for _ in range(int((3 + seconds) / 0.5) + 2):
            peer_sock.sendto(beat.pack(mav), ("127.0.0.1", port))
            now = time.monotonic()
            if started is None and now > deadline - seconds:
                started = now
                link.counting = monitor.counting = True
            if now >= deadline:
                break
            time.sleep(0.5)
        elapsed = time.monotonic() - (started or time.monotonic())
        link.counting = monitor.counting = False
        planned = bridge.mavlink.core.budget.plan.link_bytes_s
    finally:
        bridge.stop()
        link.close()
        monitor.close()
    return link.bytes / elapsed, monitor.bytes / elapsed, planned


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    args = parser.parse_args()
    print("| budget | signing | autopilot link B/s | monitor output B/s | planned periodic B/s |")
    print("|---|---|---:|---:|---:|")
    for budget in (False, True):
        for signed in (False, True):
            link, monitor, planned = run(budget, signed, args.seconds)
            print(
                f"| {'1000 B/s' if budget else 'none'} | {'signed' if signed else 'unsigned'} "
                f"| {link:,.0f} | {monitor:,.0f} | {planned:,.0f} |"
            )


if __name__ == "__main__":
    main()
