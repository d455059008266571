"""A simulated ArduPilot autopilot on a MAVLink link: what the bridge sees from a real one.

:class:`AutopilotStream` runs one bounded thread that, over any pymavlink connection string
(``udpout:`` to the bridge's ``udpin:`` port, or ``udpin:`` to wait for the bridge), sends as
sysid 1 / compid 1 with MAVLink 2 and the ardupilotmega dialect:

* HEARTBEAT 1 Hz (FIXED_WING, ARDUPILOTMEGA, MANUAL, standby), SYS_STATUS and ATTITUDE,
* SERVO_OUTPUT_RAW (port 0, all 16 channels, ``time_usec``) at the configured rate, 20 Hz by
  default like ArduPilot after SET_MESSAGE_INTERVAL; SET_MESSAGE_INTERVAL and REQUEST_MESSAGE
  from the companion are honoured and ACKed,
* the values of a scripted :mod:`mavservo.sim.autopilot.motion_scripts` profile, with DO_SET_SERVO /
DO_REPEAT_SERVO /
  DO_SET_ACTUATOR sent as COMMAND_LONG (ACKs collected, MAVSDK-style retries) from a
  :class:`mavservo.config.autopilot_script.Script` or from calls made while it runs,
* a gimbal manager like ArduPilot's MNT1_TYPE 6 backend: MAV_CMD_REQUEST_MESSAGE(283) every
  second until the device at component 154 answers, then GIMBAL_DEVICE_SET_ATTITUDE and
  AUTOPILOT_STATE_FOR_GIMBAL_DEVICE at ~50 Hz,
* link drop-outs: nothing at all (heartbeats included) for N seconds.

It keeps what it commanded, with monotonic timestamps, so tests can compute tracking error
(:meth:`AutopilotStream.commanded_pwm`), and everything it received back
(:attr:`AutopilotStream.received`).
"""

from __future__ import annotations

import math
import queue
import select
import threading
import time
from bisect import bisect_right
from collections import Counter, deque
from collections.abc import Iterable
from dataclasses import dataclass
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
    repeat_servo_value,
)
from mavservo.mavlink import euler_to_quaternion, open_connection
from mavservo.mavlink import mavlink2 as mav
from mavservo.sim.autopilot.background import Background
from mavservo.sim.autopilot.command_tracker import CommandRecord, CommandTracker
from mavservo.sim.autopilot.motion_scripts import (
    SURFACE_MAX,
    SURFACE_MIN,
    SURFACE_TRIM,
    THROTTLE_CHANNEL,
    THROTTLE_MAX,
    THROTTLE_MIN,
    Profile,
    get_profile,
)
from mavservo.sim.autopilot.recorder import Received
from mavservo.threads import BackgroundLoop

GIMBAL_DEVICE_INFORMATION_ID = 283
REQUEST_INTERVAL_S = 1.0  # ArduPilot re-asks the gimbal device for its information every second
BOOT_OFFSET_S = 1.0  # the simulated autopilot "booted" this long before the stream starts
#: ArduPilot's MAVLink gimbal driver looks for a gimbal from 10 s after boot and stops past
#: 60 s once armed (libraries/AP_Mount/AP_Mount_Gremsy.cpp, find_gimbal, master 3d099b0)
ARDUPILOT_GIMBAL_SEARCH_S = (10.0, 60.0)
MAX_IDLE_WAIT_S = 0.01
#: SERVO_OUTPUT_RAW rate of current ArduPlane on SERIAL1 with default parameters (MAV2_RC_CHAN,
#: measured on a real SITL build): what a companion gets unless it asks with
#: SET_MESSAGE_INTERVAL. Pass it as ``servo_output_rate_hz`` to rehearse an unconfigured port.
ARDUPILOT_SERIAL1_SERVO_OUTPUT_HZ = 1.0


@dataclass(frozen=True, slots=True)
class Commanded:
    """One change of what the autopilot asked for: a SERVO_OUTPUT_RAW value or a command."""

    t: float  # time.monotonic() when it first went out
    key: int  # servo channel (1-based), actuator index (1-based), or 0 for the gimbal
    value: Any  # PWM us, normalized float, or (roll, pitch, yaw, flags)
    source: str  # "servo_output_raw", "do_set_servo", "do_repeat_servo", "do_set_actuator", ...


#: Records kept by default (``keep``): commanded values per channel for
#: :meth:`AutopilotStream.commanded_pwm` lookups (about 17 minutes of changes at 20 Hz, 7 at
#: 50 Hz), sent messages, received messages, commands and ACKs. Older commanded values are
#: dropped in halves (amortised O(1)). A process that only streams (``python -m
#: mavservo.sim.autopilot stream``,
#: the soak's autopilot) asks for far fewer, so its memory is flat within a minute.
COMMANDED_KEEP = 20_000


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
    ) -> None:
        if repeat_servo_cycle not in ("seconds", "milliseconds"):
            raise ValueError("repeat_servo_cycle must be 'seconds' or 'milliseconds'")
        if keep < 2:
            raise ValueError("keep must be >= 2")
        self.url = url
        self.profile = get_profile(profile) if isinstance(profile, str) else profile
        self.script = script if isinstance(script, Script) else Script(script or ())
        self.system_id = system_id
        self.component_id = component_id
        self.command_target = command_target
        self.gimbal_enabled = gimbal
        self.gimbal_component = gimbal_component
        self.wait_for_gimbal_device = wait_for_gimbal_device
        self.mirror_commands_in_output = mirror_commands_in_output
        self.repeat_servo_cycle = repeat_servo_cycle
        self.servo_trim = servo_trim
        self.duration_s = duration_s
        self._connection_kwargs = connection_kwargs or {}
        #: MAVLink 2 signing key (32 bytes): sign everything, as an autopilot set up with
        #: the same key as a signed bridge does, so a signed config can be rehearsed
        self.signing_key = signing_key
        #: (from, until) seconds of boot time in which the gimbal is looked for, like
        #: ArduPilot (:data:`ARDUPILOT_GIMBAL_SEARCH_S`): past ``until`` only while disarmed;
        #: None looks at any time
        self.gimbal_search_s = gimbal_search_s
        self.armed = armed
        #: how long before the start the autopilot "booted" (a bridge started late sees a
        #: boot time of minutes)
        self.boot_offset_s = boot_offset_s

        # message name -> interval in seconds (None = off); changed by SET_MESSAGE_INTERVAL
        self._defaults: dict[str, float | None] = {
            "HEARTBEAT": _interval(heartbeat_hz),
            "SYS_STATUS": _interval(sys_status_hz),
            "ATTITUDE": _interval(attitude_hz),
            "SERVO_OUTPUT_RAW": _interval(servo_output_rate_hz),
            "ACTUATOR_OUTPUT_STATUS": _interval(actuator_output_status_hz),
            "GIMBAL_DEVICE_SET_ATTITUDE": _interval(gimbal_rate_hz) if gimbal else None,
            "AUTOPILOT_STATE_FOR_GIMBAL_DEVICE": _interval(gimbal_rate_hz) if gimbal else None,
        }
        self._intervals = dict(self._defaults)

        #: bound of every record log below (per channel for the commanded values)
        self.keep = keep
        self.commands = CommandTracker(retry_interval_s, max_attempts, keep=keep)
        self.received = Received(keep=keep)
        self.sent: Counter[str] = Counter()
        self.sent_log: deque[tuple[float, str]] = deque(maxlen=keep)
        self.dropouts: list[tuple[float, float]] = []
        self.gimbal_device_info: Any | None = None

        self._lock = threading.Lock()
        self._commanded: dict[tuple[str, int], list[Commanded]] = {}
        self._commanded_times: dict[tuple[str, int], list[float]] = {}  # for bisect
        self._actions: queue.Queue[Action] = queue.Queue()
        self._overrides: dict[int, int] = {}
        self._repeats: dict[int, tuple[RepeatServo, float]] = {}
        self._last_output: tuple[int, ...] | None = None
        self._gimbal_target = initial_gimbal or GimbalTarget()
        self._gimbal_logged: GimbalTarget | None = None
        self._dropout_until = 0.0
        #: monotonic time of the (last) boot: the origin of every boot time sent
        self._boot_at = 0.0
        self._reboot_after: float | None = None
        self.reboots = 0
        self._next_request = 0.0
        self._loop = BackgroundLoop(self._run, name="sitl-autopilot")
        self._conn: Any = None
        self.t0: float | None = None
        self.error: BaseException | None = None

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> AutopilotStream:
        """Open the link and start the thread; returns self so ``with ... .start()`` reads well."""
        if self.t0 is not None:  # one run per stream: its records and counters are that run's
            raise RuntimeError("stream already started")
        self._conn = open_connection(
            self.url,
            source_system=self.system_id,
            source_component=self.component_id,
            **self._connection_kwargs,
        )
        if self.signing_key is not None:
            # accept the bridge's unsigned replies too: this side only plays the autopilot
            self._conn.setup_signing(
                self.signing_key, sign_outgoing=True, allow_unsigned_callback=lambda *_: True
            )
        self.t0 = time.monotonic()
        self._boot_at = self.t0
        self._loop.start()
        return self

    def stop(self, timeout: float = 2.0) -> None:
        """Stop the thread (waits at most ``timeout``) and close the link."""
        self._loop.stop(timeout)
        if self._conn is not None:
            self._conn.close()
            self._conn = None

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
        return self._intervals.get(name)

    # ------------------------------------------------------------------ what was commanded

    def commanded_log(self, kind: str = "servo") -> list[Commanded]:
        """Changes in order; ``kind`` is "servo" (channels), "actuator" or "gimbal"."""
        with self._lock:
            return sorted(
                (c for (k, _), log in self._commanded.items() if k == kind for c in log),
                key=lambda c: c.t,
            )

    def commanded_pwm(self, channel: int, t: float) -> int | None:
        """PWM the autopilot was asking for on servo ``channel`` at monotonic time ``t``."""
        entry = self._lookup("servo", channel, t)
        return None if entry is None else entry.value

    def commanded_actuator(self, index: int, t: float) -> float | None:
        entry = self._lookup("actuator", index, t)
        return None if entry is None else entry.value

    def commanded_gimbal(self, t: float) -> tuple[float, float, float, int] | None:
        """(roll, pitch, yaw, flags) the gimbal was being sent at monotonic time ``t``."""
        entry = self._lookup("gimbal", 0, t)
        return None if entry is None else entry.value

    def _lookup(self, kind: str, key: int, t: float) -> Commanded | None:
        with self._lock:
            log = self._commanded.get((kind, key), [])
            i = bisect_right(self._commanded_times.get((kind, key), []), t)
            return log[i - 1] if i else None

    def _record(self, kind: str, entry: Commanded) -> None:
        with self._lock:
            log = self._commanded.setdefault((kind, entry.key), [])
            times = self._commanded_times.setdefault((kind, entry.key), [])
            log.append(entry)
            times.append(entry.t)
            if len(log) > self.keep:  # long runs (soak, `url: sim`) stay bounded
                drop = len(log) - self.keep // 2
                del log[:drop], times[:drop]

    # ------------------------------------------------------------------ the thread

    def _run(self) -> None:
        assert self.t0 is not None
        next_due = {name: self.t0 for name, iv in self._intervals.items() if iv}
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
                for name, interval in self._intervals.items():
                    if interval is None:
                        next_due.pop(name, None)
                        continue
                    due = next_due.setdefault(name, now)
                    if now >= due:
                        if not silent:
                            self._send_periodic(name, now)
                        # absolute deadlines; after a stall, skip ahead instead of bursting
                        next_due[name] = due + interval if now - due < interval else now + interval
                if not silent:
                    for record in self.commands.due(now):
                        self._send_command(record)
                    self._gimbal_discovery(now)
                wake = min(next_due.values(), default=now + MAX_IDLE_WAIT_S)
                self._wait(min(max(wake - time.monotonic(), 0.0), MAX_IDLE_WAIT_S))
        except Exception as exc:  # surfaced to tests through .error instead of dying silently
            self.error = exc
            raise

    def _reboot_if_asked(self, now: float) -> None:
        seconds, self._reboot_after = self._reboot_after, None
        if seconds is None:
            return
        self._dropout_until = max(self._dropout_until, now + seconds)
        self._boot_at = now + seconds
        self._intervals = dict(self._defaults)
        self.boot_offset_s = BOOT_OFFSET_S  # a fresh boot, disarmed
        self.armed = False
        self.reboots += 1

    def _wait(self, timeout: float) -> None:
        port = getattr(self._conn, "port", None)
        if port is None:  # not a socket or serial connection (closed, or a file)
            time.sleep(timeout)
            return
        try:
            select.select([port], [], [], timeout)
        except (TypeError, ValueError, OSError):
            time.sleep(timeout)

    # ------------------------------------------------------------------ actions

    def _apply(self, action: Action, now: float) -> None:
        target_sys, target_comp = self.command_target
        if isinstance(action, Dropout):
            self._dropout_until = max(self._dropout_until, now + action.seconds)
            self.dropouts.append((now, now + action.seconds))
        elif isinstance(action, SetServo):
            self._repeats.pop(action.channel, None)
            if self.mirror_commands_in_output:
                self._overrides[action.channel] = action.pwm
            self.commands.submit(
                mav.MAV_CMD_DO_SET_SERVO,
                (action.channel, action.pwm, 0, 0, 0, 0, 0),
                target_sys,
                target_comp,
                now,
            )
            self._record("servo", Commanded(now, action.channel, action.pwm, "do_set_servo"))
        elif isinstance(action, RepeatServo):
            if self.mirror_commands_in_output:
                self._repeats[action.channel] = (action, now)
            cycle = action.cycle_s * (1000.0 if self.repeat_servo_cycle == "milliseconds" else 1.0)
            self.commands.submit(
                mav.MAV_CMD_DO_REPEAT_SERVO,
                (action.channel, action.pwm, action.count, cycle, 0, 0, 0),
                target_sys,
                target_comp,
                now,
            )
            self._record("servo", Commanded(now, action.channel, action.pwm, "do_repeat_servo"))
        elif isinstance(action, SetActuator):
            self.commands.submit(
                mav.MAV_CMD_DO_SET_ACTUATOR,
                (*action.values, float(action.set_index)),
                target_sys,
                target_comp,
                now,
            )
            for index, value in action.actuators().items():
                self._record("actuator", Commanded(now, index, value, "do_set_actuator"))
        elif isinstance(action, GimbalTarget):
            self._gimbal_target = action

    # ------------------------------------------------------------------ sending

    def _send(self, name: str, now: float, send: Any, *args: Any) -> None:
        send(*args)
        self.sent[name] += 1
        self.sent_log.append((now, name))

    def _output_frame(self, now: float, profile_t: float | None = None) -> tuple[int, ...]:
        """The 16 outputs at ``now``; ``profile_t`` (stream seconds) overrides the profile's
        time so it can be the exact time stamped into the message."""
        if profile_t is None:
            profile_t = now - self.t0  # type: ignore[operator]
        frame = list(self.profile.pwm(profile_t))
        for channel, pwm in self._overrides.items():
            frame[channel - 1] = pwm
        for channel, (action, started) in list(self._repeats.items()):
            pwm, finished = repeat_servo_value(action, now - started, self.servo_trim)
            frame[channel - 1] = pwm
            if finished:
                del self._repeats[channel]
                self._overrides[channel] = pwm
        return tuple(frame)

    def _send_periodic(self, name: str, now: float) -> None:
        m = self._conn.mav
        boot_s = now - self._boot_at + self.boot_offset_s
        if name == "HEARTBEAT":
            self._send(
                name,
                now,
                m.heartbeat_send,
                mav.MAV_TYPE_FIXED_WING,
                mav.MAV_AUTOPILOT_ARDUPILOTMEGA,
                81 | (mav.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0),
                0,
                mav.MAV_STATE_STANDBY,
                3,
            )
        elif name == "SYS_STATUS":
            sensors = 0x0020FC2F
            self._send(
                name,
                now,
                m.sys_status_send,
                sensors,
                sensors,
                sensors,
                120,
                12600,
                150,
                95,
                0,
                0,
                0,
                0,
                0,
                0,
            )
        elif name == "ATTITUDE":
            wobble = 0.02 * math.sin(0.5 * boot_s)
            self._send(
                name,
                now,
                m.attitude_send,
                int(boot_s * 1000) & 0xFFFFFFFF,
                wobble,
                -wobble / 2,
                -0.12,
                0.0,
                0.0,
                0.0,
            )
        elif name == "SERVO_OUTPUT_RAW":
            usec = int(boot_s * 1e6)
            # the profile is evaluated at the microsecond stamped into time_usec, so a receiver
            # can recompute exactly what was sent from the message alone
            frame = self._output_frame(now, profile_t=usec / 1e6 - self.boot_offset_s)
            self._send(name, now, m.servo_output_raw_send, usec & 0xFFFFFFFF, 0, *frame)
            previous = self._last_output
            for channel, pwm in enumerate(frame, start=1):
                if previous is None or previous[channel - 1] != pwm:
                    self._record("servo", Commanded(now, channel, pwm, "servo_output_raw"))
            self._last_output = frame
        elif name == "ACTUATOR_OUTPUT_STATUS":
            values, active = normalized_outputs(self._output_frame(now))
            self._send(name, now, m.actuator_output_status_send, int(boot_s * 1e6), active, values)
        elif name == "GIMBAL_DEVICE_SET_ATTITUDE":
            if self._gimbal_ready():
                self._send_gimbal_target(now)
        elif name == "AUTOPILOT_STATE_FOR_GIMBAL_DEVICE" and self._gimbal_ready():
            q = euler_to_quaternion(0.0, 0.0, -7.0)
            self._send(
                name,
                now,
                m.autopilot_state_for_gimbal_device_send,
                self.system_id,
                0,
                int(boot_s * 1e6),
                q,
                0,
                0.0,
                0.0,
                0.0,
                0,
                0.0,
                41791,
                0,
                0.0,
            )
        elif name not in ("GIMBAL_DEVICE_SET_ATTITUDE", "AUTOPILOT_STATE_FOR_GIMBAL_DEVICE"):
            raise AssertionError(f"no sender for {name}")

    def _gimbal_ready(self) -> bool:
        return self.gimbal_device_info is not None or not self.wait_for_gimbal_device

    def _send_gimbal_target(self, now: float) -> None:
        target = self._gimbal_target
        nan = math.nan
        if target.flags & mav.GIMBAL_DEVICE_FLAGS_RETRACT:
            q, rates = (nan, nan, nan, nan), (0.0, 0.0, 0.0)
        else:
            q, rates = euler_to_quaternion(target.roll, target.pitch, target.yaw), (nan, nan, nan)
        send = self._conn.mav.gimbal_device_set_attitude_send
        self._send(
            "GIMBAL_DEVICE_SET_ATTITUDE",
            now,
            send,
            self.system_id,
            self.gimbal_component,
            target.flags,
            q,
            *rates,
        )
        if target != self._gimbal_logged:
            value = (target.roll, target.pitch, target.yaw, target.flags)
            self._record("gimbal", Commanded(now, 0, value, "gimbal"))
            self._gimbal_logged = target

    def _gimbal_discovery(self, now: float) -> None:
        if not self.gimbal_enabled or self.gimbal_device_info is not None:
            return
        if self.gimbal_search_s is not None:
            start, stop = self.gimbal_search_s
            boot_s = now - self._boot_at + self.boot_offset_s
            if boot_s < start or (boot_s > stop and self.armed):
                return
        if now < self._next_request:
            return
        self._next_request = now + REQUEST_INTERVAL_S
        self._send(
            "COMMAND_LONG",
            now,
            self._conn.mav.command_long_send,
            self.system_id,
            self.gimbal_component,
            mav.MAV_CMD_REQUEST_MESSAGE,
            0,
            GIMBAL_DEVICE_INFORMATION_ID,
            0,
            0,
            0,
            0,
            0,
            0,
        )

    def _send_command(self, record: CommandRecord) -> None:
        self._send(
            "COMMAND_LONG",
            record.sends[-1],
            self._conn.mav.command_long_send,
            record.target_system,
            record.target_component,
            record.command,
            0,
            *record.params,
        )

    # ------------------------------------------------------------------ receiving

    def _drain_incoming(self, now: float) -> None:
        for _ in range(1000):  # bounded: never starve the sending side
            msg = self._conn.recv_match(blocking=False)
            if msg is None:
                return
            name = msg.get_type()
            if name == "BAD_DATA":
                continue
            self.received.add(now, msg)
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
            elif (
                name == "GIMBAL_DEVICE_INFORMATION"
                and msg.get_srcComponent() == self.gimbal_component
            ):
                self.gimbal_device_info = msg

    def _addressed_to_me(self, msg: Any) -> bool:
        return msg.target_system in (0, self.system_id) and msg.target_component in (
            0,
            self.component_id,
        )

    def _handle_command(self, msg: Any, now: float) -> None:
        """The few commands a companion sends an autopilot: message intervals and requests."""
        result = mav.MAV_RESULT_UNSUPPORTED
        if msg.command == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
            name = _message_name(int(msg.param1))
            if name in self._intervals:
                interval_us = msg.param2
                if interval_us < 0:
                    self._intervals[name] = None
                elif interval_us == 0:
                    self._intervals[name] = self._defaults[name]
                else:
                    self._intervals[name] = interval_us / 1e6
                result = mav.MAV_RESULT_ACCEPTED
            else:
                result = mav.MAV_RESULT_DENIED
        elif msg.command == mav.MAV_CMD_REQUEST_MESSAGE:
            name = _message_name(int(msg.param1))
            if name in self._intervals and name not in (
                "GIMBAL_DEVICE_SET_ATTITUDE",
                "AUTOPILOT_STATE_FOR_GIMBAL_DEVICE",
            ):
                self._send_periodic(name, now)
                result = mav.MAV_RESULT_ACCEPTED
            else:
                result = mav.MAV_RESULT_DENIED
        if now < self._dropout_until:
            return  # a silent link does not answer either
        self._send(
            "COMMAND_ACK",
            now,
            self._conn.mav.command_ack_send,
            msg.command,
            result,
            0,
            0,
            msg.get_srcSystem(),
            msg.get_srcComponent(),
        )


def normalized_outputs(frame: tuple[int, ...]) -> tuple[list[float], int]:
    """PX4-style ACTUATOR_OUTPUT_STATUS content for a PWM frame: values in [-1, 1], active mask.

    Surfaces map 1100..1900 to -1..1 around 1500 and throttle 1000..2000 to -1..1 (the config's
    ``source: actuator`` input is normalized); channels reading 0 (no pulse) are inactive and NaN.
    """
    values = [math.nan] * 32
    active = 0
    for index, pwm in enumerate(frame):
        if pwm == 0:
            continue
        if index == THROTTLE_CHANNEL - 1:
            value = (pwm - THROTTLE_MIN) / (THROTTLE_MAX - THROTTLE_MIN) * 2.0 - 1.0
        else:
            value = (pwm - SURFACE_TRIM) / ((SURFACE_MAX - SURFACE_MIN) / 2.0)
        values[index] = max(-1.0, min(1.0, value))
        active |= 1 << index
    return values, active


def _interval(rate_hz: float | None) -> float | None:
    return None if not rate_hz or rate_hz <= 0 else 1.0 / rate_hz


def _message_name(msg_id: int) -> str | None:
    cls = mav.mavlink_map.get(msg_id)
    return None if cls is None else cls.msgname


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
