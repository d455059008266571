"""A simulated ArduPilot autopilot on a MAVLink link: what the bridge sees from a real one.

:class:`AutopilotStream` runs one bounded thread that, over any pymavlink connection string
(``udpout:`` to the bridge's ``udpin:`` port, or ``udpin:`` to wait for the bridge), sends as
sysid 1 / compid 1 with MAVLink 2 and the ardupilotmega dialect:

* HEARTBEAT 1 Hz (FIXED_WING, ARDUPILOTMEGA, MANUAL, standby), SYS_STATUS and ATTITUDE,
* SERVO_OUTPUT_RAW (port 0, all 16 channels, ``time_usec``) at the configured rate, 20 Hz by
  default like ArduPilot after SET_MESSAGE_INTERVAL; SET_MESSAGE_INTERVAL and REQUEST_MESSAGE
  from the companion are honoured and ACKed,
* the values of a scripted :mod:`mavservo.sim.autopilot.motion_scripts` profile, with
  DO_SET_SERVO / DO_REPEAT_SERVO / DO_SET_ACTUATOR sent as COMMAND_LONG (ACKs collected,
  MAVSDK-style retries) from a :class:`mavservo.config.autopilot_script.Script` or from calls
  made while it runs,
* a gimbal manager like ArduPilot's MNT1_TYPE 6 backend: MAV_CMD_REQUEST_MESSAGE(283) every
  second until the device at component 154 answers, then GIMBAL_DEVICE_SET_ATTITUDE and
  AUTOPILOT_STATE_FOR_GIMBAL_DEVICE at ~50 Hz,
* link drop-outs: nothing at all (heartbeats included) for N seconds.

It keeps what it commanded, with monotonic timestamps, so tests can compute tracking error
(:meth:`AutopilotStream.commanded_pwm`), and everything it received back
(:attr:`AutopilotStream.received`).

The stream is the MAVLink session (the link, what is sent when, the commands a companion
sends it); its parts each keep a state of their own and do no I/O: the message rates
(:mod:`.message_rates`), the servo outputs (:mod:`.servo_outputs`), the gimbal device search
and attitude (:mod:`.mount_driver`), the record of what was commanded (:mod:`.commanded`),
command retries and ACKs (:mod:`.command_tracker`) and what came back (:mod:`.recorder`).
"""

from __future__ import annotations

import math
import queue
import time
from collections import Counter, deque
from collections.abc import Iterable
from typing import Any

from mavservo.config import (
    Action,
    Dropout,
    Event,
    GimbalTarget,
    RepeatServo,
    Script,
    SetActuator,
    SetServo,
)
from mavservo.mavlink import mavlink2 as mav
from mavservo.sim.autopilot.autopilot_link import AutopilotLink
from mavservo.sim.autopilot.background import Background
from mavservo.sim.autopilot.can_forward import CanForwardLink
from mavservo.sim.autopilot.command_tracker import CommandRecord, CommandTracker
from mavservo.sim.autopilot.commanded import COMMANDED_KEEP, Commanded, CommandedLog
from mavservo.sim.autopilot.message_rates import MessageRates, interval_of
from mavservo.sim.autopilot.motion_scripts import Profile, get_profile
from mavservo.sim.autopilot.mount_driver import (
    ARDUPILOT_GIMBAL_SEARCH_S,
    REQUEST_INTERVAL_S,
    MountDriver,
)
from mavservo.sim.autopilot.recorder import Received
from mavservo.sim.autopilot.servo_outputs import ServoOutputs, normalized_outputs
from mavservo.threads import BackgroundLoop

# names the stream's users import from here, wherever they now live
__all__ = [
    "ARDUPILOT_GIMBAL_SEARCH_S",
    "ARDUPILOT_SERIAL1_SERVO_OUTPUT_HZ",
    "AutopilotStream",
    "BOOT_OFFSET_S",
    "COMMANDED_KEEP",
    "Commanded",
    "GIMBAL_DEVICE_INFORMATION_ID",
    "REQUEST_INTERVAL_S",
    "gimbal_demo_script",
    "normalized_outputs",
]

GIMBAL_DEVICE_INFORMATION_ID = 283
BOOT_OFFSET_S = 1.0  # the simulated autopilot "booted" this long before the stream starts
MAX_IDLE_WAIT_S = 0.01
#: SERVO_OUTPUT_RAW rate of current ArduPlane on SERIAL1 with default parameters (MAV2_RC_CHAN,
#: measured on a real SITL build): what a companion gets unless it asks with
#: SET_MESSAGE_INTERVAL. Pass it as ``servo_output_rate_hz`` to rehearse an unconfigured port.
ARDUPILOT_SERIAL1_SERVO_OUTPUT_HZ = 1.0
#: messages only the gimbal part sends, and only once the device is ready
_GIMBAL_STREAMS = ("GIMBAL_DEVICE_SET_ATTITUDE", "AUTOPILOT_STATE_FOR_GIMBAL_DEVICE")


class AutopilotStream(Background):
    """The simulated autopilot. ``start()`` launches the thread, ``stop()`` ends it (bounded)."""

    def __init__(
        self,
        url: str,
        profile: Profile | str = "sweep",
        script: Script | Iterable[Event] | None = None,
        *,
        system_id: int = 1,
        component_id: int = 1,
        servo_output_rate_hz: float = 20.0,
        actuator_output_status_hz: float = 0.0,
        heartbeat_hz: float = 1.0,
        sys_status_hz: float = 2.0,
        attitude_hz: float = 10.0,
        command_target: tuple[int, int] = (1, 0),
        gimbal: bool = False,
        gimbal_component: int = 154,
        gimbal_rate_hz: float = 50.0,
        wait_for_gimbal_device: bool = True,
        initial_gimbal: GimbalTarget | None = None,
        mirror_commands_in_output: bool = True,
        repeat_servo_cycle: str = "seconds",
        servo_trim: int = 1500,
        retry_interval_s: float = 0.5,
        max_attempts: int = 4,
        duration_s: float | None = None,
        connection_kwargs: dict[str, Any] | None = None,
        signing_key: bytes | None = None,
        keep: int = COMMANDED_KEEP,
        gimbal_search_s: tuple[float, float] | None = None,
        armed: bool = False,
        boot_offset_s: float = BOOT_OFFSET_S,
        can_forward: CanForwardLink | None = None,
    ) -> None:
        if repeat_servo_cycle not in ("seconds", "milliseconds"):
            raise ValueError("repeat_servo_cycle must be 'seconds' or 'milliseconds'")
        #: what was commanded when, bounded by ``keep`` per channel (refuses keep < 2)
        self.commanded = CommandedLog(keep)
        self.url = url
        self.script = script if isinstance(script, Script) else Script(script or ())
        self.system_id = system_id
        self.component_id = component_id
        self.command_target = command_target
        self.repeat_servo_cycle = repeat_servo_cycle
        self.duration_s = duration_s
        self._connection_kwargs = connection_kwargs or {}
        #: MAVLink 2 signing key (32 bytes): sign everything, as an autopilot set up with
        #: the same key as a signed bridge does, so a signed config can be rehearsed
        self.signing_key = signing_key
        self.armed = armed
        #: how long before the start the autopilot "booted" (a bridge started late sees a
        #: boot time of minutes)
        self.boot_offset_s = boot_offset_s

        #: message name -> interval; changed by SET_MESSAGE_INTERVAL, reset by a reboot
        self.rates = MessageRates(
            {
                "HEARTBEAT": interval_of(heartbeat_hz),
                "SYS_STATUS": interval_of(sys_status_hz),
                "ATTITUDE": interval_of(attitude_hz),
                "SERVO_OUTPUT_RAW": interval_of(servo_output_rate_hz),
                "ACTUATOR_OUTPUT_STATUS": interval_of(actuator_output_status_hz),
                "GIMBAL_DEVICE_SET_ATTITUDE": interval_of(gimbal_rate_hz) if gimbal else None,
                "AUTOPILOT_STATE_FOR_GIMBAL_DEVICE": (
                    interval_of(gimbal_rate_hz) if gimbal else None
                ),
            },
            unrequestable=_GIMBAL_STREAMS,
        )
        self.outputs = ServoOutputs(
            get_profile(profile) if isinstance(profile, str) else profile,
            servo_trim,
            mirror=mirror_commands_in_output,
        )
        #: the gimbal device: (from, until) seconds of boot time in which it is looked for,
        #: like ArduPilot (:data:`ARDUPILOT_GIMBAL_SEARCH_S`); None looks at any time
        self.mount = MountDriver(
            gimbal_component,
            enabled=gimbal,
            wait_for_device=wait_for_gimbal_device,
            search_s=gimbal_search_s,
            target=initial_gimbal,
        )

        #: bound of every record log below (per channel for the commanded values)
        self.keep = keep
        self.commands = CommandTracker(retry_interval_s, max_attempts, keep=keep)
        self.received = Received(keep=keep)
        #: the MAVLink connection; what was sent, counted per type and logged with its time
        self.link = AutopilotLink(system_id, component_id, keep=keep)
        self.sent: Counter[str] = self.link.sent
        self.sent_log: deque[tuple[float, str]] = self.link.sent_log
        self.dropouts: list[tuple[float, float]] = []
        #: CAN forwarding to a MAVLink client (MAV_CMD_CAN_FORWARD, CAN_FRAME), if it has a bus
        self.can_forward = can_forward
        if can_forward is not None:
            can_forward.send = lambda msg: self.link.message(time.monotonic(), msg)

        self._actions: queue.Queue[Action] = queue.Queue()
        self._dropout_until = 0.0
        #: monotonic time of the (last) boot: the origin of every boot time sent
        self._boot_at = 0.0
        self._reboot_after: float | None = None
        self.reboots = 0
        self._loop = BackgroundLoop(self._run, name="sitl-autopilot")
        self.t0: float | None = None
        self.error: BaseException | None = None

    @property
    def profile(self) -> Profile:
        """The motion script the servo outputs follow."""
        return self.outputs.profile

    @property
    def gimbal_device_info(self) -> Any | None:
        """The gimbal device's GIMBAL_DEVICE_INFORMATION (None: not found yet)."""
        return self.mount.device_info

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> AutopilotStream:
        """Open the link and start the thread; returns self so ``with ... .start()`` reads well."""
        if self.t0 is not None:  # one run per stream: its records and counters are that run's
            raise RuntimeError("stream already started")
        self.link.open(self.url, self.signing_key, **self._connection_kwargs)
        self.t0 = time.monotonic()
        self._boot_at = self.t0
        self._loop.start()
        return self

    def stop(self, timeout: float = 2.0) -> None:
        """Stop the thread (waits at most ``timeout``) and close the link."""
        self._loop.stop(timeout)
        self.link.close()

    def elapsed(self, now: float | None = None) -> float:
        """Seconds since start (the profile's time axis)."""
        if self.t0 is None:
            return 0.0
        return (time.monotonic() if now is None else now) - self.t0

    # ------------------------------------------------------------------ actions while running

    def dropout(self, seconds: float) -> None:
        """Go silent now for ``seconds``: no message of any kind leaves the autopilot."""
        self._actions.put(Dropout(seconds))

    def reboot(self, seconds: float = 1.0) -> None:
        """Reboot like a real autopilot: silent for ``seconds``, then boot time restarts from
        zero and every SET_MESSAGE_INTERVAL a companion sent is forgotten (rates back to the
        defaults given at construction)."""
        self._reboot_after = seconds  # picked up by the thread

    def set_servo(self, channel: int, pwm: int) -> None:
        self._actions.put(SetServo(channel, pwm))

    def repeat_servo(self, channel: int, pwm: int, count: int, cycle_s: float) -> None:
        self._actions.put(RepeatServo(channel, pwm, count, cycle_s))

    def set_actuator(self, values: Iterable[float | None], set_index: int = 0) -> None:
        """DO_SET_ACTUATOR; ``set_index`` is param 7 (0 = actuators 1..6, see SetActuator)."""
        vals = tuple(math.nan if v is None else float(v) for v in values)
        self._actions.put(SetActuator(vals, set_index))

    def set_gimbal(
        self, roll: float = 0.0, pitch: float = 0.0, yaw: float = 0.0, flags: int = 0
    ) -> None:
        self._actions.put(GimbalTarget(roll, pitch, yaw, flags))

    def interval_s(self, name: str) -> float | None:
        """The period this autopilot now sends ``name`` at (None: off), as SET_MESSAGE_INTERVAL
        and reboots left it."""
        return self.rates.interval_s(name)

    # ------------------------------------------------------------------ what was commanded

    def commanded_log(self, kind: str = "servo") -> list[Commanded]:
        """Changes in order; ``kind`` is "servo" (channels), "actuator" or "gimbal"."""
        return self.commanded.changes(kind)

    def commanded_pwm(self, channel: int, t: float) -> int | None:
        """PWM the autopilot was asking for on servo ``channel`` at monotonic time ``t``."""
        entry = self.commanded.at("servo", channel, t)
        return None if entry is None else entry.value

    def commanded_actuator(self, index: int, t: float) -> float | None:
        entry = self.commanded.at("actuator", index, t)
        return None if entry is None else entry.value

    def commanded_gimbal(self, t: float) -> tuple[float, float, float, int] | None:
        """(roll, pitch, yaw, flags) the gimbal was being sent at monotonic time ``t``."""
        entry = self.commanded.at("gimbal", 0, t)
        return None if entry is None else entry.value

    # ------------------------------------------------------------------ the thread

    def _run(self) -> None:
        assert self.t0 is not None
        self.rates.start(self.t0)
        try:
            while not self._loop.stopping:
                now = time.monotonic()
                t = now - self.t0
                if self.duration_s is not None and t >= self.duration_s:
                    break
                self._reboot_if_asked(now)
                self._drain_incoming(now)
                for event in self.script.due(t):
                    self._apply(event.action, now)
                while True:
                    try:
                        self._apply(self._actions.get_nowait(), now)
                    except queue.Empty:
                        break
                silent = now < self._dropout_until
                if self.can_forward is not None:
                    self.can_forward.pump(silent=silent)
                for name in self.rates.due(now):
                    if not silent:
                        self._send_periodic(name, now)
                if not silent:
                    for record in self.commands.due(now):
                        self._send_command(record)
                    self._gimbal_discovery(now)
                wake = self.rates.next_deadline(default=now + MAX_IDLE_WAIT_S)
                self.link.wait(min(max(wake - time.monotonic(), 0.0), MAX_IDLE_WAIT_S))
        except Exception as exc:  # surfaced to tests through .error instead of dying silently
            self.error = exc
            raise

    def _reboot_if_asked(self, now: float) -> None:
        seconds, self._reboot_after = self._reboot_after, None
        if seconds is None:
            return
        self._dropout_until = max(self._dropout_until, now + seconds)
        self._boot_at = now + seconds
        self.rates.reset()
        self.boot_offset_s = BOOT_OFFSET_S  # a fresh boot, disarmed
        self.armed = False
        self.reboots += 1
        if self.can_forward is not None:
            self.can_forward.reboot()

    # ------------------------------------------------------------------ actions

    def _apply(self, action: Action, now: float) -> None:
        target_sys, target_comp = self.command_target
        if isinstance(action, Dropout):
            self._dropout_until = max(self._dropout_until, now + action.seconds)
            self.dropouts.append((now, now + action.seconds))
        elif isinstance(action, SetServo):
            self.outputs.set_servo(action.channel, action.pwm)
            self.commands.submit(
                mav.MAV_CMD_DO_SET_SERVO,
                (action.channel, action.pwm, 0, 0, 0, 0, 0),
                target_sys,
                target_comp,
                now,
            )
            self.commanded.record(
                "servo", Commanded(now, action.channel, action.pwm, "do_set_servo")
            )
        elif isinstance(action, RepeatServo):
            self.outputs.repeat_servo(action, now)
            cycle = action.cycle_s * (1000.0 if self.repeat_servo_cycle == "milliseconds" else 1.0)
            self.commands.submit(
                mav.MAV_CMD_DO_REPEAT_SERVO,
                (action.channel, action.pwm, action.count, cycle, 0, 0, 0),
                target_sys,
                target_comp,
                now,
            )
            self.commanded.record(
                "servo", Commanded(now, action.channel, action.pwm, "do_repeat_servo")
            )
        elif isinstance(action, SetActuator):
            self.commands.submit(
                mav.MAV_CMD_DO_SET_ACTUATOR,
                (*action.values, float(action.set_index)),
                target_sys,
                target_comp,
                now,
            )
            for index, value in action.actuators().items():
                self.commanded.record("actuator", Commanded(now, index, value, "do_set_actuator"))
        elif isinstance(action, GimbalTarget):
            self.mount.target = action

    # ------------------------------------------------------------------ sending

    def _send_periodic(self, name: str, now: float) -> None:
        link = self.link
        boot_s = now - self._boot_at + self.boot_offset_s
        if name == "HEARTBEAT":
            link.heartbeat(now, self.armed)
        elif name == "SYS_STATUS":
            link.sys_status(now)
        elif name == "ATTITUDE":
            link.attitude(now, boot_s)
        elif name == "SERVO_OUTPUT_RAW":
            usec = int(boot_s * 1e6)
            # the profile is evaluated at the microsecond stamped into time_usec, so a receiver
            # can recompute exactly what was sent from the message alone
            frame = self.outputs.frame(usec / 1e6 - self.boot_offset_s, now)
            link.servo_output_raw(now, usec, frame)
            for channel, pwm in self.outputs.changes(frame):
                self.commanded.record("servo", Commanded(now, channel, pwm, "servo_output_raw"))
        elif name == "ACTUATOR_OUTPUT_STATUS":
            values, active = normalized_outputs(self.outputs.frame(self.elapsed(now), now))
            link.actuator_output_status(now, int(boot_s * 1e6), values, active)
        elif name == "GIMBAL_DEVICE_SET_ATTITUDE":
            if self.mount.ready():
                self._send_gimbal_target(now)
        elif name == "AUTOPILOT_STATE_FOR_GIMBAL_DEVICE":
            if self.mount.ready():
                link.autopilot_state_for_gimbal_device(now, int(boot_s * 1e6))
        else:
            raise AssertionError(f"no sender for {name}")

    def _send_gimbal_target(self, now: float) -> None:
        flags, q, rates = self.mount.attitude()
        self.link.gimbal_device_set_attitude(now, self.mount.component, flags, q, rates)
        target = self.mount.new_target()
        if target is not None:
            value = (target.roll, target.pitch, target.yaw, target.flags)
            self.commanded.record("gimbal", Commanded(now, 0, value, "gimbal"))

    def _gimbal_discovery(self, now: float) -> None:
        boot_s = now - self._boot_at + self.boot_offset_s
        if self.mount.request_due(now, boot_s, self.armed):
            params = (GIMBAL_DEVICE_INFORMATION_ID, 0, 0, 0, 0, 0, 0)
            target = (self.system_id, self.mount.component)
            self.link.command_long(now, target, mav.MAV_CMD_REQUEST_MESSAGE, params)

    def _send_command(self, record: CommandRecord) -> None:
        target = (record.target_system, record.target_component)
        self.link.command_long(record.sends[-1], target, record.command, record.params)

    # ------------------------------------------------------------------ receiving

    def _drain_incoming(self, now: float) -> None:
        for _ in range(1000):  # bounded: never starve the sending side
            msg = self.link.recv()
            if msg is None:
                return
            name = msg.get_type()
            if name == "BAD_DATA":
                continue
            self.received.add(now, msg)
            forward = self.can_forward
            if forward is not None and now >= self._boot_at and forward.take(msg):
                continue  # the CAN forward's (not while rebooting)
            if name == "COMMAND_ACK":
                if self._addressed_to_me(msg):
                    self.commands.on_ack(
                        msg.command,
                        msg.result,
                        (msg.get_srcSystem(), msg.get_srcComponent()),
                        (msg.target_system, msg.target_component),
                        now,
                    )
            elif name == "COMMAND_LONG":
                if self._addressed_to_me(msg) and now >= self._boot_at:  # not while rebooting
                    self._handle_command(msg, now)
            elif name == "GIMBAL_DEVICE_INFORMATION":
                self.mount.heard(msg)

    def _addressed_to_me(self, msg: Any) -> bool:
        return msg.target_system in (0, self.system_id) and msg.target_component in (
            0,
            self.component_id,
        )

    def _handle_command(self, msg: Any, now: float) -> None:
        """The few commands a companion sends an autopilot: message intervals and requests."""
        result, send_now = self.rates.on_command(msg.command, msg.param1, msg.param2)
        if send_now is not None:
            self._send_periodic(send_now, now)
        if now < self._dropout_until:
            return  # a silent link does not answer either
        target = (msg.get_srcSystem(), msg.get_srcComponent())
        self.link.command_ack(now, msg.command, result, target)


def gimbal_demo_script(start_s: float = 1.0, hold_s: float = 3.0) -> list[Event]:
    """Gimbal targets like the recorded ArduPlane session: pitch steps, yaw both ways, yaw lock."""
    steps = [
        (0, 0, 0, 0),
        (0, -30, 0, 0),
        (0, -60, 0, 0),
        (0, -90, 0, 0),
        (0, -30, -45, 0),
        (0, -30, 45, 0),
        (0, -30, -45, 28),
        (0, -30, 45, 28),
        (0, 0, 0, 0),
    ]
    return [
        Event(start_s + i * hold_s, GimbalTarget(float(r), float(p), float(y), f))
        for i, (r, p, y, f) in enumerate(steps)
    ]
