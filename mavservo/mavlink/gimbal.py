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
  carries GIMBAL_DEVICE_ERROR_FLAGS_AT_{ROLL,PITCH,YAW}_LIMIT; the ``clamped`` counter counts
  clamps.
* **Refusals.** A demand the backend refuses (TEMPORARILY_REJECTED while a servo is offline) is
  forgotten, never retried: carrying it out once the servos are back would apply a command after
  its refusal. The next demand is a fresh one.
* **Hostile values.** Everything is validated before use: a quaternion must have finite
  components and a length of 0.5..2, angles must be finite and within a turn, rates finite and at
  most ``MAX_DEMAND_RATE_DPS``, flags and ids finite. A bad command is DENIED, a bad message
  ignored; both are counted (``bad_value``) and logged once per kind per interval.
* **Status.** q comes from the MEASURED servo positions, with failure flags from the servos'
  faults and health (``gimbal_report``).

Three parts, each with its own state and job: this module reads MAVLink (addressing, control,
validation, the retract shadow) and turns it into a :class:`~.gimbal_pointing.Demand`;
``gimbal_pointing.GimbalPointing`` holds the demand in effect and drives the servos (frames,
rates, limits, refusals); ``gimbal_report.GimbalReport`` builds what the gimbal publishes. Their
shared settings and counters are in ``gimbal_settings``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Sequence
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from mavservo.mavlink.backend import ActuatorBackend, Outcome
from mavservo.mavlink.gimbal_manager import ControlSlots, addresses_this_gimbal
from mavservo.mavlink.gimbal_pointing import (
    NEUTRAL,
    RETRACT,
    Demand,
    GimbalPointing,
    Mode,
    yaw_in_earth_frame,
)
from mavservo.mavlink.gimbal_report import GimbalReport
from mavservo.mavlink.gimbal_settings import Angles, GimbalCounters, GimbalSettings
from mavservo.mavlink.quaternion import (
    is_nan_quaternion,
    is_usable_attitude,
    quaternion_to_euler,
    wrap_180,
    yaw_of,
)

log = logging.getLogger(__name__)

MAV_TYPE_GIMBAL = mav.MAV_TYPE_GIMBAL  # 26

CMD_DO_MOUNT_CONTROL = mav.MAV_CMD_DO_MOUNT_CONTROL  # 205
CMD_DO_GIMBAL_MANAGER_PITCHYAW = mav.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW  # 1000
CMD_DO_GIMBAL_MANAGER_CONFIGURE = mav.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE  # 1001

MSG_GIMBAL_MANAGER_INFORMATION = mav.MAVLINK_MSG_ID_GIMBAL_MANAGER_INFORMATION  # 280
MSG_GIMBAL_MANAGER_STATUS = mav.MAVLINK_MSG_ID_GIMBAL_MANAGER_STATUS  # 281
MSG_GIMBAL_DEVICE_INFORMATION = mav.MAVLINK_MSG_ID_GIMBAL_DEVICE_INFORMATION  # 283
MSG_GIMBAL_DEVICE_ATTITUDE_STATUS = mav.MAVLINK_MSG_ID_GIMBAL_DEVICE_ATTITUDE_STATUS  # 285

IDENTITY_TOLERANCE = 1e-3
"""How close to (1, 0, 0, 0) a float32 quaternion must be to count as ArduPilot's shadow target."""
MAX_DEMAND_ANGLE_DEG = 360.0
"""A demanded angle beyond a full turn is not a pointing request but garbage (or an attack):
refused, not clamped, because clamping 3.4e38 to a limit would move the gimbal to that limit."""
MAX_DEMAND_RATE_DPS = 3600.0
"""Ten turns a second: far beyond any gimbal; a larger (or infinite) rate is refused."""
MAX_FLAGS = 0xFFFFFFFF
"""Largest flags value a command parameter may carry (the flags fields are uint32)."""
BAD_INPUT_LOG_INTERVAL_S = 10.0
"""One log line per kind of bad input per interval; the rest are only counted."""


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

    The device reads MAVLink: it validates, addresses and arbitrates every input and turns it
    into a demand. It owns two parts with a job each: :attr:`pointing` (the demand in effect,
    driven to the servos, ``gimbal_pointing``) and :attr:`report` (the status and information
    messages from the measured servos, ``gimbal_report``).
    """

    mav_type = MAV_TYPE_GIMBAL

    def __init__(
        self, settings: GimbalSettings, backend: ActuatorBackend, boot_time: float | None = None
    ) -> None:
        self.backend = backend
        self.component_id = settings.component_id
        self.counters = GimbalCounters()
        self.control = ControlSlots()
        self.report = GimbalReport(settings, backend, self.control, boot_time)
        self.pointing = GimbalPointing(
            settings, backend, self.counters, measured=self.report.measured_angles
        )
        self.settings = settings
        self._last_retract_message: float | None = None
        self._next_status = -math.inf
        self._next_manager_status = -math.inf
        self._bad_input_logged: dict[str, tuple[float, int]] = {}
        """kind of bad input -> (when its last line was logged, how many since)."""

    @property
    def settings(self) -> GimbalSettings:
        """The gimbal's settings; a PARAM_SET replaces them in every part at once. (The
        device's own code reads ``_settings``: no property call per message.)"""
        return self._settings

    @settings.setter
    def settings(self, settings: GimbalSettings) -> None:
        self._settings = settings
        self.pointing.settings = settings
        self.report.settings = settings

    @property
    def demand(self) -> Demand | None:
        """The demand in effect (None: none, or the last one was refused)."""
        return self.pointing.demand

    @property
    def vehicle_yaw_deg(self) -> float | None:
        """The vehicle heading last heard, None before any."""
        return self.pointing.vehicle_yaw_deg

    # ------------------------------------------------------------------ inputs

    def counter_values(self) -> dict[str, int]:
        """Each counter by name (:class:`~mavservo.mavlink.component.CountingComponent`)."""
        return dataclasses.asdict(self.counters)

    def handle_message(self, msg: Any, now: float) -> None:
        """Consume one received message; anything not gimbal-related is ignored cheaply."""
        self.report.note_time(now)
        kind = msg.get_type()
        if kind == "GIMBAL_DEVICE_SET_ATTITUDE":
            if not self._addressed_to_me(msg):
                self.counters.not_for_me += 1
                return
            self._on_set_attitude(kind, msg, now)
        elif kind == "GIMBAL_MANAGER_SET_ATTITUDE":
            if not (
                self._settings.act_as_manager
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
            self.pointing.follow_vehicle_yaw(yaw_of(msg.q), now)
        elif kind == "ATTITUDE" and self._from_my_system(msg) and not math.isnan(msg.yaw):
            # the spec's range is -pi..pi; beyond a couple of turns it is garbage (3e306 rad
            # overflows to inf in degrees and wraps to NaN)
            if not math.isfinite(msg.yaw) or abs(msg.yaw) > MAX_VEHICLE_YAW_RAD:
                self._bad_input(kind, f"vehicle yaw {msg.yaw!r}", now)
                return
            self.pointing.follow_vehicle_yaw(wrap_180(math.degrees(msg.yaw)), now)

    def forget_demand(self) -> None:
        """The autopilot was lost or restarted: its demand is over.

        Why (px4: issue 39): PX4 streams ATTITUDE at up to 100 Hz, and each one re-drives an
        earth-frame demand (the ATTITUDE branch of :meth:`handle_message`); after PX4 restarted,
        its first ATTITUDE drove the gimbal back to the demand of the PX4 before, which the new
        one never sent (the new one sends nothing until it has found the gimbal again). A
        demand kept through the restart would be a command applied late; the gimbal holds
        where the failsafe left it until a fresh demand comes (the servos' rule after a
        failsafe too: "servos move again on fresh commands")."""
        self.pointing.forget()
        self._last_retract_message = None

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
        log.warning("gimbal %s: %s ignored/denied: %s%s", self._settings.name, kind, detail, more)

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
        self.report.note_time(now)
        if command_id == CMD_DO_MOUNT_CONTROL:
            return self._do_mount_control(params, now)
        if not self._settings.act_as_manager:
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
            if ok:  # who is in control goes out with the next tick, not the next period
                self._next_manager_status = -math.inf
            return int(Outcome.ACCEPTED if ok else Outcome.DENIED)
        return None

    def handles_command(self, command_id: int) -> bool:
        """The commands :meth:`handle_command` acts on (the others return None, "not mine")."""
        if command_id == CMD_DO_MOUNT_CONTROL:
            return True
        manager_commands = (CMD_DO_GIMBAL_MANAGER_PITCHYAW, CMD_DO_GIMBAL_MANAGER_CONFIGURE)
        return bool(self._settings.act_as_manager) and command_id in manager_commands

    def supports_message(self, message_id: int) -> bool:
        """Whether a MAV_CMD_REQUEST_MESSAGE for ``message_id`` is ours to answer.

        A request for GIMBAL_MANAGER_INFORMATION/STATUS to a gimbal that is not its own manager
        must be answered UNSUPPORTED, so a ground station looks for the manager elsewhere.
        """
        if message_id in (MSG_GIMBAL_DEVICE_INFORMATION, MSG_GIMBAL_DEVICE_ATTITUDE_STATUS):
            return True
        if message_id in (MSG_GIMBAL_MANAGER_INFORMATION, MSG_GIMBAL_MANAGER_STATUS):
            return self._settings.act_as_manager
        return False

    def requested_message(self, message_id: int, now: float) -> Any | None:
        """The message answering a REQUEST_MESSAGE, or None if this gimbal does not provide it."""
        self.report.note_time(now)
        if not self.supports_message(message_id):
            return None
        if message_id == MSG_GIMBAL_DEVICE_INFORMATION:
            return self.report.device_information(now)
        if message_id == MSG_GIMBAL_DEVICE_ATTITUDE_STATUS:
            return self.attitude_status(now)
        if message_id == MSG_GIMBAL_MANAGER_INFORMATION:
            return self.report.manager_information(now)
        return self.manager_status(now)

    def periodic(self, now: float) -> list[Any]:
        """Advance rate targets and return the messages now due.

        GIMBAL_DEVICE_ATTITUDE_STATUS at ``status_rate_hz``; as manager also GIMBAL_MANAGER_STATUS
        at ``manager_status_rate_hz``. A late call sends one message, not a burst. A refused
        demand is not retried here: the pointing has forgotten it.
        """
        self.report.note_time(now)
        self.pointing.advance(now)
        out: list[Any] = []
        if now >= self._next_status:
            out.append(self.attitude_status(now))
            self._next_status = _next_deadline(
                self._next_status, 1.0 / self._settings.status_rate_hz, now
            )
        if self._settings.act_as_manager and now >= self._next_manager_status:
            out.append(self.manager_status(now))
            self._next_manager_status = _next_deadline(
                self._next_manager_status, 1.0 / self._settings.manager_status_rate_hz, now
            )
        return out

    # ------------------------------------------------------------------ demand handling

    def _on_attitude_demand(
        self,
        flags: int,
        q: Sequence[float],
        rates_dps: Angles,
        now: float,
    ) -> None:
        """Turn one SET_ATTITUDE (device or manager) into the demand in effect, then drive."""
        if flags & RETRACT:
            self._last_retract_message = now
            self.pointing.point(Demand(Mode.RETRACT, flags=flags, from_message_retract=True), now)
            return
        if self._is_retract_shadow(flags, q, now):
            self.counters.shadow_ignored += 1
            return
        if flags & NEUTRAL:
            self.pointing.point(Demand(Mode.NEUTRAL, flags=flags), now)
            return
        if is_nan_quaternion(q):
            if all(rate is None for rate in rates_dps):
                self.counters.no_target += 1
                return
            self.pointing.start_rates(rates_dps, flags, now)
            return
        roll, pitch, yaw = quaternion_to_euler(q)
        self.pointing.point(
            Demand(Mode.ANGLE, (roll, pitch, yaw), yaw_in_earth_frame(flags), flags), now
        )

    def _is_retract_shadow(self, flags: int, q: Sequence[float], now: float) -> bool:
        """ArduPilot's identity target sent right after each RETRACT message (see module doc)."""
        demand = self.pointing.demand
        if demand is None or demand.mode is not Mode.RETRACT or not demand.from_message_retract:
            return False
        if self._last_retract_message is None:
            return False
        if now - self._last_retract_message > self._settings.retract_hold_s:
            return False
        return not (flags & NEUTRAL) and not is_nan_quaternion(q) and _is_identity(q)

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
        return int(self.pointing.point(demand, now).outcome)

    def _do_pitchyaw(self, params: tuple[float, ...], now: float) -> int:
        """DO_GIMBAL_MANAGER_PITCHYAW: p1 pitch, p2 yaw (deg), p3/p4 rates (deg/s), p5 flags."""
        problem = _flags_problem(params[4]) or _angles_problem(params[:2])
        problem = problem or _rates_problem(_nan_to_none(params[2:4]))
        if problem:
            return self._deny("DO_GIMBAL_MANAGER_PITCHYAW", problem, now)
        flags = 0 if math.isnan(params[4]) else int(params[4])
        self._last_retract_message = None
        if flags & RETRACT:
            return int(self.pointing.point(Demand(Mode.RETRACT, flags=flags), now).outcome)
        if flags & NEUTRAL:
            return int(self.pointing.point(Demand(Mode.NEUTRAL, flags=flags), now).outcome)
        pitch, yaw = _finite_or_none(params[0]), _finite_or_none(params[1])
        if pitch is None and yaw is None:
            rates = (None, _finite_or_none(params[2]), _finite_or_none(params[3]))
            if rates[1] is None and rates[2] is None:
                return int(Outcome.DENIED)
            return int(self.pointing.start_rates(rates, flags, now).outcome)
        demand = Demand(Mode.ANGLE, (0.0, pitch, yaw), yaw_in_earth_frame(flags), flags)
        return int(self.pointing.point(demand, now).outcome)

    def _deny(self, command: str, problem: str, now: float) -> int:
        """DENIED for a hostile parameter, counted and logged (rate-limited)."""
        self._bad_input(command, problem, now)
        return int(Outcome.DENIED)

    # ------------------------------------------------------------------ outputs

    def attitude_status(self, now: float) -> Any:
        """GIMBAL_DEVICE_ATTITUDE_STATUS: the measured servos and the pointing in effect."""
        return self.report.attitude_status(now, self.pointing)

    def manager_status(self, now: float) -> Any:
        """GIMBAL_MANAGER_STATUS: the flags in effect and who is in control."""
        return self.report.manager_status(now, self.pointing.status_flags())

    # ------------------------------------------------------------------ small helpers

    def _addressed_to_me(self, msg: Any) -> bool:
        if msg.target_component not in (0, self.component_id):
            return False
        system_id = self._settings.system_id
        return system_id is None or msg.target_system in (0, system_id)

    def _from_my_system(self, msg: Any) -> bool:
        system_id = self._settings.system_id
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


def _next_deadline(previous: float, period: float, now: float) -> float:
    """Keep a fixed cadence, but skip missed slots instead of bursting to catch up."""
    deadline = previous + period
    return deadline if deadline > now else now + period
