"""Where a gimbal is told to point: the demand in effect, driven to the servos as body angles.

Why a part of its own: what the gimbal was asked (a demand in a mode and a frame) and what goes
to the servos (body angles, clamped to the limits, not re-sent while unchanged, forgotten once
refused) is state and policy that neither reading MAVLink (``gimbal.GimbalDevice``) nor the
status it publishes (``gimbal_report.GimbalReport``) needs to hold. The servo side is one call,
:class:`GimbalDrive`, so the pointing is tested alone with a recording fake. Sans-I/O: ``now``
always comes in as an argument.
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

from pymavlink.dialects.v20 import ardupilotmega as mav

from mavservo.mavlink.backend import ApplyResult, Outcome
from mavservo.mavlink.gimbal_settings import AXES, Angles, GimbalCounters, GimbalSettings
from mavservo.mavlink.quaternion import earth_to_body_yaw, wrap_180

# Flag values are shared by GIMBAL_DEVICE_FLAGS and GIMBAL_MANAGER_FLAGS (same bits by design).
RETRACT = mav.GIMBAL_DEVICE_FLAGS_RETRACT
NEUTRAL = mav.GIMBAL_DEVICE_FLAGS_NEUTRAL
ROLL_LOCK = mav.GIMBAL_DEVICE_FLAGS_ROLL_LOCK
PITCH_LOCK = mav.GIMBAL_DEVICE_FLAGS_PITCH_LOCK
YAW_LOCK = mav.GIMBAL_DEVICE_FLAGS_YAW_LOCK
YAW_IN_VEHICLE_FRAME = mav.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME
YAW_IN_EARTH_FRAME = mav.GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME

CLAMP_TOLERANCE_DEG = 1e-3
"""A request this close to a limit is float32 noise, not a clamp worth reporting."""
SOURCE = "gimbal"
"""``source`` passed to the backend for every gimbal request."""


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
    angles: Angles = (None, None, None)
    yaw_in_earth_frame: bool = False
    flags: int = 0
    rates_dps: Angles = (None, None, None)
    since: float = 0.0
    from_message_retract: bool = False


def yaw_in_earth_frame(flags: int) -> bool:
    """Frame of the yaw in a demand: flag 64, or ArduPilot's old YAW_LOCK without flag 32."""
    if flags & YAW_IN_EARTH_FRAME:
        return True
    if flags & YAW_IN_VEHICLE_FRAME:
        return False
    return bool(flags & YAW_LOCK)


class GimbalDrive(Protocol):
    """The servo side as the pointing sees it (``ActuatorBackend.apply_gimbal``)."""

    def apply_gimbal(
        self,
        gimbal: str,
        roll_deg: float | None,
        pitch_deg: float | None,
        yaw_deg: float | None,
        source: str,
        now: float,
    ) -> ApplyResult:
        """Move the gimbal's axis servos to body angles (None: leave the axis alone)."""
        ...


class GimbalPointing:
    """The demand in effect and the body angles it asks of the servos.

    ``measured()`` gives the measured roll/pitch/yaw, where a rate demand starts from when no
    target is in effect. ``settings`` may be replaced (a PARAM_SET of the limits): the next
    drive uses the new limits. ``counters`` is the gimbal's shared tally (applied, rejected,
    clamped).
    """

    def __init__(
        self,
        settings: GimbalSettings,
        drive: GimbalDrive,
        counters: GimbalCounters,
        measured: Callable[[], tuple[float, float, float]],
    ) -> None:
        self.settings = settings
        self._servos = drive
        self.counters = counters
        self._measured = measured
        self.demand: Demand | None = None
        self.vehicle_yaw_deg: float | None = None
        self.last_result: ApplyResult | None = None
        self._applied_angles: Angles | None = None
        self.clamped_axes: frozenset[str] = frozenset()
        """Axes whose target is held at a limit (the status's AT_*_LIMIT flags)."""

    def point(self, demand: Demand, now: float) -> ApplyResult:
        """Make ``demand`` the one in effect and drive it.

        Not forced: ArduPilot repeats the same target at 50 Hz, and the scheduler already
        refreshes the last setpoint, so an unchanged target is not sent to the backend again
        (unless the previous request was refused).
        """
        self.demand = demand
        return self._drive(now)

    def start_rates(self, rates_dps: Angles, flags: int, now: float) -> ApplyResult:
        """Begin integrating rates from the body angles currently targeted (or measured)."""
        base = self._current_body_angles(now)
        return self.point(
            Demand(Mode.RATE, base, False, flags, rates_dps=rates_dps, since=now), now
        )

    def follow_vehicle_yaw(self, yaw_deg: float, now: float) -> None:
        """Remember the vehicle heading; an earth-frame yaw target must follow it."""
        self.vehicle_yaw_deg = yaw_deg
        if (
            self.demand is not None
            and self.demand.mode is Mode.ANGLE
            and self.demand.yaw_in_earth_frame
        ):
            self._drive(now)

    def advance(self, now: float) -> None:
        """Step a rate demand to ``now`` (the other modes hold their target)."""
        if self.demand is not None and self.demand.mode is Mode.RATE:
            self._drive(now)

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

    def target_body_angles(self, now: float) -> Angles:
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

    def _clamp(self, angles: Angles) -> tuple[Angles, frozenset[str]]:
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
        if clamped_axes and (force or clamped_axes != self.clamped_axes):
            self.counters.clamped += 1
        self.clamped_axes = clamped_axes
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
        result = self._servos.apply_gimbal(self.settings.name, *angles, SOURCE, now)
        self.last_result = result
        self._applied_angles = angles
        if result.ok:
            self.counters.applied += 1
        else:
            self.counters.rejected += 1
            self._forget_refused_demand()
        return result

    def forget(self) -> None:
        """Drop the demand in effect and what was applied (the autopilot that gave it was lost
        or restarted, px4: issue 39): nothing is driven until a fresh demand, and a fresh one
        equal to the old is applied again (the servos went to their failsafe meanwhile)."""
        self.demand = None
        self.last_result = None
        self._applied_angles = None
        self.clamped_axes = frozenset()

    def _forget_refused_demand(self) -> None:
        """A refused demand is over: its sender got the refusal, so carrying it out later would
        be a command applied after its NACK. (It used to be retried on every status tick, and
        the trial's gimbal moved to a pitch refused during an adapter outage 2.2 s after the
        adapter came back.) The servos hold what they had; the next demand is a fresh one,
        as for a servo whose move was abandoned while it was offline (servo_backend)."""
        self.demand = None
        self.clamped_axes = frozenset()

    def _current_body_angles(self, now: float) -> Angles:
        """Where rates start from: the clamped current target, else the measured angles."""
        if self.demand is not None:
            target, _ = self._clamp(self.target_body_angles(now))
            if all(
                angle is not None
                for axis, angle in zip(AXES, target, strict=True)
                if axis in self.settings.axis_servos
            ):
                return target
        measured = self._measured()
        return (
            measured[0] if "roll" in self.settings.axis_servos else None,
            measured[1] if "pitch" in self.settings.axis_servos else None,
            measured[2] if "yaw" in self.settings.axis_servos else None,
        )


def _same_angles(
    a: Sequence[float | None], b: Sequence[float | None], tolerance_deg: float
) -> bool:
    for x, y in zip(a, b, strict=True):
        if (x is None) != (y is None):
            return False
        if x is not None and y is not None and abs(x - y) > tolerance_deg:
            return False
    return True
