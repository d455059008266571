"""CubeMars AK series in "servo mode".

Wire facts (extended 29-bit IDs, big-endian):

* command ID ``(mode << 8) | id``; mode 4 = position, ``int32 deg * 10000`` (4 bytes);
  mode 6 = position + speed: ``int32 deg * 10000, int16 ERPM / 10, int16 ERPM/s / 10``;
* the servo pushes status on ``0x2900 | id`` at its configured rate (no polling):
  ``position i16 0.1 deg, speed i16 10 ERPM, current i16 0.01 A, temperature i8, error u8``,
  error codes 1 over-temperature, 2 over-current, 3 over-voltage, 4 under-voltage, 5 encoder,
  6 phase imbalance.

Speeds travel as electrical RPM of the motor's rotor (the manual's servo-mode tables: speed
"ERPM", electrical speed), positions as degrees of the output (after the module's gearbox). So
one output degree per second is ``pole_pairs x gear_ratio / 6`` ERPM (``erpm_per_dps``): an
AK80-9 (21 pole pairs, 9:1) turns 1 output deg/s at 31.5 ERPM. Both are per model: the
``model`` option names an AK model (its pole pairs from :data:`MODEL_POLE_PAIRS`, its ratio from
:data:`MODEL_GEAR_RATIO`: the number after the dash), ``pole_pairs`` and ``gear_ratio``
override them; the default is an AK80-9.

Servo mode has no motor-off or enable command, so the profile has no lifecycle frames and
``failsafe: release`` is refused for it.

Range policy: angles outside the documented +-36000 deg raise ``ValueError``; speed limits
saturate at what the int16 field can carry; a position command without a speed limit uses
mode 4 (the servo's own configured speed).
"""

from __future__ import annotations

import struct
from typing import Literal

import can
from pydantic import Field

from ..base import (
    NO_FAULT,
    Fault,
    FrameId,
    ProfileOptions,
    ServoProfile,
    ServoState,
    SimDevice,
    SimMotor,
)
from ..sim_registry import simulated_device

MODE_POSITION = 4
MODE_POSITION_SPEED = 6
STATUS_BASE = 0x2900

ERROR_CODES: dict[int, Fault] = {
    1: Fault.OVER_TEMPERATURE,
    2: Fault.OVER_CURRENT,
    3: Fault.OVER_VOLTAGE,
    4: Fault.LOW_VOLTAGE,
    5: Fault.ENCODER,
    6: Fault.PHASE_IMBALANCE,
}

DEFAULT_POLE_PAIRS = 21

MODEL_POLE_PAIRS: dict[str, int] = {
    "AK10-9": 21,
    "AK60-6": 14,
    "AK70-10": 21,
    "AK80-6": 21,
    "AK80-8": 21,
    "AK80-9": 21,
    "AK80-64": 21,
}
"""Pole pairs of the AK models. Only AK80-9 (21), AK70-10 (21) and AK60-6 (14) were checked
against an independent driver's table; the others are unverified here: check your model's
datasheet and set ``pole_pairs`` when in doubt (it overrides the model)."""

MODEL_GEAR_RATIO: dict[str, float] = {
    "AK10-9": 9.0,
    "AK60-6": 6.0,
    "AK70-10": 10.0,
    "AK80-6": 6.0,
    "AK80-8": 8.0,
    "AK80-9": 9.0,
    "AK80-64": 64.0,
}
"""Reduction ratio of each AK module (its name: AK80-9 is 9:1; the manual's product tables)."""

ModelName = Literal["AK10-9", "AK60-6", "AK70-10", "AK80-6", "AK80-8", "AK80-9", "AK80-64"]

COMMAND_MODES = range(8)
"""Servo-mode command modes 0..7 ((mode << 8) | id): the ids a servo of this id listens on."""


def fault_from_error_code(code: int) -> Fault:
    """The status frame carries one error code (not bits); unknown codes are ``OTHER``."""
    if code == 0:
        return NO_FAULT
    return ERROR_CODES.get(code, Fault.OTHER)


def command_id(mode: int, can_id: int) -> int:
    return (mode << 8) | can_id


class CubeMarsOptions(ProfileOptions):
    """Per-servo options of CubeMars AK servo mode."""

    model: ModelName = Field("AK80-9", description="the AK model: sets the pole pairs")
    pole_pairs: int | None = Field(
        None, ge=1, le=64, description="motor pole pairs (null: the model's); speeds are ERPM"
    )
    gear_ratio: float | None = Field(
        None,
        ge=1.0,
        le=1000.0,
        description="output gear reduction (null: the model's, e.g. 9 for an AK80-9); speeds "
        "are rotor ERPM, positions output degrees",
    )
    accel_dps2: float = Field(
        3600.0, gt=0, le=1_000_000, description="acceleration limit sent with a speed (deg/s^2)"
    )

    def resolved_pole_pairs(self) -> int:
        """``pole_pairs`` if set, else the model's."""
        return self.pole_pairs if self.pole_pairs is not None else MODEL_POLE_PAIRS[self.model]

    def resolved_gear_ratio(self) -> float:
        """``gear_ratio`` if set, else the model's."""
        return self.gear_ratio if self.gear_ratio is not None else MODEL_GEAR_RATIO[self.model]


class CubeMarsAK(ServoProfile):
    """CubeMars AK servo mode: push-style status, so ``telemetry_requests()`` is empty."""

    STOP_BEHAVIOUR = "holds its last target (servo mode has no command timeout)"

    name = "cubemars-ak"
    Options = CubeMarsOptions
    options: CubeMarsOptions
    telemetry = "pushed"
    resolution_deg = 0.1
    replies_per_command = 1
    """The real servo only pushes at its rate; the simulator also answers each command, and
    counting that frame keeps the bus-load budget on the safe side."""
    replies_per_request = 0
    min_id, max_id = 0, 255
    min_angle_deg, max_angle_deg = -36000.0, 36000.0

    def __init__(self, can_id: int, options: ProfileOptions | None = None, **overrides: object):
        super().__init__(can_id, options, **overrides)
        self.erpm_per_dps = erpm_per_dps(self.options)
        self.accel_dps2 = self.options.accel_dps2
        self.max_speed_dps = 32767 * 10 / self.erpm_per_dps

    @property
    def status_id(self) -> int:
        return STATUS_BASE | self.can_id

    def identifiers(self) -> tuple[FrameId, ...]:
        """The servo listens on every servo-mode command id of its id; it pushes on 0x29xx."""
        commands = tuple(
            FrameId(command_id(mode, self.can_id), True, "to_servo", "command")
            for mode in COMMAND_MODES
        )
        return (*commands, FrameId(self.status_id, True, "from_servo", "push"))

    @classmethod
    def sim_device(cls, motor: SimMotor, can_id: int, options: ProfileOptions) -> SimDevice:
        return simulated_device(cls, motor, can_id, options)

    def position_command(self, angle_deg: float, max_speed_dps: float | None = None) -> can.Message:
        self._check_angle(angle_deg)
        position = round(angle_deg * 10_000)
        if max_speed_dps is None:
            return can.Message(
                arbitration_id=command_id(MODE_POSITION, self.can_id),
                is_extended_id=True,
                data=struct.pack(">i", position),
            )
        speed = self._speed_limit(max_speed_dps, max_speed_dps)
        accel = min(self.accel_dps2, self.max_speed_dps)
        return can.Message(
            arbitration_id=command_id(MODE_POSITION_SPEED, self.can_id),
            is_extended_id=True,
            data=struct.pack(
                ">ihh",
                position,
                self._erpm_field(speed),
                self._erpm_field(accel),
            ),
        )

    def _erpm_field(self, dps: float) -> int:
        """A speed or acceleration in units of 10 ERPM, saturated, and never rounded down to
        0 when it was not 0 (the servo would read 0 as "no limit")."""
        field = min(32767, round(dps * self.erpm_per_dps / 10))
        return max(1, field) if dps > 0 else 0

    def telemetry_requests(self) -> list[can.Message]:
        return []

    def is_reply(self, msg: can.Message) -> bool:
        return (
            msg.is_extended_id
            and not msg.is_remote_frame
            and msg.arbitration_id == self.status_id
            and len(msg.data) == 8
        )

    def decode(self, msg: can.Message, timestamp: float) -> ServoState | None:
        if not self.is_reply(msg):
            return None
        position, speed, current, temperature, error = struct.unpack(">hhhbB", bytes(msg.data))
        return self._merge(
            timestamp,
            position_deg=position / 10,
            velocity_dps=speed * 10 / self.erpm_per_dps,
            current_a=current / 100,
            temperature_c=float(temperature),
            faults=fault_from_error_code(error),
        )


def erpm_per_dps(options: CubeMarsOptions) -> float:
    """Rotor electrical RPM per output degree per second: pole pairs x gear ratio / 6."""
    return options.resolved_pole_pairs() * options.resolved_gear_ratio() / 6
