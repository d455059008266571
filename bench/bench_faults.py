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
import os
import platform
import random
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import can

from mavservo.app.bridge import Bridge, settle_heap
from mavservo.config.loader import load_config_text
from mavservo.scheduling.runner import SchedulerObserver
from mavservo.sim.adapter import LineCorrupter, LineFaults
from mavservo.sim.child import RecentKeys, SimulatorProcess, frame_key
from mavservo.transport.aa55 import codec as aa55

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
        wire = corrupter.corrupt(
            b"".join(aa55.encode(f, protocol) for f in sent[start : start + block])
        )
        wire_total += len(wire)
        got += decoder.feed(wire)
    got += decoder.flush()
    frames = [f for f in got if isinstance(f, aa55.Frame)]
    wrong = [f for f in frames if f not in sent_set]
    impossible = [
        f
        for f in frames
        if f.dlc > 8
        or f.arbitration_id > (aa55.MAX_EXT_ID if f.is_extended_id else aa55.MAX_STD_ID)
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
            rows.append(
                codec_run(protocol, LineFaults(flip_prob=rate, direction="both"), count, seed=1)
            )
        rows.append(
            codec_run(protocol, LineFaults(drop_byte_prob=1e-3, direction="both"), count, seed=2)
        )
        rows.append(
            codec_run(
                protocol, LineFaults(burst_prob=0.05, burst_len=16, direction="both"), count, seed=3
            )
        )
    return rows


# ------------------------------------------------------------------ end to end


def bridge_config(
    servos: int,
    protocol: str,
    command_mode: str = "periodic",
    *,
    channel: str = "sim",
    url: str = "sim",
    realtime: bool = False,
) -> str:
    """16 (``servos``) RMD-X servos mirroring SERVO_OUTPUT_RAW at 50 Hz, polled at 10 Hz.

    ``channel``/``url`` ``sim``: the bridge builds the adapter emulator and the autopilot in its
    own process; a device path and a MAVLink URL: they run elsewhere (child processes).
    """
    lines = [
        f"mavlink: {{url: '{url}', heartbeat_timeout_s: 30}}",
        "can:",
        "  buses:",
        f"    - {{name: bus0, interface: aa55, channel: '{channel}', protocol: {protocol},"
        " max_load: 0.9}",
        "servos:",
    ]
    for i in range(1, servos + 1):
        lines.append(
            f"  - {{name: s{i}, profile: rmd-x, can_id: {i}, limits_deg: [-45, 45],"
            f" telemetry_hz: 10, command_mode: {command_mode},"
            " failsafe: {action: hold, timeout_s: 5}}"
        )
    lines.append("channels:")
    for i in range(1, servos + 1):
        lines.append(
            f"  - {{servo: s{i}, source: servo_output, channel: {i},"
            " input: {min: 1000, max: 2000}}"
        )
    lines.append(
        "simulation: {autopilot: {profile: sweep, servo_output_rate_hz: 50, gimbal: false}}"
    )
    lines.append(
        "scheduler: {command_period_s: 0.02, telemetry_period_s: 0.1,"
        f" realtime: {str(realtime).lower()}}}"
    )
    return "\n".join(lines) + "\n"


class Recorder:
    """Frames the host sent (wrapping the bus's ``send``) and frames the servos received, to
    find commands nobody sent.

    Arrivals are seen by wrapping the in-process simulated CAN bus's ``submit`` (with the
    simulator in a child process, :meth:`DeployedRig.commands` asks the child instead).

    Only the last ``window`` sent frames are remembered (a frame reaches the adapter within
    milliseconds of being sent), so a soak does not measure the recorder's own growth.
    """

    def __init__(self, bridge: Bridge, emulator: Any, window: int = 60_000) -> None:
        self.sent = RecentKeys(window)
        self.arrived = 0
        self.wrong_count = 0
        self.wrong: deque[str] = deque(maxlen=100)  # the last few, for inspection
        self.lock = threading.Lock()
        bus = bridge.buses["bus0"]
        original_send: Callable[..., Any] = bus.send

        def send(msg: can.Message, timeout: float | None = None) -> None:
            with self.lock:
                self.sent.add(frame_key(msg))
            original_send(msg, timeout)

        bus.send = send  # type: ignore[method-assign]
        original_submit: Callable[..., Any] = emulator.canbus.submit

        def submit(msg: can.Message, ready: float, *rest: Any) -> None:
            if not rest:  # from the host (servo replies pass the servo as source)
                frame = frame_key(msg)
                with self.lock:
                    self.arrived += 1
                    if frame not in self.sent:
                        self.wrong_count += 1
                        self.wrong.append(frame)
            original_submit(msg, ready, *rest)

        emulator.canbus.submit = submit  # type: ignore[method-assign]


def transport(summary: dict[str, Any]) -> dict[str, Any]:
    bus = summary["buses"]["bus0"]
    return {
        "missed_command_slots": bus["missed_command_slots"],
        "transport": bus["transport"],
        "servo_frames": {
            k: sum(s["frames"][k] for s in summary["servos"].values())
            for k in ("sent", "received", "lost", "late")
        },
    }


def line_section(seconds: float, servos: int) -> list[dict[str, Any]]:
    rows = []
    for protocol in ("variable", "fixed"):
        for rate in (0.0, 1e-4, 1e-3, 1e-2):
            bridge = Bridge(load_config_text(bridge_config(servos, protocol)), log_dir=False)
            bridge.start()
            recorder = Recorder(bridge, bridge.emulators["bus0"])
            emulator = bridge.emulators["bus0"]
            emulator.line = LineCorrupter(LineFaults(flip_prob=rate, direction="both"), seed=7)
            time.sleep(seconds)
            summary = bridge.stop()
            rows.append(
                {
                    "protocol": protocol,
                    "flip_prob": rate,
                    "seconds": seconds,
                    "servos": servos,
                    "commands_arrived": recorder.arrived,
                    "wrong_commands": recorder.wrong_count,
                    "bytes_flipped": emulator.line.flipped,
                    **transport(summary),
                }
            )
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
    recorder = Recorder(bridge, bridge.emulators["bus0"])
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
        to_reply.append(
            None if reconnected is None or first_reply is None else reconnected + first_reply
        )
        time.sleep(0.5)
    summary = bridge.stop()
    ok_reply = sorted(t for t in to_reply if t is not None)
    ok_reconnect = sorted(t for t in to_reconnect if t is not None)
    return {
        "cycles": cycles,
        "unplug_s": unplug_s,
        "resume_to_first_reply_s": {
            "median": ok_reply[len(ok_reply) // 2] if ok_reply else None,
            "max": ok_reply[-1] if ok_reply else None,
            "never": to_reply.count(None),
        },
        "replug_to_reconnected_s": {
            "median": ok_reconnect[len(ok_reconnect) // 2] if ok_reconnect else None,
            "max": ok_reconnect[-1] if ok_reconnect else None,
            "never": to_reconnect.count(None),
        },
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
        rows.append(
            {
                "fault": fault,
                "seconds": seconds,
                "victim": {
                    "online": rows_now["s2"]["online"],
                    "faults": rows_now["s2"]["faults"],
                    "frames": summary["servos"]["s2"]["frames"],
                },
                "others_online": all(rows_now[f"s{i}"]["online"] for i in (1, 3, 4)),
                "others_lost": sum(summary["servos"][f"s{i}"]["frames"]["lost"] for i in (1, 3, 4)),
                **transport(summary),
            }
        )
    return rows


BRIDGE_PRIORITY, SIM_PRIORITY, AUTOPILOT_PRIORITY = 50, 40, 30
"""SCHED_FIFO priorities of the deployed rig: the bridge as deploy/mavservo.service runs it; the
simulated hardware and autopilot just below, since on a drone they have CPUs of their own."""


class DeployedRig:
    """The bridge alone in this process at SCHED_FIFO (``scheduler.realtime: true`` too), the
    adapter emulator and its servos in a child process (:class:`SimulatorProcess`) and the
    simulated autopilot in another (``python -m mavservo.sim.autopilot stream``), both real-time as
    well.

    Why: real servos, adapter and autopilot do not share the bridge's CPU or interpreter lock;
    in one process a timing figure measures the simulator as much as the bridge.
    """

    def __init__(
        self,
        servos: int,
        observers: Sequence[Any] = (),
        protocol: str = "variable",
        sim_trace_keep: int | None = None,
        sim_max_keys: int | None = None,
    ) -> None:
        self._dir = tempfile.TemporaryDirectory(prefix="mavservo-rig-")
        port = free_udp_port()
        config_path = os.path.join(self._dir.name, "rig.yaml")
        Path(config_path).write_text(bridge_config(servos, protocol))
        self.sim = SimulatorProcess(
            config=config_path,
            protocol=protocol,
            realtime_priority=SIM_PRIORITY,
            trace_keep=sim_trace_keep,
            max_keys=sim_max_keys,
        )
        self.autopilot = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "mavservo.sim.autopilot",
                "stream",
                "--url",
                f"udpout:127.0.0.1:{port}",
                "--profile",
                "sweep",
                "--servo-rate",
                "50",
                "--keep",  # its logs are read by nobody here: full (flat) within ~20 s
                "1000",
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            preexec_fn=lambda: os.sched_setscheduler(
                0, os.SCHED_FIFO, os.sched_param(AUTOPILOT_PRIORITY)
            ),
        )
        # A deployed bridge starts beside an autopilot that is already running. The child takes
        # ~0.5 s of CPU at SCHED_FIFO to import; started under the bridge's first slots, the two
        # cores were busy at real-time priority while the bridge started, and the simulator
        # child left a poll round unread for 61 ms (docs/engineering/reliability.md, "Start-up"). So
        # the bridge starts once the autopilot talks.
        if not wait_for_datagram(port, AUTOPILOT_START_TIMEOUT_S):
            self.autopilot.kill()
            self.autopilot.wait(5)
            self.sim.stop()
            self._dir.cleanup()
            raise RuntimeError(f"simulated autopilot sent nothing in {AUTOPILOT_START_TIMEOUT_S} s")
        # as systemd's CPUSchedulingPolicy=fifo does: every thread started from here inherits it
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(BRIDGE_PRIORITY))
        text = bridge_config(
            servos, protocol, channel=self.sim.path, url=f"udpin:127.0.0.1:{port}", realtime=True
        )
        self.bridge = Bridge(load_config_text(text), log_dir=False, observers=list(observers))

    def start(self) -> Bridge:
        self.bridge.start()
        settle_heap()  # as `mavservo run` does
        return self.bridge

    def commands(self) -> tuple[int, int]:
        """Host frames that reached the CAN bus so far, and how many of them the host never
        sent: judged inside the child against the host's bytes before the line corrupted
        them, so the bridge's process does no bookkeeping for it."""
        counts = self.sim.request("wrong")
        return counts["arrived"], counts["wrong"]

    def stop(self) -> dict[str, Any]:
        """Stop everything; this thread goes back to normal priority. Returns the summary."""
        try:
            return self.bridge.stop()
        finally:
            self.autopilot.terminate()
            try:
                self.autopilot.wait(5)
            except subprocess.TimeoutExpired:
                self.autopilot.kill()
                self.autopilot.wait(5)
            self.sim.stop()
            self._dir.cleanup()
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


AUTOPILOT_START_TIMEOUT_S = 30.0


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def wait_for_datagram(port: int, timeout_s: float) -> bool:
    """Hold ``127.0.0.1:port`` until a first datagram arrives (True) or ``timeout_s`` ends.

    Why: the simulated autopilot sends with ``udpout`` as soon as it has started, so its first
    datagram says it is up. The port is free again on return, for the bridge to bind; what the
    autopilot sends in between is lost, as it would be to a bridge not yet listening.
    """
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(("127.0.0.1", port))
        sock.settimeout(timeout_s)
        try:
            sock.recv(65536)
        except TimeoutError:
            return False
    return True


class LatencyProbe(SchedulerObserver):
    """Command-to-reply delay per frame (matched in order per servo), for one time window.

    Hooks only append (they run inside the scheduler's loops); :meth:`take` reads and resets.
    """

    def __init__(self) -> None:
        self._sent: dict[str, deque[float]] = {}
        self._delays: list[float] = []

    def on_tx(self, bus: str, msg: Any, t: float, kind: str, servo: str, seq: Any) -> None:
        self._sent.setdefault(servo, deque(maxlen=64)).append(t)

    def on_rx(self, bus: str, msg: Any, t: float, servo: str, state: Any) -> None:
        sent = self._sent.get(servo)
        if sent:
            self._delays.append(t - sent.popleft())

    def on_lost(self, bus: str, servo: str, t: float) -> None:
        sent = self._sent.get(servo)
        if sent:
            sent.popleft()

    def take(self) -> dict[str, Any]:
        delays, self._delays = sorted(self._delays), []
        if not delays:
            return {"replies": 0}

        def ms(q: float) -> float:
            return round(delays[min(len(delays) - 1, int(q * len(delays)))] * 1e3, 3)

        return {
            "replies": len(delays),
            "p50_ms": ms(0.5),
            "p99_ms": ms(0.99),
            "max_ms": round(delays[-1] * 1e3, 3),
        }


def _ms(seconds: float) -> float:
    return round(seconds * 1e3, 3)


def canflood_section(seconds: float, servos: int) -> list[dict[str, Any]]:
    """A foreign node floods the bus at the lowest (0x7FF) and the highest (0x000) priority,
    against a baseline without it. The simulated bus plays the flood as back-to-back frames
    that take part in every arbitration (:meth:`SimCanBus.set_flood`), and the adapter's
    filter is open as the bridge leaves it: every foreign frame crosses the serial line."""
    rows = []
    for arbitration_id in (None, 0x7FF, 0x000):
        probe = LatencyProbe()
        rig = DeployedRig(servos, observers=[probe])
        bridge = rig.start()
        scheduler = bridge.schedulers["bus0"]
        try:
            time.sleep(2.0)  # servos online
            before = rig.bridge.summary()
            rig.sim.request("stats")
            probe.take()
            rig.sim.request("flood", arbitration_id=arbitration_id)
            cpu_before = time.process_time()
            loads, sim_loads = [], []
            started = time.monotonic()
            while time.monotonic() - started < seconds:
                time.sleep(0.5)
                loads.append(scheduler.load_ratio())
                sim_loads.append(rig.sim.request("stats")["load_1s"])
            cpu = time.process_time() - cpu_before  # the bridge process (this one)
            during = probe.take()
            stats = rig.sim.request("stats")
            rows_now = {r["servo"]: r for r in bridge.status_rows()}
            after = rig.bridge.summary()
            rig.sim.request("flood", arbitration_id=None)
            recovered = wait_for(lambda b=bridge: all(r["online"] for r in b.status_rows()), 10.0)
            _, wrong = rig.commands()
        finally:
            summary = rig.stop()

        def frames(key: str, a: dict[str, Any] = after, b: dict[str, Any] = before) -> int:
            return sum(
                a["servos"][n]["frames"][key] - b["servos"][n]["frames"][key] for n in a["servos"]
            )

        rows.append(
            {
                "flood_id": None if arbitration_id is None else hex(arbitration_id),
                "seconds": seconds,
                "servos": servos,
                "flood_frames": stats["flood_frames"],
                "bus_load_sim_median": sorted(sim_loads)[len(sim_loads) // 2],
                "bus_load_bridge_median": sorted(loads)[len(loads) // 2],
                "frames_to_host": stats["frames_to_host"],
                "host_frames_dropped_by_adapter": stats["host_dropped"],
                "bytes_overflowed": stats["bytes_overflowed"],
                "sim_lag_max_ms": round(stats["lag"]["max_s"] * 1e3, 2),
                "reply_delay": during,
                "sent": frames("sent"),
                "received": frames("received"),
                "lost": frames("lost"),
                "late": frames("late"),
                # the scheduler's own command-to-reply latency (recent window, all servos)
                "latency_p50_ms_median": _ms(
                    sorted(s["latency_s"]["p50"] or 0 for s in after["servos"].values())[
                        len(after["servos"]) // 2
                    ]
                ),
                "latency_p99_ms_max": _ms(
                    max(s["latency_s"]["p99"] or 0 for s in after["servos"].values())
                ),
                "bridge_cpu_pct": round(100 * cpu / seconds, 1),
                "servos_online_at_end": sum(1 for r in rows_now.values() if r["online"]),
                "faults_at_end": sorted({r["faults"] for r in rows_now.values() if r["faults"]}),
                "back_online_after_flood_s": recovered,
                "missed_command_slots": after["buses"]["bus0"]["missed_command_slots"]
                - before["buses"]["bus0"]["missed_command_slots"],
                "wrong_commands": wrong,
                "events": summary.get("events", []),
            }
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--only", nargs="*", default=["codec", "line", "replug", "servos", "canflood"]
    )
    parser.add_argument("--frames", type=int, default=200_000, help="codec: frames per row")
    parser.add_argument("--seconds", type=float, default=10.0, help="end-to-end: per row")
    parser.add_argument("--servos", type=int, default=16)
    parser.add_argument("--cycles", type=int, default=10, help="replug cycles")
    parser.add_argument("--unplug-s", type=float, default=1.0)
    args = parser.parse_args()
    started = time.monotonic()
    out: dict[str, Any] = {
        "machine": f"{platform.machine()} {platform.processor() or ''} "
        f"python {platform.python_version()}"
    }
    if "codec" in args.only:
        out["codec"] = codec_section(args.frames)
    if "line" in args.only:
        out["line"] = line_section(args.seconds, args.servos)
    if "replug" in args.only:
        out["replug"] = replug_section(args.cycles, args.unplug_s)
    if "servos" in args.only:
        out["servos"] = servos_section(args.seconds)
    if "canflood" in args.only:
        out["canflood"] = canflood_section(args.seconds, args.servos)
    out["wall_s"] = time.monotonic() - started
    print(json.dumps(out, indent=1, default=str))


if __name__ == "__main__":
    main()
