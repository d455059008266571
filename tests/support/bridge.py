"""Helpers for the end-to-end tests: a real bridge, a real MAVLink peer over UDP, recorders.

Everything here is a real part: the bridge listens on ``udpin:127.0.0.1:PORT``, the test-side
peer is a pymavlink connection that sends to it and collects what comes back on a bounded
thread, and the CAN side is the ``aa55`` interface talking to the adapter emulator over a pty.
Recorders only watch (scheduler observer hooks, wrapped simulated-servo methods); they never
change what the bridge does.
"""

from __future__ import annotations

import contextlib
import re
import subprocess
import sys
import threading
import time
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from mavservo.app.bridge import Bridge, free_udp_port
from mavservo.config import Config, load_config, load_config_text
from mavservo.mavlink.connection import mavlink2, open_connection
from mavservo.scheduling.runner import SchedulerObserver
from mavservo.sim.servo import SimServo
from tests.app.test_run_cli import REPO, assert_positions_followed, read_trace
from tests.support.waiting import wait_until

MAV_CMD_DO_SET_SERVO = 183
MAV_CMD_DO_SET_ACTUATOR = 187
MAV_RESULT_ACCEPTED = 0
MAV_RESULT_TEMPORARILY_REJECTED = 1
MAV_RESULT_DENIED = 2
MOTOR_ERROR = mavlink2.GIMBAL_DEVICE_ERROR_FLAGS_MOTOR_ERROR


def bridge_config(body: str, port: int, *, extra_mavlink: str = "") -> Config:
    """A config from YAML ``body`` (servos, channels, ...) with MAVLink on a UDP port.

    ``body`` must not contain a ``mavlink:`` section; ``extra_mavlink`` adds keys to it
    (indented by four spaces). The CAN side defaults to one aa55 bus on the emulator.
    """
    head = f"mavlink:\n  url: udpin:127.0.0.1:{port}\n{extra_mavlink}"
    return load_config_text(head + body, "<e2e>")


@dataclass
class Recorder(SchedulerObserver):
    """Scheduler observer: setpoints accepted and frames written, per servo, in order."""

    setpoints: dict[str, list[tuple[float, str]]] = field(default_factory=dict)
    tx: dict[str, list[tuple[str, int, bytes]]] = field(default_factory=dict)
    rx_count: dict[str, int] = field(default_factory=dict)
    lost: dict[str, int] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def on_setpoint(self, servo: str, seq: int, angle_deg: float, source: str, t: float) -> None:
        with self._lock:
            self.setpoints.setdefault(servo, []).append((angle_deg, source))

    def on_tx(self, bus: str, msg: Any, t: float, kind: str, servo: str, seq: int | None) -> None:
        with self._lock:
            self.tx.setdefault(servo, []).append((kind, msg.arbitration_id, bytes(msg.data)))

    def on_rx(self, bus: str, msg: Any, t: float, servo: str, state: Any) -> None:
        with self._lock:
            self.rx_count[servo] = self.rx_count.get(servo, 0) + 1

    def on_lost(self, bus: str, servo: str, t: float) -> None:
        with self._lock:
            self.lost[servo] = self.lost.get(servo, 0) + 1

    def angles(self, servo: str) -> list[float]:
        with self._lock:
            return [a for a, _ in self.setpoints.get(servo, [])]

    def frames(self, servo: str) -> list[tuple[str, int, bytes]]:
        with self._lock:
            return list(self.tx.get(servo, []))


class ServoSpy:
    """Wraps one simulated servo's ``receive`` and ``command_position`` to record what it got.

    ``frames``: (arbitration id, data) of every frame the servo's device accepted;
    ``targets``: every angle it was commanded to. Instance attributes shadow the methods, so the
    servo behaves exactly as before.
    """

    def __init__(self, servo: SimServo) -> None:
        self.servo = servo
        self.frames: list[tuple[int, bytes, int]] = []
        self.targets: list[float] = []
        self.malformed: list[Any] = []
        receive, command = servo.receive, servo.command_position
        device = servo._device  # noqa: SLF001 - the spy needs the device's own accept test

        def spy_receive(msg: Any, now: float) -> Any:
            if not msg.is_remote_frame and device.accepts(msg):
                if (
                    len(msg.data) > 8
                    or msg.dlc != len(msg.data)
                    or (not msg.is_extended_id and msg.arbitration_id > 0x7FF)
                ):
                    self.malformed.append(msg)
                self.frames.append((msg.arbitration_id, bytes(msg.data), len(msg.data)))
            return receive(msg, now)

        def spy_command(angle_deg: float, *args: Any, **kwargs: Any) -> None:
            self.targets.append(angle_deg)
            command(angle_deg, *args, **kwargs)

        servo.receive = spy_receive  # type: ignore[method-assign]
        servo.command_position = spy_command  # type: ignore[method-assign]


def sim_servo(bridge: Bridge, name: str) -> SimServo:
    """The simulated device behind servo ``name`` (matched by bus, profile and CAN id)."""
    cfg = bridge.config.servo(name)
    bus = bridge.config.bus_of(cfg).name
    for servo in bridge.emulators[bus].servos:
        if servo.profile == cfg.profile and servo.can_id == cfg.can_id:
            return servo
    raise KeyError(name)


def status(bridge: Bridge, name: str) -> Any:
    """The bridge's current status of servo ``name`` (online, last state, ...)."""
    return next(s for s in bridge.backend.servo_statuses() if s.name == name)


class Peer:
    """A MAVLink peer of the bridge on UDP: sends as any (system, component), collects replies.

    One socket for every identity, because the bridge's ``udpin`` answers the last sender's
    address. The receive thread runs until :meth:`close` (each wait is bounded).
    """

    def __init__(self, port: int, system: int = 255, component: int = 190) -> None:
        self.conn = open_connection(
            f"udpout:127.0.0.1:{port}", source_system=system, source_component=component
        )
        self.received: list[Any] = []
        self._lock = threading.Lock()
        self._send_lock = threading.Lock()
        self._stop = threading.Event()
        self._heartbeat: threading.Thread | None = None
        self._heartbeat_stop = threading.Event()
        self._reader = threading.Thread(target=self._read, name="e2e-peer", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.conn.recv_match(blocking=True, timeout=0.05)
            except OSError:  # no one listening yet: ICMP refusals on an unconnected port
                self._stop.wait(0.05)
                continue
            if msg is not None and msg.get_type() != "BAD_DATA":
                with self._lock:
                    self.received.append(msg)

    def send(self, msg: Any, system: int = 255, component: int = 190) -> None:
        with self._send_lock:
            mav = self.conn.mav
            mav.srcSystem, mav.srcComponent = system, component
            with contextlib.suppress(OSError):
                self.conn.write(msg.pack(mav))

    def autopilot_heartbeat(self) -> None:
        self.send(mavlink2.MAVLink_heartbeat_message(1, 3, 81, 0, 3, 3), 1, 1)

    def gcs_heartbeat(self) -> None:
        """One HEARTBEAT as a GCS (6/8), so the bridge answers (STATUSTEXT, telemetry) to us."""
        self.send(mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))

    def start_heartbeats(self, period_s: float = 0.2) -> None:
        """Act as the autopilot (1/1): HEARTBEAT every ``period_s`` until stopped."""
        self._heartbeat_stop.clear()

        def beat() -> None:
            while not self._heartbeat_stop.is_set() and not self._stop.is_set():
                self.autopilot_heartbeat()
                self._heartbeat_stop.wait(period_s)

        self._heartbeat = threading.Thread(target=beat, name="e2e-heartbeat", daemon=True)
        self._heartbeat.start()

    def stop_heartbeats(self) -> None:
        self._heartbeat_stop.set()
        if self._heartbeat is not None:
            self._heartbeat.join(2.0)
            self._heartbeat = None

    def messages(self, kind: str | None = None) -> list[Any]:
        with self._lock:
            return [m for m in self.received if kind is None or m.get_type() == kind]

    def count(self) -> int:
        with self._lock:
            return len(self.received)

    def since(self, start: int, kind: str | None = None) -> list[Any]:
        with self._lock:
            return [m for m in self.received[start:] if kind is None or m.get_type() == kind]

    def statustexts(self, start: int = 0) -> list[str]:
        return [m.text for m in self.since(start, "STATUSTEXT")]

    def joined_statustexts(self, start: int = 0) -> str:
        """Every STATUSTEXT since ``start`` in one string, a long text's chunks joined as a
        ground station joins them (a chunk broken between words loses its padding)."""
        from mavservo.mavlink import join_statustext_chunks

        return join_statustext_chunks(self.statustexts(start))

    def command(
        self,
        command: int,
        params: Sequence[float],
        *,
        target: tuple[int, int] = (1, 140),
        timeout: float = 3.0,
        retry_s: float = 0.5,
    ) -> int | None:
        """COMMAND_LONG as a GCS would send it, retried until ACKed; the ACK result or None."""
        padded = list(params) + [0.0] * (7 - len(params))
        msg = mavlink2.MAVLink_command_long_message(target[0], target[1], command, 0, *padded)
        deadline = time.monotonic() + timeout
        start = self.count()
        while time.monotonic() < deadline:
            self.send(msg)
            ack = None

            def got_ack(start: int = start) -> bool:
                nonlocal ack
                for m in self.since(start, "COMMAND_ACK"):
                    if m.command == command and m.get_srcComponent() == target[1]:
                        ack = m
                        return True
                return False

            if wait_until(got_ack, min(retry_s, max(0.0, deadline - time.monotonic()))):
                return int(ack.result)
        return None

    def close(self) -> None:
        self.stop_heartbeats()
        self._stop.set()
        self._reader.join(2.0)
        self.conn.close()


@contextlib.contextmanager
def running(
    body: str, *, extra_mavlink: str = "", observers: Sequence[Any] = ()
) -> Iterator[tuple[Bridge, int]]:
    """A started bridge for ``body`` on a fresh UDP port; stopped (and summarised) on exit."""
    port = free_udp_port()
    config = bridge_config(body, port, extra_mavlink=extra_mavlink)
    bridge = Bridge(config, log_dir=False, observers=observers).start()
    try:
        yield bridge, port
    finally:
        bridge.stop()


def gimbal_config(pitch_profile: str, yaw_profile: str, yaw_options: str = "") -> str:
    """Config body for a two-axis gimbal (component 154): pitch on CAN id 1 (-90..30 deg), yaw
    on CAN id 2 (-160..160 deg), gimbal status at 20 Hz and no other telemetry, so a family's
    fault test sees GIMBAL_DEVICE_ATTITUDE_STATUS. ``yaw_options``: YAML flow text for the yaw
    servo's ``options``, empty for none."""
    options = f",\n     options: {yaw_options}" if yaw_options else ""
    return f"""
  telemetry: {{gimbal_attitude_status_hz: 20, named_value_float_hz: 0, esc_telemetry_hz: 0,
              actuator_output_status_hz: 0}}
  mirror: {{servo_output_raw: false}}
servos:
  - {{name: pitch, profile: {pitch_profile}, can_id: 1, limits_deg: [-90, 30], telemetry_hz: 20}}
  - {{name: yaw, profile: {yaw_profile}, can_id: 2, limits_deg: [-160, 160],
     telemetry_hz: 20{options}}}
gimbals:
  - {{name: gimbal, component_id: 154, pitch: pitch, yaw: yaw,
     limits_deg: {{pitch: [-90, 30], yaw: [-160, 160]}}}}
scheduler: {{reply_timeout_s: 0.5, command_period_s: 0.02, telemetry_period_s: 0.05}}
"""


def assert_fault_reaches_statustext_and_gimbal_flags(
    bridge: Bridge, peer: Peer, axis: str, fault: str, text: str, wait_s: float
) -> None:
    """Once ``axis`` is online, set its simulated ``fault``: STATUSTEXT ``servo AXIS fault TEXT``
    and the MOTOR_ERROR gimbal failure flag must both reach ``peer``. The body every family's
    gimbal fault test shares; the family test brings the axis up its own way first."""
    assert wait_until(lambda: status(bridge, axis).online, wait_s)
    mark = peer.count()
    setattr(sim_servo(bridge, axis).faults, fault, True)
    assert wait_until(lambda: f"servo {axis} fault {text}" in peer.statustexts(mark), wait_s), (
        peer.statustexts(mark)
    )
    assert wait_until(
        lambda: any(
            m.failure_flags & MOTOR_ERROR for m in peer.since(mark, "GIMBAL_DEVICE_ATTITUDE_STATUS")
        ),
        wait_s,
    )


def assert_servos_follow_pwm(
    bridge: Bridge,
    peer: Peer,
    servos: dict[str, tuple[int, int]],
    pwm: int,
    resolution_deg: float,
    wait_s: float,
) -> None:
    """DO_SET_SERVO ``pwm`` on each servo's channel (``servos``: name -> (NAMED_VALUE_FLOAT
    index, channel), every channel 1000..2000 us onto -90..90 deg): each is ACCEPTED, every
    simulated servo settles on the target, and the last reported positions match the servo
    within ``resolution_deg``."""
    target = pwm_to_angle(pwm, 1000, 2000, (-90, 90))
    for name, (_, channel) in servos.items():
        result = peer.command(MAV_CMD_DO_SET_SERVO, [channel, pwm])
        assert result == MAV_RESULT_ACCEPTED, name
    sims = {name: sim_servo(bridge, name) for name in servos}
    assert wait_until(
        lambda s=sims, t=target: all(
            abs(x.position_deg - t) < 0.05 and abs(x.velocity_dps) < 0.1 for x in s.values()
        ),
        wait_s,
    ), {n: s.position_deg for n, s in sims.items()}
    mark = peer.count()
    assert wait_until(
        lambda m=mark: all(
            len(named_values(peer.since(m), f"s{n}_pos")) >= 3 for n, _ in servos.values()
        ),
        wait_s,
    )
    for name, (n, _) in servos.items():
        for value in named_values(peer.since(mark), f"s{n}_pos")[-2:]:
            assert abs(value - sims[name].position_deg) <= resolution_deg, name


def assert_nothing_lost(summary: dict[str, Any], servos: Iterable[str]) -> None:
    """The bridge's stop summary: each of ``servos`` sent and received frames, none lost or
    rejected, and the bus rejected nothing."""
    for name in servos:
        frames = summary["servos"][name]["frames"]
        assert frames["sent"] > 0 and frames["received"] > 0, name
        assert frames["lost"] == 0 and frames["rejected"] == 0, (name, frames)
    assert summary["buses"]["bus0"]["bus_rejected"] == 0


class ExampleRun:
    """``mavservo run`` on the shipped ``config/CONFIG_NAME`` for 8 s on the built-in
    simulation, started at construction in a child process of its own; judged once it ended by
    :meth:`assert_follows_and_loses_nothing`: it exits cleanly, every servo's summary row shows
    frames both ways with none lost or rejected, and every servo follows the simulated
    autopilot's sweep in the trace.

    The example as shipped, except that a reply counts as lost only when it never comes: a
    loaded test machine can delay one past the 50 ms default, and timing is not judged here.
    Several can run side by side (each its own config copy, log directory and output files),
    so a test module can start all of its examples at once and judge each in its own test.
    """

    def __init__(self, config_name: str, tmp_path: Path) -> None:
        tmp_path.mkdir(parents=True, exist_ok=True)
        document = yaml.safe_load((REPO / "config" / config_name).read_text())
        document["scheduler"]["reply_timeout_s"] = 0.5
        document["logging"]["dir"] = str(tmp_path / "runs")
        self.path = tmp_path / config_name
        self.path.write_text(yaml.safe_dump(document))
        self.logs = tmp_path / "runs"
        self._out = tmp_path / "stdout.txt"
        self._err = tmp_path / "stderr.txt"
        command = [sys.executable, "-m", "mavservo", "run", "--config", str(self.path)]
        command += ["--duration", "8", "--log-dir", str(self.logs)]
        with self._out.open("w") as out, self._err.open("w") as err:
            self.proc = subprocess.Popen(command, stdout=out, stderr=err, text=True, cwd=REPO)

    def wait(self) -> None:
        """Until the run ended by itself (its 8 s and the summary), at most 60 s."""
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.proc.wait(timeout=60)

    def kill(self) -> None:
        """Ends the run if it is still going (a test that failed before judging it)."""
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)

    def assert_follows_and_loses_nothing(self) -> None:
        try:
            returncode = self.proc.wait(timeout=60)
        finally:
            self.kill()
        stderr = self._err.read_text()
        assert returncode == 0, stderr
        assert "Traceback" not in stderr
        out = self._out.read_text()
        assert "decoder rejections 0" in out
        config = load_config(self.path)
        for servo in config.servos:
            # columns: sent, recv, pushed, offline, lost, late, rej (a pushing servo's pushed is
            # not lost)
            row = re.search(rf"^\s+{servo.name}" + r"\s+(\d+)" * 7, out, re.M)
            assert row, f"no summary row for {servo.name}:\n{out}"
            sent, received, _pushed, _offline, lost, _late, rejected = map(int, row.groups())
            assert sent > 0 and received > 0, row.group(0)
            assert lost == 0 and rejected == 0, row.group(0)
        [run_dir] = list(self.logs.iterdir())
        trace = read_trace(run_dir / "trace.csv")
        for servo in config.servos:
            # the simulated autopilot sweeps every servo of these configs: each one follows
            assert_positions_followed(servo.name, trace, span=20.0)


def named_values(messages: Sequence[Any], name: str) -> list[float]:
    """Values of NAMED_VALUE_FLOAT ``name`` in arrival order."""
    return [m.value for m in messages if m.get_type() == "NAMED_VALUE_FLOAT" and m.name == name]


def pwm_to_angle(pwm: float, low_us: float, high_us: float, out: tuple[float, float]) -> float:
    """Linear map of a PWM range onto an angle range (trim in the middle), computed here, not
    with the project's mapping, so the tests check it."""
    fraction = (pwm - low_us) / (high_us - low_us)
    return out[0] + fraction * (out[1] - out[0])


__all__ = [
    "MAV_CMD_DO_SET_ACTUATOR",
    "MAV_CMD_DO_SET_SERVO",
    "MAV_RESULT_DENIED",
    "MAV_RESULT_ACCEPTED",
    "MAV_RESULT_TEMPORARILY_REJECTED",
    "MOTOR_ERROR",
    "Peer",
    "ExampleRun",
    "Recorder",
    "ServoSpy",
    "assert_fault_reaches_statustext_and_gimbal_flags",
    "assert_nothing_lost",
    "assert_servos_follow_pwm",
    "bridge_config",
    "gimbal_config",
    "named_values",
    "pwm_to_angle",
    "running",
    "sim_servo",
    "status",
]
