"""Gimbal protocol v2 device (and optional gimbal manager) for a group of gimbal servos, sans-I/O.

:class:`GimbalDevice` turns gimbal MAVLink traffic into body-frame axis angles for
``backend.apply_gimbal`` and turns the measured servo positions back into
GIMBAL_DEVICE_ATTITUDE_STATUS. It owns no socket, thread or clock: the link hands it messages and
commands with the receive time, and asks it for periodic and requested messages, which it returns
as pymavlink message objects for the gimbal component's own encoder.

Rules it applies (the "why" of each is in the method that applies it):

* **Frames.** Roll and pitch are always relative to the vehicle: servos cannot level the camera
  without an IMU, so ROLL_LOCK/PITCH_LOCK are echoed in the status but not stabilised. Yaw is in
  the earth frame when a demand carries YAW_IN_EARTH_FRAME (64), or ArduPilot's older YAW_LOCK (16)
  without YAW_IN_VEHICLE_FRAME (32); it is turned into body yaw by subtracting the vehicle yaw from
  AUTOPILOT_STATE_FOR_GIMBAL_DEVICE.q or ATTITUDE.yaw, wrapped to [-180, 180), and re-applied as the
  vehicle turns. Until a vehicle yaw is known an earth-frame yaw leaves the yaw axis where it is.
* **Retract.** ArduPilot's mount backend sends, on every update while retracted, a RETRACT message
  (q NaN, flags 1) followed by a "shadow" identity-q flags-0 target. The device therefore ignores
  an identity-q message without NEUTRAL that arrives within ``retract_hold_s`` of the latest
  RETRACT message. Anything else (another angle, NEUTRAL, rates) ends retract at once; when the
  RETRACT messages stop, messages are applied normally again after ``retract_hold_s``. The retract
  pose is configurable; by default roll 0, pitch at its lower limit (camera stowed looking down,
  lens away from propwash and debris on landing), yaw 0. Neutral is 0/0/0 unless configured.
* **Rates.** A demand with q NaN and finite angular velocities is integrated from the current
  target at each call (``handle_message``/``periodic``), clamped to the limits; NaN rates leave
  their axis alone. With a finite q, rates are feed-forward and ignored (servos track angles).
* **Limits.** Targets are clamped to ``limits_deg``; while a clamped target is in effect the status
  carries GIMBAL_DEVICE_ERROR_FLAGS_AT_{ROLL,PITCH,YAW}_LIMIT and ``clamp_count`` counts clamps.
* **Refusals.** A demand the backend refuses (TEMPORARILY_REJECTED while a servo is offline) is
  forgotten, never retried: carrying it out once the servos are back would apply a command after
  its refusal. The next demand is a fresh one.
* **Hostile values.** Everything is validated before use: a quaternion must have finite
  components and a length of 0.5..2, angles must be finite and within a turn, rates finite and at
  most ``MAX_DEMAND_RATE_DPS``, flags and ids finite. A bad command is DENIED, a bad message
  ignored; both are counted (``bad_value``) and logged once per kind per interval.
* **Status.** q comes from the MEASURED servo positions (falling back to the last setpoint, then 0,
  for an axis with no reading yet), in the vehicle frame (flag 32). Failure flags: offline servo
  or ``Fault.NO_REPLY`` -> COMMS_ERROR, ENCODER -> ENCODER_ERROR, voltage/power faults ->
  POWER_ERROR, every other fault -> MOTOR_ERROR.
"""

from __future__ import annotations

import dataclasses
import enum
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from mavservo.mavlink.backend import ActuatorBackend, ApplyResult, Health, Outcome, ServoStatus
from mavservo.mavlink.gimbal_manager import (
    SAME_COMPONENT_DEVICE_ID,
    ControlSlots,
    addresses_this_gimbal,
)
from mavservo.mavlink.quaternion import (
    earth_to_body_yaw,
    euler_to_quaternion,
    is_nan_quaternion,
    is_usable_attitude,
    quaternion_to_euler,
    wrap_180,
    yaw_of,
)
from mavservo.mavlink.telemetry import float32_field
from mavservo.servos import Fault

log = logging.getLogger(__name__)

AXES = ("roll", "pitch", "yaw")
MAV_TYPE_GIMBAL = mav.MAV_TYPE_GIMBAL  # 26

# Flag values are shared by GIMBAL_DEVICE_FLAGS and GIMBAL_MANAGER_FLAGS (same bits by design).
RETRACT = mav.GIMBAL_DEVICE_FLAGS_RETRACT
NEUTRAL = mav.GIMBAL_DEVICE_FLAGS_NEUTRAL
ROLL_LOCK = mav.GIMBAL_DEVICE_FLAGS_ROLL_LOCK
PITCH_LOCK = mav.GIMBAL_DEVICE_FLAGS_PITCH_LOCK
YAW_LOCK = mav.GIMBAL_DEVICE_FLAGS_YAW_LOCK
YAW_IN_VEHICLE_FRAME = mav.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME
YAW_IN_EARTH_FRAME = mav.GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME

AT_LIMIT_FLAG = {
    "roll": mav.GIMBAL_DEVICE_ERROR_FLAGS_AT_ROLL_LIMIT,
    "pitch": mav.GIMBAL_DEVICE_ERROR_FLAGS_AT_PITCH_LIMIT,
    "yaw": mav.GIMBAL_DEVICE_ERROR_FLAGS_AT_YAW_LIMIT,
}
COMMS_ERROR = mav.GIMBAL_DEVICE_ERROR_FLAGS_COMMS_ERROR
MOTOR_ERROR = mav.GIMBAL_DEVICE_ERROR_FLAGS_MOTOR_ERROR
ENCODER_ERROR = mav.GIMBAL_DEVICE_ERROR_FLAGS_ENCODER_ERROR
POWER_ERROR = mav.GIMBAL_DEVICE_ERROR_FLAGS_POWER_ERROR

FAULT_TO_FAILURE_FLAG: dict[Fault, int] = {
    Fault.NO_REPLY: COMMS_ERROR,
    Fault.COMMUNICATION_LOST: COMMS_ERROR,
    Fault.ENCODER: ENCODER_ERROR,
    Fault.LOW_VOLTAGE: POWER_ERROR,
    Fault.OVER_VOLTAGE: POWER_ERROR,
    Fault.POWER: POWER_ERROR,
}
"""Servo faults with a specific gimbal failure flag; any other fault reports MOTOR_ERROR."""

HEALTH_TO_FAILURE_FLAG: dict[Health, int] = {
    Health.TRACKING: MOTOR_ERROR,
    Health.JAMMED: MOTOR_ERROR,
    Health.SLIPPING: MOTOR_ERROR,
    Health.OVERLOAD: MOTOR_ERROR,
    Health.OVERHEATED: MOTOR_ERROR,
    Health.SUPPLY: POWER_ERROR,
}
"""The bridge's own health findings on an axis (issue 33; docs/health.md) as failure flags, so
ArduPilot's mount reports the gimbal unhealthy; a temperature warning (``HOT``) is a warning,
not a failure, and sets none."""

CMD_DO_MOUNT_CONTROL = mav.MAV_CMD_DO_MOUNT_CONTROL  # 205
CMD_DO_GIMBAL_MANAGER_PITCHYAW = mav.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW  # 1000
CMD_DO_GIMBAL_MANAGER_CONFIGURE = mav.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE  # 1001

MSG_GIMBAL_MANAGER_INFORMATION = mav.MAVLINK_MSG_ID_GIMBAL_MANAGER_INFORMATION  # 280
MSG_GIMBAL_MANAGER_STATUS = mav.MAVLINK_MSG_ID_GIMBAL_MANAGER_STATUS  # 281
MSG_GIMBAL_DEVICE_INFORMATION = mav.MAVLINK_MSG_ID_GIMBAL_DEVICE_INFORMATION  # 283
MSG_GIMBAL_DEVICE_ATTITUDE_STATUS = mav.MAVLINK_MSG_ID_GIMBAL_DEVICE_ATTITUDE_STATUS  # 285

IDENTITY_TOLERANCE = 1e-3
"""How close to (1, 0, 0, 0) a float32 quaternion must be to count as ArduPilot's shadow target."""
CLAMP_TOLERANCE_DEG = 1e-3
"""A request this close to a limit is float32 noise, not a clamp worth reporting."""
SOURCE = "gimbal"
"""``source`` passed to the backend for every gimbal request."""
MAX_DEMAND_ANGLE_DEG = 360.0
"""A demanded angle beyond a full turn is not a pointing request but garbage (or an attack):
refused, not clamped, because clamping 3.4e38 to a limit would move the gimbal to that limit."""
MAX_DEMAND_RATE_DPS = 3600.0
"""Ten turns a second: far beyond any gimbal; a larger (or infinite) rate is refused."""
MAX_FLAGS = 0xFFFFFFFF
"""Largest flags value a command parameter may carry (the flags fields are uint32)."""
BAD_INPUT_LOG_INTERVAL_S = 10.0
"""One log line per kind of bad input per interval; the rest are only counted."""


@dataclass(frozen=True)
class GimbalSettings:
    """What a gimbal group in the YAML config says about one gimbal.

    ``axis_servos`` maps "roll"/"pitch"/"yaw" to servo names (a 2-axis gimbal omits one);
    ``limits_deg`` maps each axis to ``(min, max)`` body-frame degrees.
    """

    name: str
    axis_servos: dict[str, str]
    limits_deg: dict[str, tuple[float, float]]
    component_id: int = mav.MAV_COMP_ID_GIMBAL  # 154
    act_as_manager: bool = False
    vendor_name: str = "mavservo"
    model_name: str = "CAN servo gimbal"
    custom_name: str = ""
    firmware_version: int = 0
    uid: int = 0
    status_rate_hz: float = 10.0
    manager_status_rate_hz: float = 2.0
    retract_pose_deg: tuple[float, float, float] | None = None
    neutral_pose_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    retract_hold_s: float = 0.25
    apply_deadband_deg: float = 0.05
    system_id: int | None = None

    def __post_init__(self) -> None:
        unknown = (set(self.axis_servos) | set(self.limits_deg)) - set(AXES)
        if unknown:
            raise ValueError(f"gimbal {self.name!r}: unknown axes {sorted(unknown)}")
        if not self.axis_servos:
            raise ValueError(f"gimbal {self.name!r}: no axis servos")
        for axis, (low, high) in self.limits_deg.items():
            if not low <= high:
                raise ValueError(f"gimbal {self.name!r}: {axis} limits {low} > {high}")
        if self.status_rate_hz < 5.0:
            raise ValueError(
                f"gimbal {self.name!r}: status_rate_hz {self.status_rate_hz} < 5 "
                "(ArduPilot marks a gimbal unhealthy without frequent status)"
            )
        if self.manager_status_rate_hz <= 0:
            raise ValueError(f"gimbal {self.name!r}: manager_status_rate_hz must be > 0")
        if not 1 <= self.component_id <= 255:
            raise ValueError(f"gimbal {self.name!r}: component_id {self.component_id}")

    def limits(self, axis: str) -> tuple[float, float]:
        """Limits of ``axis``; an axis without limits is free over a full turn."""
        return self.limits_deg.get(axis, (-180.0, 180.0))

    def retract_pose(self) -> tuple[float, float, float]:
        """Configured retract pose, or roll 0 / pitch at its lower limit / yaw 0."""
        if self.retract_pose_deg is not None:
            return self.retract_pose_deg
        return (0.0, self.limits("pitch")[0], 0.0)


class Mode(enum.Enum):
    """What kind of demand is in effect."""

    ANGLE = "angle"
    RATE = "rate"
    RETRACT = "retract"
    NEUTRAL = "neutral"


@dataclass
class Demand:
    """The pointing request in effect, in the frame it was given.

    ``angles`` are roll/pitch/yaw degrees (None = leave that axis alone); for RATE mode they are
    the integration base at ``since`` and ``rates_dps`` the rates. ``flags`` are the request's
    lock flags, echoed in the status.
    """

    mode: Mode
    angles: tuple[float | None, float | None, float | None] = (None, None, None)
    yaw_in_earth_frame: bool = False
    flags: int = 0
    rates_dps: tuple[float | None, float | None, float | None] = (None, None, None)
    since: float = 0.0
    from_message_retract: bool = False


@dataclass
class GimbalCounters:
    """Why messages were ignored or changed, for logs and tests."""

    applied: int = 0
    rejected: int = 0
    clamped: int = 0
    shadow_ignored: int = 0
    not_for_me: int = 0
    no_target: int = 0
    denied_control: int = 0
    bad_value: int = 0
    """Messages ignored and commands DENIED for a hostile value (non-finite or absurd angle,
    rate or flags; a zero, infinite or overflowing quaternion)."""


def yaw_in_earth_frame(flags: int) -> bool:
    """Frame of the yaw in a demand: flag 64, or ArduPilot's old YAW_LOCK without flag 32."""
    if flags & YAW_IN_EARTH_FRAME:
        return True
    if flags & YAW_IN_VEHICLE_FRAME:
        return False
    return bool(flags & YAW_LOCK)


#: Largest |ATTITUDE.yaw| taken as a heading (two turns; the spec sends -pi..pi).
MAX_VEHICLE_YAW_RAD = 4 * math.pi


def _finite_or_none(value: float) -> float | None:
    return None if value is None or math.isnan(value) else float(value)


def _is_identity(q: Sequence[float]) -> bool:
    w, x, y, z = q
    return (
        abs(abs(w) - 1.0) < IDENTITY_TOLERANCE and max(abs(x), abs(y), abs(z)) < IDENTITY_TOLERANCE
    )


class GimbalDevice:
    """One gimbal group as a MAVLink gimbal device (MAV_TYPE_GIMBAL), optionally its own manager.

    Public surface used by the link: :attr:`component_id`, :attr:`mav_type`,
    :meth:`handle_message`, :meth:`handle_command`, :meth:`supports_message`,
    :meth:`requested_message`, :meth:`periodic`. ``now`` is always ``time.monotonic()`` at receipt
    (or a test's clock); the device never reads a clock itself.
    """

    mav_type = MAV_TYPE_GIMBAL

    def __init__(
        self, settings: GimbalSettings, backend: ActuatorBackend, boot_time: float | None = None
    ) -> None:
        self.settings = settings
        self.backend = backend
        self.component_id = settings.component_id
        self.counters = GimbalCounters()
        self.control = ControlSlots()
        self.demand: Demand | None = None
        self.vehicle_yaw_deg: float | None = None
        self.last_result: ApplyResult | None = None
        self._boot_time = boot_time
        self._last_retract_message: float | None = None
        self._applied_angles: tuple[float | None, float | None, float | None] | None = None
        self._clamped_axes: frozenset[str] = frozenset()
        self._next_status = -math.inf
        self._next_manager_status = -math.inf
        self._bad_input_logged: dict[str, tuple[float, int]] = {}
        """kind of bad input -> (when its last line was logged, how many since)."""

    # ------------------------------------------------------------------ inputs

    def counter_values(self) -> dict[str, int]:
        """Each counter by name (:class:`~mavservo.mavlink.component.CountingComponent`)."""
        return dataclasses.asdict(self.counters)

    def handle_message(self, msg: Any, now: float) -> None:
        """Consume one received message; anything not gimbal-related is ignored cheaply."""
        self._note_time(now)
        kind = msg.get_type()
        if kind == "GIMBAL_DEVICE_SET_ATTITUDE":
            if not self._addressed_to_me(msg):
                self.counters.not_for_me += 1
                return
            self._on_set_attitude(kind, msg, now)
        elif kind == "GIMBAL_MANAGER_SET_ATTITUDE":
            if not (
                self.settings.act_as_manager
                and self._addressed_to_me(msg)
                and addresses_this_gimbal(msg.gimbal_device_id, self.component_id)
            ):
                self.counters.not_for_me += 1
                return
            if not self.control.may_control(_sender_of(msg)):
                self.counters.denied_control += 1
                return
            self._on_set_attitude(kind, msg, now)
        elif kind == "AUTOPILOT_STATE_FOR_GIMBAL_DEVICE":
            if not self._from_my_system(msg) or is_nan_quaternion(msg.q):
                return
            if not is_usable_attitude(msg.q):
                self._bad_input(kind, f"unusable vehicle attitude q={list(msg.q)!r}", now)
                return
            self._on_vehicle_yaw(yaw_of(msg.q), now)
        elif kind == "ATTITUDE" and self._from_my_system(msg) and not math.isnan(msg.yaw):
            # the spec's range is -pi..pi; beyond a couple of turns it is garbage (3e306 rad
            # overflows to inf in degrees and wraps to NaN)
            if not math.isfinite(msg.yaw) or abs(msg.yaw) > MAX_VEHICLE_YAW_RAD:
                self._bad_input(kind, f"vehicle yaw {msg.yaw!r}", now)
                return
            self._on_vehicle_yaw(wrap_180(math.degrees(msg.yaw)), now)

    def _on_set_attitude(self, kind: str, msg: Any, now: float) -> None:
        """A device or manager SET_ATTITUDE addressed to us: validated, then the demand."""
        rates = self._rates_of(msg)
        problem = _attitude_problem(msg.q, rates)
        if problem:
            self._bad_input(kind, problem, now)
            return
        self._on_attitude_demand(msg.flags, msg.q, rates, now)

    def _bad_input(self, kind: str, detail: str, now: float) -> None:
        """Count a hostile value and log it: the first of its kind at once, then one line per
        :data:`BAD_INPUT_LOG_INTERVAL_S` with how many came since (a flood must not flood the
        journal, and a traceback would be a lie: nothing is broken)."""
        self.counters.bad_value += 1
        last, since = self._bad_input_logged.get(kind, (-math.inf, 0))
        if now - last < BAD_INPUT_LOG_INTERVAL_S:
            self._bad_input_logged[kind] = (last, since + 1)
            return
        self._bad_input_logged[kind] = (now, 0)
        more = f" (and {since} more since the last line)" if since else ""
        log.warning("gimbal %s: %s ignored/denied: %s%s", self.settings.name, kind, detail, more)

    def handle_command(
        self,
        command_id: int,
        params: tuple[float, ...],
        now: float,
        *,
        sender: tuple[int, int] | None = None,
    ) -> int | None:
        """Execute a command this gimbal owns and return its MAV_RESULT; None = not mine.

        ``sender`` (sysid, compid), when the dispatcher passes it, lets the manager honour
        DO_GIMBAL_MANAGER_CONFIGURE's "me" values and refuse clients that are not in control.
        """
        self._note_time(now)
        if command_id == CMD_DO_MOUNT_CONTROL:
            return self._do_mount_control(params, now)
        if not self.settings.act_as_manager:
            return None
        if command_id == CMD_DO_GIMBAL_MANAGER_PITCHYAW:
            if not addresses_this_gimbal(params[6], self.component_id):
                return int(Outcome.DENIED)
            if not self.control.may_control(sender):
                self.counters.denied_control += 1
                return int(Outcome.DENIED)
            return self._do_pitchyaw(params, now)
        if command_id == CMD_DO_GIMBAL_MANAGER_CONFIGURE:
            if not addresses_this_gimbal(params[6], self.component_id):
                return int(Outcome.DENIED)
            ok = self.control.configure(params, sender)
            return int(Outcome.ACCEPTED if ok else Outcome.DENIED)
        return None

    def handles_command(self, command_id: int) -> bool:
        """The commands :meth:`handle_command` acts on (the others return None, "not mine")."""
        if command_id == CMD_DO_MOUNT_CONTROL:
            return True
        manager_commands = (CMD_DO_GIMBAL_MANAGER_PITCHYAW, CMD_DO_GIMBAL_MANAGER_CONFIGURE)
        return bool(self.settings.act_as_manager) and command_id in manager_commands

    def supports_message(self, message_id: int) -> bool:
        """Whether a MAV_CMD_REQUEST_MESSAGE for ``message_id`` is ours to answer.

        A request for GIMBAL_MANAGER_INFORMATION/STATUS to a gimbal that is not its own manager
        must be answered UNSUPPORTED, so a ground station looks for the manager elsewhere.
        """
        if message_id in (MSG_GIMBAL_DEVICE_INFORMATION, MSG_GIMBAL_DEVICE_ATTITUDE_STATUS):
            return True
        if message_id in (MSG_GIMBAL_MANAGER_INFORMATION, MSG_GIMBAL_MANAGER_STATUS):
            return self.settings.act_as_manager
        return False

    def requested_message(self, message_id: int, now: float) -> Any | None:
        """The message answering a REQUEST_MESSAGE, or None if this gimbal does not provide it."""
        self._note_time(now)
        if not self.supports_message(message_id):
            return None
        if message_id == MSG_GIMBAL_DEVICE_INFORMATION:
            return self.device_information(now)
        if message_id == MSG_GIMBAL_DEVICE_ATTITUDE_STATUS:
            return self.attitude_status(now)
        if message_id == MSG_GIMBAL_MANAGER_INFORMATION:
            return self.manager_information(now)
        return self.manager_status(now)

    def periodic(self, now: float) -> list[Any]:
        """Advance rate targets and return the messages now due.

        GIMBAL_DEVICE_ATTITUDE_STATUS at ``status_rate_hz``; as manager also GIMBAL_MANAGER_STATUS
        at ``manager_status_rate_hz``. A late call sends one message, not a burst. A refused
        demand is not retried here: :meth:`_drive` has forgotten it.
        """
        self._note_time(now)
        out: list[Any] = []
        if now >= self._next_status:
            if self.demand is not None and self.demand.mode is Mode.RATE:
                self._drive(now)
            out.append(self.attitude_status(now))
            self._next_status = _next_deadline(
                self._next_status, 1.0 / self.settings.status_rate_hz, now
            )
        elif self.demand is not None and self.demand.mode is Mode.RATE:
            self._drive(now)
        if self.settings.act_as_manager and now >= self._next_manager_status:
            out.append(self.manager_status(now))
            self._next_manager_status = _next_deadline(
                self._next_manager_status, 1.0 / self.settings.manager_status_rate_hz, now
            )
        return out

    # ------------------------------------------------------------------ demand handling

    def _on_attitude_demand(
        self,
        flags: int,
        q: Sequence[float],
        rates_dps: tuple[float | None, float | None, float | None],
        now: float,
    ) -> None:
        """Turn one SET_ATTITUDE (device or manager) into the demand in effect, then drive."""
        if flags & RETRACT:
            self._last_retract_message = now
            self._set_demand(Demand(Mode.RETRACT, flags=flags, from_message_retract=True), now)
            return
        if self._is_retract_shadow(flags, q, now):
            self.counters.shadow_ignored += 1
            return
        if flags & NEUTRAL:
            self._set_demand(Demand(Mode.NEUTRAL, flags=flags), now)
            return
        if is_nan_quaternion(q):
            if all(rate is None for rate in rates_dps):
                self.counters.no_target += 1
                return
            self._start_rates(rates_dps, flags, now)
            return
        roll, pitch, yaw = quaternion_to_euler(q)
        self._set_demand(
            Demand(Mode.ANGLE, (roll, pitch, yaw), yaw_in_earth_frame(flags), flags), now
        )

    def _is_retract_shadow(self, flags: int, q: Sequence[float], now: float) -> bool:
        """ArduPilot's identity target sent right after each RETRACT message (see module doc)."""
        demand = self.demand
        if demand is None or demand.mode is not Mode.RETRACT or not demand.from_message_retract:
            return False
        if self._last_retract_message is None:
            return False
        if now - self._last_retract_message > self.settings.retract_hold_s:
            return False
        return not (flags & NEUTRAL) and not is_nan_quaternion(q) and _is_identity(q)

    def _start_rates(
        self,
        rates_dps: tuple[float | None, float | None, float | None],
        flags: int,
        now: float,
    ) -> ApplyResult:
        """Begin integrating rates from the body angles currently targeted (or measured)."""
        base = self._current_body_angles(now)
        return self._set_demand(
            Demand(Mode.RATE, base, False, flags, rates_dps=rates_dps, since=now), now
        )

    def _do_mount_control(self, params: tuple[float, ...], now: float) -> int:
        """MAV_CMD_DO_MOUNT_CONTROL: p1 pitch, p2 roll, p3 yaw (body), p7 MAV_MOUNT_MODE."""
        if not math.isfinite(params[6]):
            return self._deny("DO_MOUNT_CONTROL", f"mount mode {params[6]!r}", now)
        mode = int(params[6])
        if mode == mav.MAV_MOUNT_MODE_RETRACT:
            demand = Demand(Mode.RETRACT, flags=RETRACT)
        elif mode == mav.MAV_MOUNT_MODE_NEUTRAL:
            demand = Demand(Mode.NEUTRAL, flags=NEUTRAL)
        elif mode == mav.MAV_MOUNT_MODE_MAVLINK_TARGETING:
            problem = _angles_problem(params[:3])
            if problem:
                return self._deny("DO_MOUNT_CONTROL", problem, now)
            angles = (
                _finite_or_none(params[1]),
                _finite_or_none(params[0]),
                _finite_or_none(params[2]),
            )
            demand = Demand(Mode.ANGLE, angles)
        else:
            return int(Outcome.UNSUPPORTED)
        self._last_retract_message = None
        return int(self._set_demand(demand, now).outcome)

    def _do_pitchyaw(self, params: tuple[float, ...], now: float) -> int:
        """DO_GIMBAL_MANAGER_PITCHYAW: p1 pitch, p2 yaw (deg), p3/p4 rates (deg/s), p5 flags."""
        problem = _flags_problem(params[4]) or _angles_problem(params[:2])
        problem = problem or _rates_problem(_nan_to_none(params[2:4]))
        if problem:
            return self._deny("DO_GIMBAL_MANAGER_PITCHYAW", problem, now)
        flags = 0 if math.isnan(params[4]) else int(params[4])
        self._last_retract_message = None
        if flags & RETRACT:
            return int(self._set_demand(Demand(Mode.RETRACT, flags=flags), now).outcome)
        if flags & NEUTRAL:
            return int(self._set_demand(Demand(Mode.NEUTRAL, flags=flags), now).outcome)
        pitch, yaw = _finite_or_none(params[0]), _finite_or_none(params[1])
        if pitch is None and yaw is None:
            rates = (None, _finite_or_none(params[2]), _finite_or_none(params[3]))
            if rates[1] is None and rates[2] is None:
                return int(Outcome.DENIED)
            return int(self._start_rates(rates, flags, now).outcome)
        demand = Demand(Mode.ANGLE, (0.0, pitch, yaw), yaw_in_earth_frame(flags), flags)
        return int(self._set_demand(demand, now).outcome)

    def _deny(self, command: str, problem: str, now: float) -> int:
        """DENIED for a hostile parameter, counted and logged (rate-limited)."""
        self._bad_input(command, problem, now)
        return int(Outcome.DENIED)

    def _set_demand(self, demand: Demand, now: float) -> ApplyResult:
        """Make ``demand`` the one in effect and drive it.

        Not forced: ArduPilot repeats the same target at 50 Hz, and the scheduler already
        refreshes the last setpoint, so an unchanged target is not sent to the backend again
        (unless the previous request was refused).
        """
        self.demand = demand
        return self._drive(now)

    def _on_vehicle_yaw(self, yaw_deg: float, now: float) -> None:
        """Remember the vehicle heading; an earth-frame yaw target must follow it."""
        self.vehicle_yaw_deg = yaw_deg
        if (
            self.demand is not None
            and self.demand.mode is Mode.ANGLE
            and self.demand.yaw_in_earth_frame
        ):
            self._drive(now)

    # ------------------------------------------------------------------ driving the servos

    def target_body_angles(self, now: float) -> tuple[float | None, float | None, float | None]:
        """Body-frame roll/pitch/yaw the demand in effect asks for, before clamping."""
        demand = self.demand
        if demand is None:
            return (None, None, None)
        if demand.mode is Mode.RETRACT:
            return self.settings.retract_pose()
        if demand.mode is Mode.NEUTRAL:
            return self.settings.neutral_pose_deg
        roll, pitch, yaw = demand.angles
        if demand.mode is Mode.RATE:
            elapsed = max(0.0, now - demand.since)
            integrated = []
            for axis, base, rate in zip(AXES, demand.angles, demand.rates_dps, strict=True):
                if rate is None or base is None:
                    integrated.append(base)
                    continue
                low, high = self.settings.limits(axis)
                integrated.append(min(high, max(low, base + rate * elapsed)))
            return (integrated[0], integrated[1], integrated[2])
        if yaw is not None and demand.yaw_in_earth_frame:
            yaw = (
                None
                if self.vehicle_yaw_deg is None
                else earth_to_body_yaw(yaw, self.vehicle_yaw_deg)
            )
        return (roll, pitch, yaw)

    def _clamp(
        self, angles: tuple[float | None, float | None, float | None]
    ) -> tuple[tuple[float | None, float | None, float | None], frozenset[str]]:
        """Drop axes without a servo and clamp the rest; report which axes hit a limit."""
        clamped_axes: set[str] = set()
        result: list[float | None] = []
        for axis, angle in zip(AXES, angles, strict=True):
            if angle is None or axis not in self.settings.axis_servos:
                result.append(None)
                continue
            low, high = self.settings.limits(axis)
            if axis == "yaw" and high - low < 360.0:
                angle = wrap_180(angle)
            limited = min(high, max(low, angle))
            if abs(limited - angle) > CLAMP_TOLERANCE_DEG:
                clamped_axes.add(axis)
            result.append(limited)
        return (result[0], result[1], result[2]), frozenset(clamped_axes)

    def _drive(self, now: float, force: bool = False) -> ApplyResult:
        """Send the demand's body angles to the backend when they changed (or when forced)."""
        angles, clamped_axes = self._clamp(self.target_body_angles(now))
        if clamped_axes and (force or clamped_axes != self._clamped_axes):
            self.counters.clamped += 1
        self._clamped_axes = clamped_axes
        unchanged = (
            self._applied_angles is not None
            and self.last_result is not None
            and self.last_result.ok
            and _same_angles(angles, self._applied_angles, self.settings.apply_deadband_deg)
        )
        if unchanged and not force:
            assert self.last_result is not None
            return self.last_result
        if all(angle is None for angle in angles):
            self.last_result = ApplyResult(Outcome.ACCEPTED, "nothing to move")
            return self.last_result
        result = self.backend.apply_gimbal(self.settings.name, *angles, SOURCE, now)
        self.last_result = result
        self._applied_angles = angles
        if result.ok:
            self.counters.applied += 1
        else:
            self.counters.rejected += 1
            self._forget_refused_demand()
        return result

    def _forget_refused_demand(self) -> None:
        """A refused demand is over: its sender got the refusal, so carrying it out later would
        be a command applied after its NACK. (It used to be retried on every status tick, and
        the trial's gimbal moved to a pitch refused during an adapter outage 2.2 s after the
        adapter came back.) The servos hold what they had; the next demand is a fresh one,
        as for a servo whose move was abandoned while it was offline (servo_backend)."""
        self.demand = None
        self._clamped_axes = frozenset()

    def _current_body_angles(self, now: float) -> tuple[float | None, float | None, float | None]:
        """Where rates start from: the clamped current target, else the measured angles."""
        if self.demand is not None:
            target, _ = self._clamp(self.target_body_angles(now))
            if all(
                angle is not None
                for axis, angle in zip(AXES, target, strict=True)
                if axis in self.settings.axis_servos
            ):
                return target
        measured = self.measured_angles()
        return tuple(  # type: ignore[return-value]
            measured[i] if axis in self.settings.axis_servos else None
            for i, axis in enumerate(AXES)
        )

    # ------------------------------------------------------------------ outputs

    def axis_statuses(self) -> dict[str, ServoStatus | None]:
        """The backend's status of each configured axis servo (None if the backend lacks it)."""
        by_name = {status.name: status for status in self.backend.servo_statuses()}
        return {axis: by_name.get(servo) for axis, servo in self.settings.axis_servos.items()}

    def measured_angles(self) -> tuple[float, float, float]:
        """Measured roll/pitch/yaw (body); setpoint, then 0, where nothing was measured yet."""
        statuses = self.axis_statuses()
        angles = []
        for axis in AXES:
            status = statuses.get(axis)
            angles.append(_measured_or_setpoint(status))
        return (angles[0], angles[1], angles[2])

    def failure_flags(self) -> int:
        """GIMBAL_DEVICE_ERROR_FLAGS from servo faults, offline servos and clamped targets."""
        flags = 0
        for status in self.axis_statuses().values():
            if status is None or not status.online:
                flags |= COMMS_ERROR
                continue
            if status.state is None:
                continue
            for fault in Fault:
                if fault in status.state.faults:
                    flags |= FAULT_TO_FAILURE_FLAG.get(fault, MOTOR_ERROR)
            for check, flag in HEALTH_TO_FAILURE_FLAG.items():
                if check in status.health:
                    flags |= flag
        for axis in self._clamped_axes:
            flags |= AT_LIMIT_FLAG[axis]
        return flags

    def status_flags(self) -> int:
        """GIMBAL_DEVICE_FLAGS in effect: the demand's mode and locks, yaw in vehicle frame.

        The status q is built from servo angles, which are relative to the vehicle, hence
        YAW_IN_VEHICLE_FRAME; YAW_LOCK is set while an earth-frame yaw is being held.
        """
        flags = YAW_IN_VEHICLE_FRAME
        demand = self.demand
        if demand is None:
            return flags
        if demand.mode is Mode.RETRACT:
            return flags | RETRACT
        if demand.mode is Mode.NEUTRAL:
            return flags | NEUTRAL
        flags |= demand.flags & (ROLL_LOCK | PITCH_LOCK)
        if demand.mode is Mode.ANGLE and demand.yaw_in_earth_frame:
            flags |= YAW_LOCK
        return flags

    def attitude_status(self, now: float) -> Any:
        """GIMBAL_DEVICE_ATTITUDE_STATUS from the measured servo positions."""
        roll, pitch, yaw = self.measured_angles()
        rates = [math.nan, math.nan, math.nan]
        for i, status in enumerate(self.axis_statuses().get(axis) for axis in AXES):
            if status is not None and status.state is not None:
                velocity = status.state.velocity_dps
                if not math.isnan(velocity):
                    rates[i] = float32_field(math.radians(velocity))  # 1e41: an infinity
        delta_yaw = math.nan if self.vehicle_yaw_deg is None else math.radians(self.vehicle_yaw_deg)
        return mav.MAVLink_gimbal_device_attitude_status_message(
            target_system=0,
            target_component=0,
            time_boot_ms=self._time_boot_ms(now),
            flags=self.status_flags(),
            q=list(euler_to_quaternion(roll, pitch, yaw)),
            angular_velocity_x=rates[0],
            angular_velocity_y=rates[1],
            angular_velocity_z=rates[2],
            failure_flags=self.failure_flags(),
            delta_yaw=delta_yaw,
            delta_yaw_velocity=math.nan,
            gimbal_device_id=self._device_id_field(),
        )

    def capability_flags(self) -> int:
        """GIMBAL_DEVICE_CAP_FLAGS (same bits as GIMBAL_MANAGER_CAP_FLAGS) of this gimbal."""
        caps = mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_RETRACT | mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_NEUTRAL
        axis_caps = {
            "roll": mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_ROLL_AXIS
            | mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_ROLL_FOLLOW,
            "pitch": mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_PITCH_AXIS
            | mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_PITCH_FOLLOW,
            "yaw": mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_AXIS
            | mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_FOLLOW
            | mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_LOCK
            | mav.GIMBAL_DEVICE_CAP_FLAGS_SUPPORTS_YAW_IN_EARTH_FRAME,
        }
        for axis in self.settings.axis_servos:
            caps |= axis_caps[axis]
        return caps

    def _limits_rad(self) -> dict[str, float]:
        limits: dict[str, float] = {}
        for axis in AXES:
            if axis in self.settings.axis_servos:
                low, high = self.settings.limits(axis)
            else:
                low = high = 0.0
            limits[f"{axis}_min"] = math.radians(low)
            limits[f"{axis}_max"] = math.radians(high)
        return limits

    def device_information(self, now: float) -> Any:
        """GIMBAL_DEVICE_INFORMATION (ArduPilot requests it every second until it gets one)."""
        s = self.settings
        return mav.MAVLink_gimbal_device_information_message(
            time_boot_ms=self._time_boot_ms(now),
            vendor_name=s.vendor_name.encode()[:32],
            model_name=s.model_name.encode()[:32],
            custom_name=s.custom_name.encode()[:32],
            firmware_version=s.firmware_version,
            hardware_version=0,
            uid=s.uid,
            cap_flags=self.capability_flags(),
            custom_cap_flags=0,
            gimbal_device_id=self._device_id_field(),
            **self._limits_rad(),
        )

    def manager_information(self, now: float) -> Any:
        """GIMBAL_MANAGER_INFORMATION, only meaningful when acting as manager."""
        return mav.MAVLink_gimbal_manager_information_message(
            time_boot_ms=self._time_boot_ms(now),
            cap_flags=self.capability_flags(),
            gimbal_device_id=SAME_COMPONENT_DEVICE_ID,
            **self._limits_rad(),
        )

    def manager_status(self, now: float) -> Any:
        """GIMBAL_MANAGER_STATUS: flags in effect and who is in control."""
        return mav.MAVLink_gimbal_manager_status_message(
            time_boot_ms=self._time_boot_ms(now),
            flags=self.status_flags(),
            gimbal_device_id=SAME_COMPONENT_DEVICE_ID,
            primary_control_sysid=self.control.primary[0],
            primary_control_compid=self.control.primary[1],
            secondary_control_sysid=self.control.secondary[0],
            secondary_control_compid=self.control.secondary[1],
        )

    # ------------------------------------------------------------------ small helpers

    def _device_id_field(self) -> int:
        """``gimbal_device_id``: 1 when device and manager share the component, else 0 (spec)."""
        return SAME_COMPONENT_DEVICE_ID if self.settings.act_as_manager else 0

    def _note_time(self, now: float) -> None:
        if self._boot_time is None:
            self._boot_time = now

    def _time_boot_ms(self, now: float) -> int:
        boot = self._boot_time if self._boot_time is not None else now
        return int(max(0.0, now - boot) * 1000.0) & 0xFFFFFFFF

    def _addressed_to_me(self, msg: Any) -> bool:
        if msg.target_component not in (0, self.component_id):
            return False
        system_id = self.settings.system_id
        return system_id is None or msg.target_system in (0, system_id)

    def _from_my_system(self, msg: Any) -> bool:
        system_id = self.settings.system_id
        return system_id is None or msg.get_srcSystem() in (0, system_id)

    @staticmethod
    def _rates_of(msg: Any) -> tuple[float | None, float | None, float | None]:
        """Angular velocities of a SET_ATTITUDE in deg/s, None where NaN (= not used)."""
        rates = (msg.angular_velocity_x, msg.angular_velocity_y, msg.angular_velocity_z)
        return tuple(  # type: ignore[return-value]
            None if math.isnan(rate) else math.degrees(rate) for rate in rates
        )  # infinite stays infinite (math.degrees does not raise): validated by the caller


def _nan_to_none(values: Sequence[float]) -> tuple[float | None, ...]:
    return tuple(None if math.isnan(v) else float(v) for v in values)


def _angles_problem(values: Sequence[float]) -> str:
    """Why demanded angles (degrees, NaN = leave the axis alone) are unusable; "" if usable."""
    bad = [v for v in values if not math.isnan(v) and not abs(v) <= MAX_DEMAND_ANGLE_DEG]
    return f"angles {bad!r} deg not finite or beyond +-{MAX_DEMAND_ANGLE_DEG:g}" if bad else ""


def _rates_problem(rates_dps: Sequence[float | None]) -> str:
    """Why demanded rates (deg/s, None = not used) are unusable; "" if usable."""
    bad = [r for r in rates_dps if r is not None and not abs(r) <= MAX_DEMAND_RATE_DPS]
    return f"rates {bad!r} deg/s not finite or beyond +-{MAX_DEMAND_RATE_DPS:g}" if bad else ""


def _flags_problem(value: float) -> str:
    """Why a flags parameter (NaN = none) is unusable; "" if usable."""
    if math.isnan(value) or 0 <= value <= MAX_FLAGS:
        return ""
    return f"flags {value!r}"


def _attitude_problem(q: Sequence[float], rates_dps: Sequence[float | None]) -> str:
    """Why a SET_ATTITUDE's q or rates are unusable; "" if usable. A NaN q means "no attitude"
    (rates-only or retract); any other q must be a usable attitude."""
    if not is_nan_quaternion(q) and not is_usable_attitude(q):
        return f"q={list(q)!r} is not an attitude (zero, infinite or overflowing)"
    return _rates_problem(rates_dps)


def _sender_of(msg: Any) -> tuple[int, int] | None:
    sysid, compid = msg.get_srcSystem(), msg.get_srcComponent()
    return None if sysid == 0 else (sysid, compid)


def _measured_or_setpoint(status: ServoStatus | None) -> float:
    if status is None:
        return 0.0
    if status.state is not None and not math.isnan(status.state.position_deg):
        return status.state.position_deg
    if status.setpoint_deg is not None:
        return status.setpoint_deg
    return 0.0


def _same_angles(
    a: Sequence[float | None], b: Sequence[float | None], tolerance_deg: float
) -> bool:
    for x, y in zip(a, b, strict=True):
        if (x is None) != (y is None):
            return False
        if x is not None and y is not None and abs(x - y) > tolerance_deg:
            return False
    return True


def _next_deadline(previous: float, period: float, now: float) -> float:
    """Keep a fixed cadence, but skip missed slots instead of bursting to catch up."""
    deadline = previous + period
    return deadline if deadline > now else now + period
