"""Fault-injection bench: serial line corruption, USB unplug/replug, faulty servos, a CAN flood.

Sections (``--only`` picks some; all run by default):

* ``codec``: servo traffic (position commands to 16 servos, their 8-byte replies) encoded in
  each AA-55 protocol, corrupted by the simulator's :class:`LineCorrupter` (bit flips per byte
  at 1e-6 .. 1e-2, dropped bytes, garbage bursts), decoded in random chunks. Counts frames
  recovered, frames that were never sent ("wrong": a flipped byte that passed), and
  structurally impossible frames emitted (must be 0). Fast: no threads, no pty.
* ``line``: the whole Bridge on its simulated adapter with line corruption in both directions:
  frames the servos received that the host never sent (wrong commands applied), rejections,
  missed command slots.
* ``replug``: USB unplug for ``--unplug-s`` seconds mid-run; time from replug to the first
  servo reply and to the next command reaching a servo.
* ``servos``: one servo silent / slow (reply delay > timeout) / faulted: that servo goes
  offline or reports the fault; the others keep their command slots.
* ``canflood``: a foreign node keeps the CAN bus 100 % busy at the highest priority (ID 0) and
  then at the lowest (0x7FF): what still gets through.

Run by hand; prints one JSON document::

    python bench/bench_faults.py --frames 200000 --seconds 10
"""

from __future__ import annotations

import argparse
import json
import platform
import random
import struct
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from typing import Any

import can

from mavservo import aa55
from mavservo.bridge import Bridge
from mavservo.config.loader import load_config_text
from mavservo.sim.adapter import LineCorrupter, LineFaults
from mavservo.sim.canbus import frame_time

RATES = (1e-6, 1e-5, 1e-4, 1e-3, 1e-2)


# ------------------------------------------------------------------ codec


def servo_traffic(count: int, rng: random.Random) -> list[aa55.Frame]:
    """RMD-X A4 commands to 16 servos and 9C-style replies, with changing angles."""
    out = []
    for k in range(count):
        servo = 1 + k % 16
        angle = rng.randrange(-9000, 9000)
        if k % 2 == 0:
            payload = struct.pack("<BBHi", 0xA4, 0, 360, angle)
            out.append(aa55.Frame(0x140 + servo, False, False, 8, payload))
        else:
            payload = struct.pack("<BbhhH", 0xA4, 30, 120, 0, angle // 100 & 0xFFFF)
            out.append(aa55.Frame(0x240 + servo, False, False, 8, payload))
    return out


def codec_run(protocol: str, faults: LineFaults, count: int, seed: int) -> dict[str, Any]:
    rng = random.Random(seed)
    sent = servo_traffic(count, rng)
    sent_set = set(sent)
    corrupter = LineCorrupter(faults, seed)
    decoder = aa55.Decoder(protocol, keep_rejections=1)
    got: list[Any] = []
    wire_total = 0
    block = 64  # frames per serial read, as a USB packet train would deliver them
    for start in range(0, len(sent), block):
        wire = corrupter.corrupt(b"".join(aa55.encode(f, protocol) for f in sent[start:start
                                                                                 + block]))
        wire_total += len(wire)
        got += decoder.feed(wire)
    got += decoder.flush()
    frames = [f for f in got if isinstance(f, aa55.Frame)]
    wrong = [f for f in frames if f not in sent_set]
    impossible = [
        f for f in frames
        if f.dlc > 8 or f.arbitration_id > (aa55.MAX_EXT_ID if f.is_extended_id
                                             else aa55.MAX_STD_ID)
        or len(f.data) != (0 if f.is_remote_frame else f.dlc)
    ]
    recovered = sum(1 for f in frames if f in sent_set)
    return {
        "protocol": protocol,
        "flip_prob": faults.flip_prob,
        "drop_byte_prob": faults.drop_byte_prob,
        "burst_prob": faults.burst_prob,
        "frames_sent": count,
        "bytes_on_wire": wire_total,
        "bytes_flipped": corrupter.flipped,
        "bytes_dropped": corrupter.dropped,
        "bursts": corrupter.bursts,
        "frames_recovered": recovered,
        "recovered_ratio": recovered / count,
        "wrong_frames": len(wrong),
        "wrong_per_flipped_byte": len(wrong) / corrupter.flipped if corrupter.flipped else 0.0,
        "impossible_frames": len(impossible),
        "rejected": {k.value: v for k, v in decoder.rejected.items()},
    }


def codec_section(count: int) -> list[dict[str, Any]]:
    rows = []
    for protocol in ("variable", "fixed"):
        for rate in RATES:
            rows.append(codec_run(protocol, LineFaults(flip_prob=rate, direction="both"), count,
                                  seed=1))
        rows.append(codec_run(protocol, LineFaults(drop_byte_prob=1e-3, direction="both"),
                              count, seed=2))
        rows.append(codec_run(protocol, LineFaults(burst_prob=0.05, burst_len=16,
                                                   direction="both"), count, seed=3))
    return rows


# ------------------------------------------------------------------ end to end


def bridge_config(servos: int, protocol: str, command_mode: str = "periodic") -> str:
    lines = [
        "mavlink: {url: sim, heartbeat_timeout_s: 30}",
        "can:",
        "  buses:",
        f"    - {{name: bus0, interface: aa55, channel: sim, protocol: {protocol},"
        " max_load: 0.9}",
        "servos:",
    ]
    for i in range(1, servos + 1):
        lines.append(f"  - {{name: s{i}, profile: rmd-x, can_id: {i}, limits_deg: [-45, 45],"
                     f" telemetry_hz: 10, command_mode: {command_mode},"
                     " failsafe: {action: hold, timeout_s: 5}}")
    lines.append("channels:")
    for i in range(1, servos + 1):
        lines.append(f"  - {{servo: s{i}, source: servo_output, channel: {i},"
                     " input: {min: 1000, max: 2000}}")
    lines.append("simulation: {autopilot: {profile: sweep, servo_output_rate_hz: 50,"
                 " gimbal: false}}")
    lines.append("scheduler: {command_period_s: 0.02, telemetry_period_s: 0.1}")
    return "\n".join(lines) + "\n"


class Recorder:
    """Frames the host sent (wrapping the bus's ``send``) and frames the servos received
    (wrapping the simulated CAN bus's ``submit``), to find commands nobody sent.

    Only the last ``window`` sent frames are remembered (a frame reaches the adapter within
    milliseconds of being sent), so a soak does not measure the recorder's own growth.
    """

    def __init__(self, bridge: Bridge, window: int = 20_000) -> None:
        self._recent: deque[tuple] = deque()
        self._window = window
        self.sent: Counter[tuple] = Counter()
        self.arrived = 0
        self.wrong_count = 0
        self.wrong: deque[tuple] = deque(maxlen=100)  # the last few, for inspection
        self.lock = threading.Lock()
        bus = bridge.buses["bus0"]
        emulator = bridge.emulators["bus0"]
        original_send: Callable[..., Any] = bus.send
        original_submit: Callable[..., Any] = emulator.canbus.submit

        def send(msg: can.Message, timeout: float | None = None) -> None:
            with self.lock:
                self._remember(key(msg))
            original_send(msg, timeout)

        def submit(msg: can.Message, ready: float, *rest: Any) -> None:
            if not rest:  # from the host (servo replies pass the servo as source)
                with self.lock:
                    self.arrived += 1
                    if key(msg) not in self.sent:
                        self.wrong_count += 1
                        self.wrong.append(key(msg))
            original_submit(msg, ready, *rest)

        bus.send = send  # type: ignore[method-assign]
        emulator.canbus.submit = submit  # type: ignore[method-assign]

    def _remember(self, frame: tuple) -> None:
        self._recent.append(frame)
        self.sent[frame] += 1
        if len(self._recent) > self._window:
            old = self._recent.popleft()
            self.sent[old] -= 1
            if not self.sent[old]:
                del self.sent[old]


def key(msg: can.Message) -> tuple:
    return (msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame, bytes(msg.data))


def transport(summary: dict[str, Any]) -> dict[str, Any]:
    bus = summary["buses"]["bus0"]
    return {
        "missed_command_slots": bus["missed_command_slots"],
        "transport": bus["transport"],
        "servo_frames": {k: sum(s["frames"][k] for s in summary["servos"].values())
                         for k in ("sent", "received", "lost", "late_replies")},
    }


def line_section(seconds: float, servos: int) -> list[dict[str, Any]]:
    rows = []
    for protocol in ("variable", "fixed"):
        for rate in (0.0, 1e-4, 1e-3, 1e-2):
            bridge = Bridge(load_config_text(bridge_config(servos, protocol)), log_dir=False)
            bridge.start()
            recorder = Recorder(bridge)
            emulator = bridge.emulators["bus0"]
            emulator.line = LineCorrupter(LineFaults(flip_prob=rate, direction="both"), seed=7)
            time.sleep(seconds)
            summary = bridge.stop()
            rows.append({
                "protocol": protocol, "flip_prob": rate, "seconds": seconds, "servos": servos,
                "commands_arrived": recorder.arrived, "wrong_commands": recorder.wrong_count,
                "bytes_flipped": emulator.line.flipped, **transport(summary),
            })
    return rows


def wait_for(condition: Callable[[], bool], timeout: float) -> float | None:
    start = time.monotonic()
    while time.monotonic() - start < timeout:
        if condition():
            return time.monotonic() - start
        time.sleep(0.001)
    return None


def replug_section(cycles: int, unplug_s: float) -> dict[str, Any]:
    bridge = Bridge(load_config_text(bridge_config(4, "variable")), log_dir=False)
    bridge.start()
    recorder = Recorder(bridge)
    emulator = bridge.emulators["bus0"]
    bus = bridge.buses["bus0"]
    time.sleep(1.0)
    to_reply, to_reconnect = [], []
    for _ in range(cycles):
        emulator.unplug()
        time.sleep(unplug_s)
        before = bus.stats().get("frames", 0)
        emulator.replug()
        reconnected = wait_for(lambda: bool(bus.stats().get("connected")), 10.0)
        to_reconnect.append(reconnected)
        first_reply = wait_for(lambda b=before: bus.stats().get("frames", 0) > b, 10.0)
        # wait_for measures from its own start: the sum is the time since the replug
        to_reply.append(None if reconnected is None or first_reply is None
                        else reconnected + first_reply)
        time.sleep(0.5)
    summary = bridge.stop()
    ok_reply = sorted(t for t in to_reply if t is not None)
    ok_reconnect = sorted(t for t in to_reconnect if t is not None)
    return {
        "cycles": cycles, "unplug_s": unplug_s,
        "resume_to_first_reply_s": {"median": ok_reply[len(ok_reply) // 2] if ok_reply else None,
                                    "max": ok_reply[-1] if ok_reply else None,
                                    "never": to_reply.count(None)},
        "replug_to_reconnected_s": {"median": ok_reconnect[len(ok_reconnect) // 2]
                                    if ok_reconnect else None,
                                    "max": ok_reconnect[-1] if ok_reconnect else None,
                                    "never": to_reconnect.count(None)},
        "wrong_commands": recorder.wrong_count,
        **transport(summary),
    }


def servos_section(seconds: float) -> list[dict[str, Any]]:
    rows = []
    for fault in ("silent", "slow", "over_current"):
        bridge = Bridge(load_config_text(bridge_config(4, "variable")), log_dir=False)
        bridge.start()
        time.sleep(0.5)
        emulator = bridge.emulators["bus0"]
        victim = next(s for s in emulator.servos if s.can_id == 2)
        with emulator._lock:  # the adapter thread reads the faults
            if fault == "silent":
                victim.faults.silent = True
            elif fault == "slow":
                victim.faults.reply_delay_s = 0.2
            else:
                victim.faults.over_current = True
        time.sleep(seconds)
        rows_now = {r["servo"]: r for r in bridge.status_rows()}
        summary = bridge.stop()
        rows.append({
            "fault": fault, "seconds": seconds,
            "victim": {"online": rows_now["s2"]["online"], "faults": rows_now["s2"]["faults"],
                       "frames": summary["servos"]["s2"]["frames"]},
            "others_online": all(rows_now[f"s{i}"]["online"] for i in (1, 3, 4)),
            "others_lost": sum(summary["servos"][f"s{i}"]["frames"]["lost"] for i in (1, 3, 4)),
            **transport(summary),
        })
    return rows


class FloodNode:
    """A foreign CAN node that transmits back to back: one frame always queued."""

    def __init__(self, arbitration_id: int, bitrate: int) -> None:
        self.msg = can.Message(arbitration_id=arbitration_id, is_extended_id=False,
                               data=bytes(8))
        self.period = frame_time(False, 8, bitrate, False)
        self._next: float | None = None
        self.sent = 0

    def next_push_time(self) -> float | None:
        return self._next

    def poll(self, now: float) -> list[tuple[float, can.Message]]:
        if self._next is None:
            self._next = now
            return []
        due = self._next
        self._next = max(due + self.period, now - 0.01)  # never a backlog beyond 10 ms
        self.sent += 1
        return [(due, can.Message(arbitration_id=self.msg.arbitration_id,
                                  is_extended_id=False, data=self.msg.data))]

    def receive(self, msg: can.Message, now: float) -> list:
        return []


def canflood_section(seconds: float) -> list[dict[str, Any]]:
    rows = []
    for arbitration_id in (0x000, 0x7FF):
        bridge = Bridge(load_config_text(bridge_config(4, "variable")), log_dir=False)
        bridge.start()
        recorder = Recorder(bridge)
        emulator = bridge.emulators["bus0"]
        node = FloodNode(arbitration_id, emulator.bitrate)
        with emulator._lock:
            emulator.canbus.attach(node)  # type: ignore[arg-type]
        time.sleep(seconds)
        load = emulator.load()
        summary = bridge.stop()
        rows.append({
            "flood_id": hex(arbitration_id), "seconds": seconds, "bus_load": load,
            "flood_frames": node.sent, "commands_arrived": recorder.arrived,
            "servos_online": sum(1 for s in summary["servos"].values() if s["online"]),
            **transport(summary),
        })
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="*", default=["codec", "line", "replug", "servos",
                                                       "canflood"])
    parser.add_argument("--frames", type=int, default=200_000, help="codec: frames per row")
    parser.add_argument("--seconds", type=float, default=10.0, help="end-to-end: per row")
    parser.add_argument("--servos", type=int, default=16)
    parser.add_argument("--cycles", type=int, default=10, help="replug cycles")
    parser.add_argument("--unplug-s", type=float, default=1.0)
    args = parser.parse_args()
    started = time.monotonic()
    out: dict[str, Any] = {"machine": f"{platform.machine()} {platform.processor() or ''} "
                                      f"python {platform.python_version()}"}
    if "codec" in args.only:
        out["codec"] = codec_section(args.frames)
    if "line" in args.only:
        out["line"] = line_section(args.seconds, args.servos)
    if "replug" in args.only:
        out["replug"] = replug_section(args.cycles, args.unplug_s)
    if "servos" in args.only:
        out["servos"] = servos_section(args.seconds)
    if "canflood" in args.only:
        out["canflood"] = canflood_section(args.seconds)
    out["wall_s"] = time.monotonic() - started
    print(json.dumps(out, indent=1, default=str))


if __name__ == "__main__":
    main()
