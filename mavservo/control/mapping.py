"""Channel mapping: MAVLink input values <-> servo angles (pure: no I/O, no clock).

One :class:`ChannelMap` per ``channels:`` entry of the config. The conversion goes through a
normalized position ``u`` in [-1, 1], piecewise linear on each side of the trim point, so that
the input trim always lands exactly on the output centre (``(low + high) / 2 + trim_deg``)
even when the input range is asymmetric (an ArduPilot SERVOn_TRIM that is not the middle)::

    input  min ........ trim ........ max
    u       -1    ...     0    ...     +1      (negated when reverse)
    angle  low  ......  centre ......  high    then clamped to the servo's soft limits

Bad input values are not errors but a typed :class:`Rejected` result: the MAVLink layer turns
the reason into COMMAND_ACK DENIED (or, for "no pulse", simply ignores the sample).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

if TYPE_CHECKING:
    from mavservo.config import ActuatorChannel, Config, ServoOutputChannel

#: PWM values outside this window are not positions (DO_SET_SERVO sanity bounds).
PWM_VALID_US = (800.0, 2200.0)
#: Tolerance on normalized inputs, so a float round trip of exactly 1.0 is not refused.
_NORMALIZED_EPSILON = 1e-9

InputKind = Literal["pwm", "normalized"]


class RejectReason(enum.Enum):
    """Why an input value is not a position."""

    NOT_FINITE = "not a finite number"
    NO_PULSE = "PWM 0 means no pulse"
    OUT_OF_RANGE = "outside the valid input range"


@dataclass(frozen=True)
class Rejected:
    """An input that must not move the servo; ``detail`` is for COMMAND_ACK reasons and logs."""

    reason: RejectReason
    detail: str

    @property
    def ignore_silently(self) -> bool:
        """True for "no pulse": a mirrored 0 is the autopilot saying nothing, not a bad command."""
        return self.reason is RejectReason.NO_PULSE


@dataclass(frozen=True)
class Target:
    """A mapped setpoint: the angle to send and whether a limit changed what was asked."""

    angle_deg: float
    requested_deg: float
    clamped: bool


@dataclass(frozen=True)
class ChannelMap:
    """The mapping of one channel: input range, output range, reverse, trim, soft limits, slew."""

    kind: InputKind
    input_min: float
    input_trim: float
    input_max: float
    output_deg: tuple[float, float]
    limits_deg: tuple[float, float]
    reverse: bool = False
    trim_deg: float = 0.0
    max_slew_dps: float | None = None

    def __post_init__(self) -> None:
        if not self.input_min < self.input_trim < self.input_max:
            raise ValueError("input range must satisfy min < trim < max")
        low, high = self.output_deg
        if not low < self.centre_deg < high:
            raise ValueError("output centre (with trim_deg) must lie inside output_deg")
        if not self.limits_deg[0] < self.limits_deg[1]:
            raise ValueError("limits_deg must be ordered")

    @classmethod
    def from_config(
        cls, channel: ServoOutputChannel | ActuatorChannel, config: Config
    ) -> ChannelMap:
        """Build the map of one validated ``channels:`` entry (output defaults to servo limits)."""
        servo = config.servo(channel.servo)
        return cls(
            kind="pwm" if channel.source == "servo_output" else "normalized",
            input_min=float(channel.input.min),
            input_trim=float(channel.input.resolved_trim),
            input_max=float(channel.input.max),
            output_deg=config.channel_output_deg(channel),
            limits_deg=servo.limits_deg,
            reverse=channel.reverse,
            trim_deg=channel.trim_deg,
            max_slew_dps=channel.max_slew_dps,
        )

    @property
    def centre_deg(self) -> float:
        """The angle the input trim maps to."""
        low, high = self.output_deg
        return (low + high) / 2 + self.trim_deg

    # ---------------------------------------------------------------- input -> angle

    def validate_input(self, value: float) -> Rejected | None:
        """None when ``value`` is a usable input, else why not."""
        if not math.isfinite(value):
            return Rejected(RejectReason.NOT_FINITE, f"input {value!r} is not a finite number")
        if self.kind == "pwm":
            if value == 0:
                return Rejected(RejectReason.NO_PULSE, "PWM 0 (no pulse) is not a position")
            low, high = PWM_VALID_US
            if not low <= value <= high:
                return Rejected(
                    RejectReason.OUT_OF_RANGE, f"PWM {value:g} us is outside {low:g}..{high:g} us"
                )
        elif not -1.0 - _NORMALIZED_EPSILON <= value <= 1.0 + _NORMALIZED_EPSILON:
            return Rejected(RejectReason.OUT_OF_RANGE, f"value {value:g} is outside [-1, 1]")
        return None

    def input_to_normalized(self, value: float) -> float | Rejected:
        """Input -> u in [-1, 1] (before reverse); a valid input beyond min/max saturates."""
        rejected = self.validate_input(value)
        if rejected is not None:
            return rejected
        if value >= self.input_trim:
            u = (value - self.input_trim) / (self.input_max - self.input_trim)
        else:
            u = (value - self.input_trim) / (self.input_trim - self.input_min)
        return max(-1.0, min(1.0, u))

    def to_angle(self, value: float) -> Target | Rejected:
        """Input value -> target angle, clamped to the soft limits (and saying so)."""
        u = self.input_to_normalized(value)
        if isinstance(u, Rejected):
            return u
        requested = self._angle_from_u(-u if self.reverse else u)
        angle, clamped = clamp(requested, self.limits_deg)
        return Target(angle, requested, clamped)

    def _angle_from_u(self, u: float) -> float:
        low, high = self.output_deg
        centre = self.centre_deg
        if u >= 0:
            return centre + u * (high - centre)
        return centre + u * (centre - low)

    # ---------------------------------------------------------------- angle -> input

    def angle_to_normalized(self, angle_deg: float) -> float:
        """Measured angle -> normalized [-1, 1] in the input's sense (ACTUATOR_OUTPUT_STATUS).

        Angles beyond the output range saturate at -1 / +1; reverse is undone.
        """
        low, high = self.output_deg
        centre = self.centre_deg
        angle = max(low, min(high, angle_deg))
        if angle >= centre:
            u = (angle - centre) / (high - centre)
        else:
            u = (angle - centre) / (centre - low)
        return -u if self.reverse else u

    def angle_to_input(self, angle_deg: float) -> float:
        """Measured angle -> the input value (PWM us for display) that would command it."""
        u = self.angle_to_normalized(angle_deg)
        if u >= 0:
            return self.input_trim + u * (self.input_max - self.input_trim)
        return self.input_trim + u * (self.input_trim - self.input_min)

    # ---------------------------------------------------------------- rate limiting

    def slew(self, previous_deg: float | None, target_deg: float, dt_s: float) -> float:
        """This channel's slew limit applied to one step (see :func:`slew_limit`)."""
        if previous_deg is None or self.max_slew_dps is None:
            return target_deg
        return slew_limit(previous_deg, target_deg, dt_s, self.max_slew_dps)


def clamp(angle_deg: float, limits_deg: tuple[float, float]) -> tuple[float, bool]:
    """``angle_deg`` inside ``limits_deg``, and whether it had to be moved."""
    low, high = limits_deg
    clamped = min(high, max(low, angle_deg))
    return clamped, clamped != angle_deg


def slew_limit(previous_deg: float, target_deg: float, dt_s: float, max_slew_dps: float) -> float:
    """The furthest point toward ``target_deg`` reachable from ``previous_deg`` in ``dt_s``.

    A non-positive ``dt_s`` (a repeated or out-of-order timestamp) allows no motion at all, so a
    burst of commands at one instant cannot bypass the limit.
    """
    if max_slew_dps <= 0:
        raise ValueError(f"max_slew_dps must be positive, got {max_slew_dps!r}")
    step = max_slew_dps * max(0.0, dt_s)
    delta = target_deg - previous_deg
    if abs(delta) <= step:
        return target_deg
    return previous_deg + math.copysign(step, delta)


def channel_maps(config: Config) -> list[ChannelMap]:
    """One map per ``channels:`` entry, in config order."""
    return [ChannelMap.from_config(channel, config) for channel in config.channels]
