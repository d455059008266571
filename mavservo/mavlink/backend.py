"""The boundary between the MAVLink layer and the servo side of the bridge.

The MAVLink handlers (commands, mirroring, gimbal, telemetry) never touch the scheduler, the
mapping or a CAN bus directly: they talk to an :class:`ActuatorBackend`. The bridge implements it
on top of the mapping and the scheduler; tests of the MAVLink layer can implement it with a small
recording class. Keeping this one narrow interface is what lets each side be tested alone.

All values are in the units MAVLink uses at this boundary (PWM microseconds, normalized actuator
values in [-1, 1], degrees for gimbal axes); the backend converts them with the YAML mapping.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from mavservo.servos import ServoState


class Outcome(enum.IntEnum):
    """What happened to a request; values equal MAV_RESULT so they can go into a COMMAND_ACK."""

    ACCEPTED = 0
    TEMPORARILY_REJECTED = 1
    DENIED = 2
    UNSUPPORTED = 3
    FAILED = 4


@dataclass(frozen=True)
class ApplyResult:
    """Outcome of one setpoint request, with a human-readable reason for logs and STATUSTEXT."""

    outcome: Outcome
    reason: str = ""

    @property
    def ok(self) -> bool:
        return self.outcome is Outcome.ACCEPTED


ACCEPTED = ApplyResult(Outcome.ACCEPTED)


class Health(enum.Flag):
    """What the bridge's own health monitor (``mavservo.control.health``) finds wrong with a
    servo from what it was told and what it measures, apart from the faults the servo reports
    itself (:class:`~mavservo.servos.base.Fault`). Published as ``s<n>_hlt``; new members go at
    the end so the bit values never move."""

    TRACKING = enum.auto()
    """Not where it was told to be, for longer than the commanded motion allows."""
    JAMMED = enum.auto()
    """Told to move, not moving, current at its limit: blocked."""
    SLIPPING = enum.auto()
    """The motor turns but the output does not follow, or the output moves on its own."""
    OVERLOAD = enum.auto()
    """Current above the continuous rating for longer than its I^2 t budget."""
    HOT = enum.auto()
    """Temperature at or above the warning level."""
    OVERHEATED = enum.auto()
    """Temperature at or above the limit (the configured action is in force)."""
    SUPPLY = enum.auto()
    """Supply voltage outside its range."""


NO_HEALTH_PROBLEM = Health(0)


@dataclass(frozen=True)
class ServoStatus:
    """What the MAVLink side may report about one servo.

    ``normalized`` is the measured position mapped back through the channel mapping to [-1, 1]
    (None when unknown); ``setpoint_deg`` is the last accepted target.
    """

    name: str
    index: int  # 0-based position of the servo in the config, stable across a run
    state: ServoState | None
    online: bool
    setpoint_deg: float | None
    normalized: float | None
    servo_channel: int | None  # MAVLink servo output channel it mirrors, if any
    actuator_index: int | None  # DO_SET_ACTUATOR index, if any
    health: Health = NO_HEALTH_PROBLEM  # what the bridge's health monitor finds (s<n>_hlt)


@runtime_checkable
class ActuatorBackend(Protocol):
    """What the MAVLink layer needs from the servo side.

    ``source`` names the origin of a request ("servo_output_raw", "do_set_servo",
    "do_set_actuator", "gimbal", "failsafe", ...) so the backend can arbitrate between sources and
    log every decision. ``now`` is ``time.monotonic()`` at receipt.
    """

    def mapped_servo_channels(self) -> set[int]:
        """MAVLink servo output channels (1-based, port offsets applied) that map to a servo."""

    def mapped_actuator_indices(self) -> set[int]:
        """DO_SET_ACTUATOR / ACTUATOR_OUTPUT_STATUS indices (1-based) that map to a servo."""

    def apply_servo_output(
        self, channel: int, pwm_us: float, source: str, now: float
    ) -> ApplyResult:
        """Drive the servo mapped to servo output ``channel`` to the angle ``pwm_us`` maps to."""

    def apply_actuator(self, index: int, value: float, source: str, now: float) -> ApplyResult:
        """Drive the servo mapped to actuator ``index`` to the angle normalized ``value`` gives."""

    def apply_gimbal(
        self,
        gimbal: str,
        roll_deg: float | None,
        pitch_deg: float | None,
        yaw_deg: float | None,
        source: str,
        now: float,
    ) -> ApplyResult:
        """Drive a gimbal group's axes (None = leave that axis alone); angles are body frame."""

    def servo_statuses(self) -> list[ServoStatus]:
        """Snapshot of every servo, in config order."""

    def enter_failsafe(self, reason: str, now: float) -> None:
        """Apply every servo's configured failsafe action (link lost, shutdown)."""

    def leave_failsafe(self, now: float) -> None:
        """Allow fresh commands to drive the servos again; nothing moves until one arrives."""

    def health(self) -> dict[str, float]:
        """Transport figures to publish as NAMED_VALUE_FLOAT (``bus0_load``, ``lat_p99``), by
        name of at most 10 characters; empty when there are none."""
