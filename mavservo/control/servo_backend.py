"""The servo side of the bridge as the MAVLink layer sees it (:class:`ActuatorBackend`).

It turns MAVLink-unit requests (PWM, normalized values, gimbal angles) into scheduler setpoints
through the YAML mapping, applies soft limits and slew-rate limits, refuses commands for offline
servos, and carries out each servo's failsafe action. Arbitration between MAVLink sources
(explicit commands override mirroring) happens in the MAVLink layer; here every accepted request
is simply the newest goal of its servo.

Slew limiting needs time to pass, so a goal further away than one step is approached by
:meth:`ServoBackend.tick`, which the bridge calls every command period.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Protocol

from mavservo.config import Config
from mavservo.control.mapping import ChannelMap, Rejected, clamp, slew_limit
from mavservo.mavlink import ACCEPTED, NO_HEALTH_PROBLEM, ApplyResult, Health, Outcome, ServoStatus
from mavservo.scheduling import SetpointResult
from mavservo.servos import ServoState

log = logging.getLogger(__name__)


class SetpointSink(Protocol):
    """What the backend needs from a scheduler (one per bus); :class:`Scheduler` fits it."""

    def set_setpoint(
        self, servo: str, angle_deg: float, source: str, t: float | None = None
    ) -> SetpointResult:
        """Queue a setpoint; the result says whether it was accepted, and if not, why."""
        ...

    def release(self, servo: str) -> None:
        """Stop commanding ``servo`` until its next setpoint (failsafe ``release``)."""
        ...

    def mark_failsafe(self, servo: str) -> None:
        """The setpoint in force is now held by a failsafe (``hold``); nothing new is sent."""
        ...

    def state(self, servo: str) -> ServoState | None:
        """The servo's last decoded state, or None before its first reply."""
        ...

    def is_online(self, servo: str) -> bool:
        """False once the servo stopped answering (see the scheduler's liveness rules)."""
        ...


@dataclass
class _Servo:
    """Book-keeping of one servo: where it is told to go, and what it was last sent."""

    name: str
    index: int
    sink: SetpointSink
    limits_deg: tuple[float, float]
    neutral_deg: float
    failsafe_action: str
    failsafe_position_deg: float | None
    failsafe_delay_s: float = 0.0
    max_slew_dps: float | None = None
    goal_deg: float | None = None
    sent_deg: float | None = None
    sent_at: float | None = None
    source: str = ""
    servo_channel: int | None = None
    actuator_index: int | None = None
    channel_map: ChannelMap | None = None
    #: the last accepted input (``servo_output`` or ``actuator``, channel or index, value), so a
    #: new mapping (a PARAM_SET of the trim) can send the servo where that input maps now
    last_input: tuple[str, int, float] | None = None
    max_speed_dps: float = 360.0
    #: what the health monitor's temperature limit imposes (``slow``, ``hold``, ``release``)
    health_action: str | None = None
    slow_factor: float = 1.0


class ServoBackend:
    """:class:`~mavservo.mavlink.backend.ActuatorBackend` over the mapping and the schedulers.

    ``sinks`` maps each servo name to the scheduler of its bus. ``on_event`` receives one line
    per notable decision (failsafe, clamps) for logs and STATUSTEXT.
    """

    def __init__(
        self,
        config: Config,
        sinks: Mapping[str, SetpointSink],
        on_event: Callable[[str], None] | None = None,
        on_command: Callable[[str, float], None] | None = None,
        health: Callable[[], dict[str, float]] | None = None,
        slew_step_s: float | None = None,
        health_flags: Callable[[str], Health] | None = None,
    ) -> None:
        self._lock = threading.RLock()
        #: the longest time one slew step may cover (the tick period): a servo that sat still
        #: for a minute must not be allowed a minute's worth of motion in one step
        self._slew_step_s = slew_step_s
        #: ``on_command(servo, t_received)`` for each accepted MAVLink request (latency stage 1)
        self._on_command = on_command
        self._health = health
        #: the bridge's health monitor: each servo's Health bits, for its status
        self._health_flags = health_flags
        self._on_event = on_event or (lambda line: log.info("%s", line))
        self._servos: dict[str, _Servo] = {
            servo_config.name: _Servo(
                name=servo_config.name,
                index=index,
                sink=sinks[servo_config.name],
                limits_deg=servo_config.limits_deg,
                neutral_deg=servo_config.neutral_deg,
                failsafe_action=servo_config.failsafe.action,
                failsafe_position_deg=servo_config.failsafe.position_deg,
            )
            for index, servo_config in enumerate(config.servos)
        }
        self._by_channel: dict[int, tuple[_Servo, ChannelMap]] = {}
        self._by_actuator: dict[int, tuple[_Servo, ChannelMap]] = {}
        self._gimbals: dict[str, dict[str, str]] = {}
        self._configure(config)
        self.in_failsafe = False
        #: servo name -> when its failsafe action is due (link lost, waiting out its timeout_s)
        self._failsafe_due: dict[str, float] = {}
        self.counters: dict[str, int] = {"accepted": 0, "rejected": 0, "clamped": 0}

    def _configure(self, config: Config) -> None:
        """Take limits, failsafe settings and the channel mapping from ``config`` (the servo
        names and their order never change: they come from the file, not from parameters)."""
        for servo_config in config.servos:
            servo = self._servos[servo_config.name]
            servo.limits_deg = servo_config.limits_deg
            servo.neutral_deg = servo_config.neutral_deg
            servo.failsafe_action = servo_config.failsafe.action
            servo.failsafe_position_deg = servo_config.failsafe.position_deg
            servo.failsafe_delay_s = servo_config.failsafe.timeout_s
            servo.channel_map = None
            servo.max_slew_dps = None
            servo.max_speed_dps = servo_config.max_speed_dps
        # A servo may be mapped from both sources, each with its own input range: keep the
        # map with the source, and the first map on the servo for reporting measured positions.
        self._by_channel.clear()
        self._by_actuator.clear()
        for entry in config.channels:
            servo = self._servos[entry.servo]
            channel_map = ChannelMap.from_config(entry, config)
            servo.channel_map = servo.channel_map or channel_map
            if entry.max_slew_dps is not None:
                servo.max_slew_dps = entry.max_slew_dps
            if entry.source == "servo_output":
                self._by_channel[entry.channel] = (servo, channel_map)
                servo.servo_channel = entry.channel
            else:
                self._by_actuator[entry.index] = (servo, channel_map)
                servo.actuator_index = entry.index
        self._gimbals = {g.name: g.axes() for g in config.gimbals}

    def reconfigure(self, config: Config, now: float) -> None:
        """Apply new settings (a ground station's PARAM_SET) without a restart.

        A servo that follows an input is sent where that same input maps now (a new trim moves
        it by the trim), a goal outside new limits is brought inside them, and every move goes
        through the slew limit like any other, so a parameter never makes a servo jump faster
        than its channel allows.
        """
        with self._lock:
            self._configure(config)
            for servo in self._servos.values():
                if servo.goal_deg is None or servo.source == "failsafe":
                    continue
                goal = servo.goal_deg
                # an overheated servo on hold stays put: a new trim is no reason to move it
                # (only limits that no longer hold it bring it inside them)
                holding = servo.health_action in ("hold", "release")
                if servo.last_input is not None and not holding:
                    mapped = self._remap(servo, *servo.last_input)
                    goal = goal if mapped is None else mapped
                servo.goal_deg = clamp(goal, servo.limits_deg)[0]
                if servo.sink.is_online(servo.name):
                    self._send_step(servo, now)

    def _remap(self, servo: _Servo, source: str, key: int, value: float) -> float | None:
        table = self._by_channel if source == "servo_output" else self._by_actuator
        mapped = table.get(key)
        if mapped is None or mapped[0] is not servo:
            return None
        target = mapped[1].to_angle(value)
        return None if isinstance(target, Rejected) else target.angle_deg

    # ------------------------------------------------------------------ ActuatorBackend

    def mapped_servo_channels(self) -> set[int]:
        return set(self._by_channel)

    def mapped_actuator_indices(self) -> set[int]:
        return set(self._by_actuator)

    def apply_servo_output(
        self, channel: int, pwm_us: float, source: str, now: float
    ) -> ApplyResult:
        mapped = self._by_channel.get(channel)
        if mapped is None:
            return ApplyResult(Outcome.DENIED, f"servo channel {channel} is not mapped")
        result = self._apply_input(*mapped, pwm_us, source, now)
        if result.ok:
            mapped[0].last_input = ("servo_output", channel, pwm_us)
        return result

    def apply_actuator(self, index: int, value: float, source: str, now: float) -> ApplyResult:
        mapped = self._by_actuator.get(index)
        if mapped is None:
            return ApplyResult(Outcome.DENIED, f"actuator {index} is not mapped")
        result = self._apply_input(*mapped, value, source, now)
        if result.ok:
            mapped[0].last_input = ("actuator", index, value)
        return result

    def apply_gimbal(
        self,
        gimbal: str,
        roll_deg: float | None,
        pitch_deg: float | None,
        yaw_deg: float | None,
        source: str,
        now: float,
    ) -> ApplyResult:
        axes = self._gimbals.get(gimbal)
        if axes is None:
            return ApplyResult(Outcome.DENIED, f"no gimbal named {gimbal!r}")
        wanted = {"roll": roll_deg, "pitch": pitch_deg, "yaw": yaw_deg}
        targets = [
            (self._servos[axes[a]], v) for a, v in wanted.items() if v is not None and a in axes
        ]
        for servo, _ in targets:
            if not servo.sink.is_online(servo.name):
                return ApplyResult(Outcome.TEMPORARILY_REJECTED, f"servo {servo.name} is offline")
        for servo, angle in targets:
            result = self._set_goal(servo, angle, source, now)
            if not result.ok:
                return result
        return ACCEPTED

    def servo_statuses(self) -> list[ServoStatus]:
        """Every servo, in config order. An offline servo has no ``normalized`` position: its
        last one is not a measurement of now, and ACTUATOR_OUTPUT_STATUS built from it showed
        a frozen position as active for a whole adapter outage (the trial)."""
        out = []
        with self._lock:
            for servo in self._servos.values():
                state = servo.sink.state(servo.name)
                online = servo.sink.is_online(servo.name)
                normalized = None
                if online and state is not None and servo.channel_map is not None:
                    normalized = servo.channel_map.angle_to_normalized(state.position_deg)
                out.append(
                    ServoStatus(
                        name=servo.name,
                        index=servo.index,
                        state=state,
                        online=online,
                        setpoint_deg=servo.goal_deg,
                        normalized=normalized,
                        servo_channel=servo.servo_channel,
                        actuator_index=servo.actuator_index,
                        health=(
                            self._health_flags(servo.name)
                            if self._health_flags is not None
                            else NO_HEALTH_PROBLEM
                        ),
                    )
                )
        return out

    def enter_failsafe(self, reason: str, now: float) -> None:
        """The link is lost: each servo acts after its own ``failsafe.timeout_s``.

        Staggered on purpose: a throttle can go to idle at once while control surfaces hold a
        little longer in case the link comes back. :meth:`tick` carries the actions out.
        """
        with self._lock:
            self.in_failsafe = True
            self._failsafe_due = {
                name: now + servo.failsafe_delay_s for name, servo in self._servos.items()
            }
        self._on_event(f"failsafe: {reason}")
        self.tick(now)

    def leave_failsafe(self, now: float) -> None:
        with self._lock:
            self.in_failsafe = False
            self._failsafe_due.clear()  # actions not yet due are cancelled
        self._on_event("failsafe cleared: servos move again on fresh commands")

    def health(self) -> dict[str, float]:
        """Transport figures worth publishing as NAMED_VALUE_FLOAT (a copy); may be empty.

        They come from the ``health`` callable the bridge passes in (``Bridge._health``: bus
        loads and the latency percentiles), because the bridge is what owns the schedulers;
        the telemetry publisher asks the backend, which is all it knows of the bridge.
        """
        return dict(self._health()) if self._health is not None else {}

    # ------------------------------------------------------------------ bridge API

    def set_health_action(
        self, name: str, action: str | None, now: float, slow_factor: float = 0.5
    ) -> None:
        """The health monitor's temperature limit for ``name`` (None: lifted).

        ``slow``: the servo's moves are slew-limited to ``slow_factor`` of its speed limit;
        ``hold``: it stays where it was last sent and new setpoints are refused (a reason in
        the ACK); ``release``: motor off and new setpoints refused until the limit is lifted.
        Failsafe moves go through either way: they are what the crew configured for a lost link.
        """
        with self._lock:
            servo = self._servos.get(name)
            if servo is None:
                return
            servo.health_action = action
            servo.slow_factor = slow_factor if action == "slow" else 1.0
            if action == "hold" and servo.sent_deg is not None:
                servo.goal_deg = servo.sent_deg
            elif action == "release":
                servo.sink.release(name)
                servo.goal_deg = None

    def tick(self, now: float) -> None:
        """Carry out failsafe actions that fell due, and advance slew-limited servos one step
        toward their goals (call every command period)."""
        events: list[str] = []
        with self._lock:
            for name, due in list(self._failsafe_due.items()):
                if due <= now:
                    del self._failsafe_due[name]
                    self._apply_failsafe(self._servos[name], now)
            for servo in self._servos.values():
                if servo.goal_deg is not None and servo.sent_deg != servo.goal_deg:
                    if servo.sink.is_online(servo.name):
                        self._send_step(servo, now)
                    else:
                        events.extend(self._pause_offline(servo, now))
        # Emitted after the lock is released: the event hook announces over MAVLink, whose lock
        # the MAVLink threads hold while calling into this backend (red-team finding D, a
        # lock-order deadlock that hung the whole bridge).
        self._emit(events)

    def _emit(self, events: list[str]) -> None:
        """Hand events to ``on_event``; never called with ``_lock`` held (see :meth:`tick`)."""
        for line in events:
            self._on_event(line)

    def _pause_offline(self, servo: _Servo, now: float) -> list[str]:
        """No slew steps go to an offline servo (the scheduler would drop them unsent).

        A commanded move is abandoned: resuming it when the servo is back, maybe seconds
        later, would carry out a command long after its ACK (the trial's late payload servo);
        the servo waits for a fresh command, as after a release. A failsafe move stays in
        force and resumes at the slew rate from where it stopped once the servo answers.
        """
        if servo.source == "failsafe":
            servo.sent_at = now
            return []
        goal, servo.goal_deg = servo.goal_deg, None
        return [f"{servo.name} offline: move to {goal:g} deg stopped; it waits for a fresh command"]

    def failsafe_all(self, reason: str, now: float, *, announce: bool = True) -> None:
        """Shutdown path: every servo to its failsafe action at once (no per-servo delay).

        ``announce=False``: no ``failsafe: ...`` event; the caller says it in its own words
        (a normal end of a run is not an alarm)."""
        with self._lock:
            self.in_failsafe = True
            self._failsafe_due.clear()
            for servo in self._servos.values():
                self._apply_failsafe(servo, now)
        if announce:
            self._on_event(f"failsafe: {reason}")

    # ------------------------------------------------------------------ internals

    def _apply_input(
        self, servo: _Servo, channel_map: ChannelMap, value: float, source: str, now: float
    ) -> ApplyResult:
        target = channel_map.to_angle(value)
        if isinstance(target, Rejected):
            with self._lock:
                self.counters["rejected"] += 1
            return ApplyResult(Outcome.DENIED, target.detail)
        if not servo.sink.is_online(servo.name):
            return ApplyResult(Outcome.TEMPORARILY_REJECTED, f"servo {servo.name} is offline")
        if target.clamped:
            with self._lock:
                self.counters["clamped"] += 1
        return self._set_goal(servo, target.angle_deg, source, now)

    def _set_goal(self, servo: _Servo, angle_deg: float, source: str, now: float) -> ApplyResult:
        angle, clamped = clamp(angle_deg, servo.limits_deg)
        with self._lock:
            if servo.health_action in ("hold", "release"):
                refused = self.counters.get("refused_overheated", 0)
                self.counters["refused_overheated"] = refused + 1
                verb = "holding" if servo.health_action == "hold" else "released"
                return ApplyResult(
                    Outcome.TEMPORARILY_REJECTED,
                    f"servo {servo.name} overheated: {verb} until it cools",
                )
            if clamped:
                self.counters["clamped"] += 1
            servo.goal_deg = angle
            servo.source = source
            servo.last_input = None  # the input callers record it again after this
            self.counters["accepted"] += 1
            result = self._send_step(servo, now)
        # The latency hook is the bridge's: called without this lock held (finding D).
        if self._on_command is not None:
            self._on_command(servo.name, now)
        return result

    def _send_step(self, servo: _Servo, now: float) -> ApplyResult:
        assert servo.goal_deg is not None
        step = servo.goal_deg
        max_slew = servo.max_slew_dps
        if servo.slow_factor < 1.0:  # an overheated servo's lowered speed limit
            max_slew = servo.slow_factor * min(servo.max_speed_dps, max_slew or math.inf)
        if max_slew is not None and servo.sent_deg is not None and servo.sent_at is not None:
            dt = now - servo.sent_at
            if self._slew_step_s is not None:
                dt = min(dt, self._slew_step_s)
            step = slew_limit(servo.sent_deg, servo.goal_deg, dt, max_slew)
            if step == servo.sent_deg:
                return ACCEPTED  # no time has passed yet; the next tick moves it
        # t=None: the scheduler stamps it on arrival. Calls come in under this backend's lock, so
        # arrival order is command order even when threads read their clocks out of order.
        result = servo.sink.set_setpoint(servo.name, step, servo.source)
        if result.accepted:
            servo.sent_deg = step
            servo.sent_at = now
            return ACCEPTED
        return ApplyResult(Outcome.DENIED, result.reason or "rejected by the scheduler")

    def _apply_failsafe(self, servo: _Servo, now: float) -> None:
        action = servo.failsafe_action
        if action == "release":
            servo.sink.release(servo.name)
            servo.goal_deg = None
            return
        if action == "hold":
            # the scheduler keeps refreshing the last setpoint; it is marked as held by the
            # failsafe (no new command: the command stream stays exactly what was applied), so
            # the bus knows the servo is in failsafe (a DroneCAN node's SafetyState plan,
            # ``safety_on: failsafe_and_stop``, never saw a held servo in failsafe)
            if servo.goal_deg is None:
                return
            servo.source = "failsafe"
            if servo.goal_deg == servo.sent_deg:
                servo.sink.mark_failsafe(servo.name)
            return  # a move under way goes on, its next steps failsafe ones
        angle = servo.neutral_deg if action == "neutral" else servo.failsafe_position_deg
        if angle is None:
            return
        servo.goal_deg = clamp(angle, servo.limits_deg)[0]
        servo.source = "failsafe"
        self._send_step(servo, now)
