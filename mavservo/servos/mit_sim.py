"""The MIT packing as the drives read and write it, for the simulated MIT-family devices
(Damiao, CubeMars MIT mode, Robstride MIT protocol), written from the vendors' manuals (the
MIT command and feedback tables; the ``float_to_uint`` / ``uint_to_float`` of their example
code), not from :mod:`.mit`: the profiles' packing and the devices' must be able to disagree.

Command (8 bytes): position 16 bits, velocity 12, kp 12, kd 12, torque 12, big-endian bit
fields; feedback: a head byte, position 16, velocity 12, torque 12. Each value maps linearly
from ``[-max, +max]`` (gains ``[0, max]``) onto the field's unsigned range.
"""

from __future__ import annotations

from dataclasses import dataclass

SPECIAL = b"\xff" * 7
"""Seven 0xFF then a code: enable FC, disable FD, set zero FE, clear error FB (Damiao)."""


@dataclass(frozen=True)
class DriveRanges:
    """The ranges a drive maps its fields with (set on the drive with the vendor's tool)."""

    p_max: float
    v_max: float
    t_max: float
    kp_max: float = 500.0
    kd_max: float = 5.0


def configured_ranges(setup: dict[str, object], v_max: float, t_max: float) -> DriveRanges:
    """The ranges a drive was set to (the servo's ``p_max_rad`` / ``v_max_rad_s`` /
    ``t_max_nm`` options), the model's defaults where the options do not say."""

    def number(key: str, default: float) -> float:
        value = setup.get(key)
        return float(value) if isinstance(value, (int, float)) else default

    return DriveRanges(
        number("p_max_rad", 12.5), number("v_max_rad_s", v_max), number("t_max_nm", t_max)
    )


def uint_to_float(raw: int, low: float, high: float, bits: int) -> float:
    return raw * (high - low) / ((1 << bits) - 1) + low


def float_to_uint_nearest(value: float, low: float, high: float, bits: int) -> int:
    """A reading as a field: saturated at the range's ends, rounded to the nearest count."""
    top = (1 << bits) - 1
    if value != value:  # NaN: the middle of a symmetric range
        value = (low + high) / 2
    value = min(high, max(low, value))
    return min(top, int((value - low) * top / (high - low) + 0.5))


def command_setpoints(data: bytes, ranges: DriveRanges) -> tuple[float, float, float, float, float]:
    """``(position rad, velocity rad/s, kp, kd, torque N m)`` of an MIT command frame."""
    p = data[0] << 8 | data[1]
    v = data[2] << 4 | data[3] >> 4
    kp = (data[3] & 0x0F) << 8 | data[4]
    kd = data[5] << 4 | data[6] >> 4
    t = (data[6] & 0x0F) << 8 | data[7]
    return (
        uint_to_float(p, -ranges.p_max, ranges.p_max, 16),
        uint_to_float(v, -ranges.v_max, ranges.v_max, 12),
        uint_to_float(kp, 0.0, ranges.kp_max, 12),
        uint_to_float(kd, 0.0, ranges.kd_max, 12),
        uint_to_float(t, -ranges.t_max, ranges.t_max, 12),
    )


def feedback_body(
    head: int, position_rad: float, velocity_rad_s: float, torque_nm: float, ranges: DriveRanges
) -> bytes:
    """The first six bytes of a feedback frame: head, position 16, velocity 12, torque 12."""
    p = float_to_uint_nearest(position_rad, -ranges.p_max, ranges.p_max, 16)
    v = float_to_uint_nearest(velocity_rad_s, -ranges.v_max, ranges.v_max, 12)
    t = float_to_uint_nearest(torque_nm, -ranges.t_max, ranges.t_max, 12)
    return bytes([head & 0xFF, p >> 8, p & 0xFF, v >> 4, (v & 0x0F) << 4 | t >> 8, t & 0xFF])
