"""Issue 32 / issue 30 item 5: what a stranger's parameter traffic costs, before and after.

Each scenario runs a real bridge (config/sim.yaml's servos and gimbal, built-in CAN simulation)
on ``udpin:127.0.0.1`` with raw UDP sockets playing the autopilot (HEARTBEAT every 0.5 s) and a
stranger or ground station, and counts every byte the bridge sends each of them, with its arrival
time. Scenarios:

* ``list`` / ``read``: bytes out (PARAM_VALUE/PARAM_ERROR to any peer) per byte in for a
  stranger's PARAM_REQUEST_LIST (1) and PARAM_REQUEST_READ (100 at 50/s), on an unsigned link
  and on a signing link (the stranger unsigned);
* ``flood_read``: PARAM_REQUEST_READ at 1,000/s for 5 s: the autopilot's socket, peak 1-s window
  and seconds above the 1,000 B/s budget;
* ``flood_set``: PARAM_SET at 200/s for 10 s from an allowed ground station, every fsync 20 ms
  slower (an SD card, emulated), while the station sends DO_SET_SERVO at 10 Hz: failsafes on the
  healthy link, COMMAND_ACK latency p50, command period sigma, overlay writes per second;
* ``windows``: the default config for ``--seconds`` (60 for the issue's figure): seconds above
  the budget, peak and mean.

``--tree`` runs the scenarios on another checkout (``git worktree add /tmp/sec-base c3ae82c``)
in a subprocess with ``PYTHONPATH`` set to it, so before and after come from one command:

    python bench/bench_param_security.py --tree /tmp/sec-base --seconds 60
"""

from __future__ import annotations

import argparse
import json
import math
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import yaml
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

SIM = Path(__file__).resolve().parent.parent / "config" / "sim.yaml"
KEY = "5a" * 32
BUDGET = 1000
ANSWERS = ("PARAM_VALUE", "PARAM_ERROR")


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def windows(samples: list[tuple[float, int]], start: float, end: float) -> list[int]:
    """Bytes in each whole second from ``start``, and the peak of any 1-s sliding window last."""
    seconds = [0] * max(1, int(end - start))
    for t, n in samples:
        k = math.floor(t - start)
        if 0 <= k < len(seconds):
            seconds[k] += n
    ordered = sorted(s for s in samples if start <= s[0] < end)
    peak = total = first = 0
    for last in range(len(ordered)):
        total += ordered[last][1]
        while ordered[last][0] - ordered[first][0] >= 1.0:
            total -= ordered[first][1]
            first += 1
        peak = max(peak, total)
    return [*seconds, peak]


class Peer:
    """A UDP socket that records (time, bytes, decoded messages) of what the bridge sends."""

    def __init__(self, port: int, source: tuple[int, int], key: str | None = None) -> None:
        self.port = port
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.mav = mavlink2.MAVLink(None, srcSystem=source[0], srcComponent=source[1])
        if key is not None:
            self.mav.signing.secret_key = bytes.fromhex(key)
            self.mav.signing.sign_outgoing = True
            self.mav.signing.timestamp = int((time.time() - 1420070400) * 100_000)
        self.decoder = mavlink2.MAVLink(None)
        self.decoder.robust_parsing = True
        self.samples: list[tuple[float, int]] = []
        self.received: list[tuple[float, Any]] = []
        self.sent_bytes = 0
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
            now = time.monotonic()
            self.samples.append((now, len(data)))
            for msg in self.decoder.parse_buffer(data) or []:
                self.received.append((now, msg))

    def send(self, msg: Any) -> None:
        raw = msg.pack(self.mav)
        self.sent_bytes += len(raw)
        self.sock.sendto(raw, ("127.0.0.1", self.port))

    def answer_bytes(self) -> int:
        return sum(len(m.get_msgbuf()) for _, m in self.received if m.get_type() in ANSWERS)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.sock.close()


def heartbeats(peer: Peer, stop: threading.Event) -> threading.Thread:
    def beat() -> None:
        while not stop.is_set():
            peer.send(mavlink2.MAVLink_heartbeat_message(1, 3, 0, 0, 4, 3))
            stop.wait(0.5)

    thread = threading.Thread(target=beat, daemon=True)
    thread.start()
    return thread


def start_bridge(**mavlink: Any) -> tuple[Any, int, Path]:
    from mavservo.app.bridge import Bridge
    from mavservo.config.overlay import load_config_with_overlay

    raw = yaml.safe_load(SIM.read_text())
    port = free_udp_port()
    raw["mavlink"].update({"url": f"udpin:127.0.0.1:{port}", "monitor_outputs": [], **mavlink})
    raw["mavlink"].pop("request_streams", None)
    raw["mavlink"].pop("parameter_writers", None)  # the key the old tree does not know
    directory = Path(tempfile.mkdtemp(prefix="bench-sec-"))
    path = directory / "sim.yaml"
    path.write_text(yaml.safe_dump(raw))
    loaded = load_config_with_overlay(path)
    bridge = Bridge(
        loaded.config, config_path=path, log_dir=False, parameter_base=loaded.base
    ).start()
    return bridge, port, path


def amplification(kind: str, signed: bool) -> dict[str, Any]:
    bridge, port, _ = start_bridge(
        signing={"key": KEY, "accept_unsigned": True} if signed else None
    )
    autopilot = Peer(port, (1, 1), KEY if signed else None)
    stranger = Peer(port, (255, 77))
    stop = threading.Event()
    heartbeats(autopilot, stop)
    try:
        time.sleep(1.5)
        stranger.send(mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
        time.sleep(0.5)
        before = stranger.sent_bytes
        if kind == "list":
            stranger.send(mavlink2.MAVLink_param_request_list_message(1, 140))
        else:
            for n in range(100):
                stranger.send(mavlink2.MAVLink_param_request_read_message(1, 140, b"SRV1_TRIM", -1))
                time.sleep(0.02 if n else 0)
        time.sleep(10.0 if kind == "list" else 4.0)
        sent = stranger.sent_bytes - before
        out = stranger.answer_bytes() + autopilot.answer_bytes()
        return {
            "in": sent,
            "out": out,
            "ratio": out / sent,
            "to_autopilot": autopilot.answer_bytes(),
        }
    finally:
        stop.set()
        bridge.stop()
        autopilot.close()
        stranger.close()


def flood_read(seconds: float = 5.0) -> dict[str, Any]:
    bridge, port, _ = start_bridge(link_budget_bytes_s=BUDGET)
    autopilot, stranger = Peer(port, (1, 1)), Peer(port, (255, 77))
    stop = threading.Event()
    heartbeats(autopilot, stop)
    try:
        time.sleep(2.0)
        start = time.monotonic()
        read = mavlink2.MAVLink_param_request_read_message(1, 140, b"SRV1_TRIM", -1)
        for n in range(int(1000 * seconds)):
            stranger.send(read)
            time.sleep(max(0.0, start + n / 1000 - time.monotonic()))
        end = time.monotonic()
        result = {}
        for name, peer in (("autopilot", autopilot), ("stranger", stranger)):
            *per_second, peak = windows(peer.samples, start, end)
            result[name] = {
                "mean_B_s": sum(per_second) / len(per_second),
                "peak_1s_window": peak,
                "seconds_over_budget": sum(s > BUDGET for s in per_second),
            }
        return result
    finally:
        stop.set()
        bridge.stop()
        autopilot.close()
        stranger.close()


def flood_set(seconds: float = 10.0) -> dict[str, Any]:
    real_fsync = os.fsync
    fsyncs: list[float] = []

    def slow_fsync(fd: int) -> None:
        fsyncs.append(time.monotonic())
        time.sleep(0.02)
        real_fsync(fd)

    os.fsync = slow_fsync  # type: ignore[assignment]
    allowed = [{"system": 255, "component": 190}]
    bridge, port, path = start_bridge(allowed_sources=allowed)
    autopilot, station = Peer(port, (1, 1)), Peer(port, (255, 190))
    stop = threading.Event()
    heartbeats(autopilot, stop)
    try:
        time.sleep(2.0)
        failsafes_before = bridge.mavlink.stats()["failsafe_count"]
        start = time.monotonic()
        commands: list[float] = []
        n = 0
        while time.monotonic() - start < seconds:
            value = float(1 + n % 10)
            station.send(mavlink2.MAVLink_param_set_message(1, 140, b"SRV1_TRIM", value, 9))
            if n % 20 == 0:  # DO_SET_SERVO at 10 Hz
                pwm = 1400 + 10 * ((n // 20) % 20)
                station.send(
                    mavlink2.MAVLink_command_long_message(1, 140, 183, 0, 1, pwm, 0, 0, 0, 0, 0)
                )
                commands.append(time.monotonic())
            n += 1
            time.sleep(max(0.0, start + n / 200 - time.monotonic()))
        end = time.monotonic()
        time.sleep(3.0)
        acks = [
            t for t, m in station.received if m.get_type() == "COMMAND_ACK" and m.command == 183
        ]
        # each ACK answers the oldest command not yet answered (one ACK per command, in order)
        latencies = [a - c for c, a in zip(commands, acks, strict=False)]
        summary = bridge.summary()
        tick = next(iter(summary["buses"].values()))["command_tick"]["interval"]
        return {
            "sets_sent": n,
            "failsafes": bridge.mavlink.stats()["failsafe_count"] - failsafes_before,
            "commands": len(commands),
            "acks": len(acks),
            "ack_p50_ms": 1000 * statistics.median(latencies) if latencies else None,
            "command_period_sigma_ms": 1000 * (tick.get("sigma") or 0.0),
            "overlay_writes_per_s": len([t for t in fsyncs if start <= t < end])
            / 2
            / (end - start),
        }
    finally:
        stop.set()
        bridge.stop()
        autopilot.close()
        station.close()
        os.fsync = real_fsync


def default_windows(seconds: float) -> dict[str, Any]:
    bridge, port, _ = start_bridge()
    autopilot = Peer(port, (1, 1))
    stop = threading.Event()
    heartbeats(autopilot, stop)
    try:
        time.sleep(3.0)
        start = time.monotonic()
        time.sleep(seconds)
        end = time.monotonic()
        *per_second, peak = windows(autopilot.samples, start, end)
        return {
            "seconds": len(per_second),
            "mean_B_s": sum(per_second) / len(per_second),
            "max_second": max(per_second),
            "peak_1s_window": peak,
            "seconds_over_budget": sum(s > BUDGET for s in per_second),
        }
    finally:
        stop.set()
        bridge.stop()
        autopilot.close()


def scenario(name: str, seconds: float) -> dict[str, Any]:
    if name in ("list", "read"):
        return {
            "unsigned": amplification(name, signed=False),
            "signed": amplification(name, signed=True),
        }
    if name == "flood_read":
        return flood_read()
    if name == "flood_set":
        return flood_set()
    return default_windows(seconds)


SCENARIOS = ("list", "read", "flood_read", "flood_set", "windows")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--tree", help="also run on this checkout (the baseline), first")
    parser.add_argument("--seconds", type=float, default=60.0, help="the windows run's length")
    parser.add_argument("--only", choices=SCENARIOS, action="append")
    parser.add_argument("--scenario", choices=SCENARIOS, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.scenario:  # a child run: one scenario, JSON out
        import logging

        logging.disable(logging.WARNING)
        print(json.dumps(scenario(args.scenario, args.seconds)))
        return
    here = str(Path(__file__).resolve().parent.parent)
    trees = ([("before", args.tree)] if args.tree else []) + [("after", here)]
    for name in args.only or SCENARIOS:
        for label, tree in trees:
            env = {**os.environ, "PYTHONPATH": tree}
            result = subprocess.run(
                [sys.executable, __file__, "--scenario", name, "--seconds", str(args.seconds)],
                env=env,
                capture_output=True,
                text=True,
                timeout=args.seconds + 120,
                check=False,
            )
            lines = result.stdout.strip().splitlines()
            shown = lines[-1] if lines else result.stderr.strip()[-400:]
            print(f"{name} {label}: {shown}", flush=True)


if __name__ == "__main__":
    main()
