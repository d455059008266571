"""The MIT packing: one 8-byte command and one reply layout shared by several servo families.

Damiao DM-J (MIT mode), CubeMars AK (MIT power mode) and Robstride (MIT mode after a protocol
switch) all speak the packing of the MIT Cheetah motor controller: five set points squeezed into
one classic CAN frame as big-endian bit fields, each a linear map of a ``[min, max]`` range onto
the unsigned range of its width:

====================  ====  =============================================
field                 bits  where
====================  ====  =============================================
position (rad)        16    D0, D1
velocity (rad/s)      12    D2, D3[7:4]
kp (N m / rad)        12    D3[3:0], D4
kd (N m s / rad)      12    D5, D6[7:4]
torque feed-forward   12    D6[3:0], D7
====================  ====  =============================================

The reply carries a byte the family defines (a motor id, or Damiao's ``status << 4 | id``),
then position 16, velocity 12 and torque (or current) 12 bits the same way, then up to two
family-defined bytes (temperatures, an error code).

The ranges are per motor model (AK80-9: +-12.5 rad, +-50 rad/s, +-18 N m; DM-J4310: +-12.5,
+-30, +-10...) and configurable on the motor itself, so they always come from the servo's
options: nothing here has a default range. Quantisation follows the vendors' published routine
(``float_to_uint``: ``(x - min) * (2**bits - 1) / span``, truncated toward zero); a value outside
its range is refused with ``ValueError``, never clamped, so a bad set point cannot reach the bus
as a different, valid-looking one.

Pure: no I/O, no clock, no state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pydantic import Field

from .base import ProfileOptions

POSITION_BITS = 16
VELOCITY_BITS = 12
GAIN_BITS = 12
TORQUE_BITS = 12
FRAME_LEN = 8
REPLY_MIN_LEN = 6
"""Bytes every MIT reply carries: the family's byte, position, velocity and torque."""

SPECIAL_PREFIX = b"\xff" * 7
ENTER_MOTOR_MODE = SPECIAL_PREFIX + b"\xfc"
"""Enable (Damiao) / enter motor control mode (CubeMars)."""
EXIT_MOTOR_MODE = SPECIAL_PREFIX + b"\xfd"
"""Disable / exit motor control mode: torque off."""
SET_ZERO = SPECIAL_PREFIX + b"\xfe"
"""Make the present position the zero (CubeMars mutes the motor for about a second)."""
CLEAR_ERROR = SPECIAL_PREFIX + b"\xfb"
"""Damiao only: clear a latched fault (communication lost included)."""


@dataclass(frozen=True)
class Span:
    """One field's range, in the field's engineering unit; ``low < high``, both finite."""

    low: float
    high: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.low) and math.isfinite(self.high) and self.low < self.high):
            raise ValueError(
                f"MIT range must be finite with low < high, got {self.low}..{self.high}"
            )

    @classmethod
    def symmetric(cls, limit: float) -> Span:
        """``-limit..limit``: how vendors state position, velocity and torque ranges."""
        return cls(-limit, limit)


@dataclass(frozen=True)
class MitRanges:
    """The five ranges one motor model packs with (from the servo's options)."""

    position_rad: Span
    velocity_rad_s: Span
    torque_nm: Span
    kp: Span
    kd: Span


@dataclass(frozen=True)
class MitCommand:
    """The five set points of one MIT command frame."""

    position_rad: float
    velocity_rad_s: float
    kp: float
    kd: float
    torque_nm: float


@dataclass(frozen=True)
class MitReply:
    """The common part of an MIT reply; ``head`` is byte 0 (its meaning is the family's)."""

    head: int
    position_rad: float
    velocity_rad_s: float
    torque_nm: float


def to_field(value: float, span: Span, bits: int, name: str = "value") -> int:
    """``value`` as a ``bits``-wide unsigned field (the vendors' truncating map).

    Raises ``ValueError`` for a value that is not finite or lies outside ``span``.
    """
    if not math.isfinite(value) or not span.low <= value <= span.high:
        raise ValueError(f"MIT {name} {value!r} outside {span.low}..{span.high}")
    top = (1 << bits) - 1
    field = int((value - span.low) * top / (span.high - span.low))
    return min(top, max(0, field))


def from_field(field: int, span: Span, bits: int) -> float:
    """The engineering value of a ``bits``-wide unsigned field."""
    top = (1 << bits) - 1
    if not 0 <= field <= top:
        raise ValueError(f"MIT field {field} does not fit {bits} bits")
    return span.low + field * (span.high - span.low) / top


def step(span: Span, bits: int) -> float:
    """The value one count of a field stands for (the field's resolution)."""
    return (span.high - span.low) / ((1 << bits) - 1)


def pack_command(command: MitCommand, ranges: MitRanges) -> bytes:
    """The 8-byte MIT command for ``command``; ``ValueError`` names the first field out of range."""
    p = to_field(command.position_rad, ranges.position_rad, POSITION_BITS, "position")
    v = to_field(command.velocity_rad_s, ranges.velocity_rad_s, VELOCITY_BITS, "velocity")
    kp = to_field(command.kp, ranges.kp, GAIN_BITS, "kp")
    kd = to_field(command.kd, ranges.kd, GAIN_BITS, "kd")
    t = to_field(command.torque_nm, ranges.torque_nm, TORQUE_BITS, "torque")
    frame = bytes(
        [
            p >> 8,
            p & 0xFF,
            v >> 4,
            (v & 0xF) << 4 | kp >> 8,
            kp & 0xFF,
            kd >> 4,
            (kd & 0xF) << 4 | t >> 8,
            t & 0xFF,
        ]
    )
    if frame[:7] == SPECIAL_PREFIX:
        raise ValueError("MIT command would encode to a reserved special frame (FF x7 + code)")
    return frame


def unpack_command(data: bytes, ranges: MitRanges) -> MitCommand:
    """The set points of an MIT command frame (the device side, and tests)."""
    if len(data) != FRAME_LEN:
        raise ValueError(f"MIT command must be {FRAME_LEN} bytes, got {len(data)}")
    if is_special(data):
        raise ValueError("a special frame (FF x7 + code) is not an MIT command")
    p = data[0] << 8 | data[1]
    v = data[2] << 4 | data[3] >> 4
    kp = (data[3] & 0xF) << 8 | data[4]
    kd = data[5] << 4 | data[6] >> 4
    t = (data[6] & 0xF) << 8 | data[7]
    return MitCommand(
        position_rad=from_field(p, ranges.position_rad, POSITION_BITS),
        velocity_rad_s=from_field(v, ranges.velocity_rad_s, VELOCITY_BITS),
        kp=from_field(kp, ranges.kp, GAIN_BITS),
        kd=from_field(kd, ranges.kd, GAIN_BITS),
        torque_nm=from_field(t, ranges.torque_nm, TORQUE_BITS),
    )


def is_special(data: bytes) -> bool:
    """True for the special frames (seven 0xFF then a code): they are not set points.

    The pattern is also what position, velocity, kp and kd all at their maxima would encode to;
    the vendors reserve it, so :func:`pack_command` refuses such a command rather than send
    what the motor would read as enable, disable or set zero.
    """
    return len(data) == FRAME_LEN and data[:7] == SPECIAL_PREFIX


def pack_reply(
    head: int, position_rad: float, velocity_rad_s: float, torque_nm: float, ranges: MitRanges
) -> bytes:
    """The first six reply bytes (the device side): ``head``, position, velocity, torque.

    Out-of-range readings saturate here: a real motor past its mapping range reports the end
    of the range, it does not stop answering. Readings round to the nearest count (a sensor
    quantises; only the host's set points follow the vendors' truncating routine).
    """
    p = _saturated_field(position_rad, ranges.position_rad, POSITION_BITS)
    v = _saturated_field(velocity_rad_s, ranges.velocity_rad_s, VELOCITY_BITS)
    t = _saturated_field(torque_nm, ranges.torque_nm, TORQUE_BITS)
    return bytes([head & 0xFF, p >> 8, p & 0xFF, v >> 4, (v & 0xF) << 4 | t >> 8, t & 0xFF])


def unpack_reply(data: bytes, ranges: MitRanges) -> MitReply:
    """The common part of an MIT reply (at least :data:`REPLY_MIN_LEN` bytes)."""
    if len(data) < REPLY_MIN_LEN:
        raise ValueError(f"MIT reply needs {REPLY_MIN_LEN} bytes, got {len(data)}")
    p = data[1] << 8 | data[2]
    v = data[3] << 4 | data[4] >> 4
    t = (data[4] & 0xF) << 8 | data[5]
    return MitReply(
        head=data[0],
        position_rad=from_field(p, ranges.position_rad, POSITION_BITS),
        velocity_rad_s=from_field(v, ranges.velocity_rad_s, VELOCITY_BITS),
        torque_nm=from_field(t, ranges.torque_nm, TORQUE_BITS),
    )


def _saturated_field(value: float, span: Span, bits: int) -> int:
    if math.isnan(value):
        value = 0.0 if span.low <= 0.0 <= span.high else span.low
    value = min(span.high, max(span.low, value))
    top = (1 << bits) - 1
    return min(top, max(0, math.floor((value - span.low) * top / (span.high - span.low) + 0.5)))


KP_SPAN = Span(0.0, 500.0)
KD_SPAN = Span(0.0, 5.0)
"""The gain ranges of the MIT packing (CubeMars and Damiao manuals: kp 0..500, kd 0..5)."""


class MitOptions(ProfileOptions):
    """The per-servo options every MIT-packing family has: the model's ranges (set on the motor
    by the vendor's tool; both ends of the link must map with the same ones), the gains, the id
    the motor answers on, and the torque constant that turns the torque field into a current.
    A family subclasses it with its own model's defaults."""

    master_id: int = Field(0, ge=0, le=0x7FF, description="CAN id the motor answers on")
    p_max_rad: float = Field(12.5, gt=0, le=1000, description="position range +-rad (PMAX)")
    v_max_rad_s: float = Field(30.0, gt=0, le=1000, description="velocity range +-rad/s (VMAX)")
    t_max_nm: float = Field(10.0, gt=0, le=1000, description="torque range +-N m (TMAX)")
    kp: float = Field(20.0, ge=0, le=500, description="MIT stiffness, N m/rad")
    kd: float = Field(
        1.0, gt=0, le=5, description="MIT damping, N m s/rad (never 0: the motor oscillates)"
    )
    torque_constant_nm_per_a: float = Field(
        0.945, gt=0, le=100, description="output torque per amp (the reported current)"
    )

    def ranges(self) -> MitRanges:
        """The ranges this motor packs set points and maps its readings with."""
        return MitRanges(
            position_rad=Span.symmetric(self.p_max_rad),
            velocity_rad_s=Span.symmetric(self.v_max_rad_s),
            torque_nm=Span.symmetric(self.t_max_nm),
            kp=KP_SPAN,
            kd=KD_SPAN,
        )
