"""Quaternion and Euler-angle helpers for the gimbal protocol (pure math, degrees at the edges).

MAVLink carries gimbal attitudes as quaternions ``(w, x, y, z)`` and ArduPilot builds them from
Euler angles in the aerospace ZYX / 3-2-1 order (yaw about z, then pitch about the new y, then
roll about the new x). A servo gimbal with a yaw-pitch-roll axis stack has exactly those Euler
angles as its servo angles, which is why this module speaks ZYX only.

A quaternion whose components are NaN means "no attitude" in MAVLink (rates-only targets, retract);
:func:`is_nan_quaternion` recognises it so callers never feed NaN into the trigonometry.

Nothing here does I/O or reads a clock.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

Quaternion = tuple[float, float, float, float]
"""``(w, x, y, z)``, the MAVLink component order."""

IDENTITY: Quaternion = (1.0, 0.0, 0.0, 0.0)


def wrap_180(angle_deg: float) -> float:
    """Wrap an angle into ``[-180, 180)`` degrees (+180 becomes -180: the range is half-open)."""
    wrapped = (angle_deg + 180.0) % 360.0 - 180.0
    # float modulo of a tiny negative number can round up to exactly 360
    return -180.0 if wrapped >= 180.0 else wrapped


def is_nan_quaternion(q: Sequence[float]) -> bool:
    """True when any component is NaN: MAVLink's "no attitude in this message"."""
    return any(math.isnan(component) for component in q)


ATTITUDE_NORM_RANGE = (0.5, 2.0)
"""Lengths a received attitude quaternion may have. MAVLink attitudes are unit quaternions,
rounded to float32 (off by ~1e-7); one off by a factor of two is not an attitude but garbage:
zero, float32 noise around zero, or huge components (which overflowed when squared)."""


def is_usable_attitude(q: Sequence[float]) -> bool:
    """True for four finite components whose length is within :data:`ATTITUDE_NORM_RANGE`:
    the only quaternions that mean an attitude.

    Received quaternions are hostile input: a zero, infinite or overflowing one used to raise
    deep inside a message handler (a traceback per message, and no validation at all before).
    ``math.hypot`` takes the length without squaring, so huge components cannot overflow.
    """
    if len(q) != 4:
        return False
    try:
        components = [float(c) for c in q]
    except (TypeError, ValueError):
        return False
    if not all(math.isfinite(c) for c in components):
        return False
    low, high = ATTITUDE_NORM_RANGE
    return low <= math.hypot(*components) <= high


def normalize(q: Sequence[float]) -> Quaternion:
    """Scale ``q`` to unit length; a zero-length quaternion raises ``ValueError``.

    Senders round components to float32, so received quaternions are only approximately unit;
    normalising first keeps the ``asin`` in :func:`quaternion_to_euler` inside its domain.
    """
    w, x, y, z = (float(c) for c in q)
    norm = math.hypot(w, x, y, z)
    if norm == 0.0 or not math.isfinite(norm):
        raise ValueError(f"cannot normalise quaternion {tuple(q)!r}")
    return (w / norm, x / norm, y / norm, z / norm)


def euler_to_quaternion(roll_deg: float, pitch_deg: float, yaw_deg: float) -> Quaternion:
    """ZYX (3-2-1) Euler angles in degrees to a unit quaternion ``(w, x, y, z)``."""
    half_roll = math.radians(roll_deg) / 2.0
    half_pitch = math.radians(pitch_deg) / 2.0
    half_yaw = math.radians(yaw_deg) / 2.0
    cr, sr = math.cos(half_roll), math.sin(half_roll)
    cp, sp = math.cos(half_pitch), math.sin(half_pitch)
    cy, sy = math.cos(half_yaw), math.sin(half_yaw)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


#: |sin(pitch)| beyond which the attitude is taken as gimbal lock (pitch within ~0.08 degrees of
#: +-90): there the usual roll and yaw formulas divide noise by noise (atan2(0, 0) for an
#: exact quaternion, float32 rounding otherwise).
GIMBAL_LOCK_SIN = 1.0 - 1e-6


def quaternion_to_euler(q: Sequence[float]) -> tuple[float, float, float]:
    """Unit quaternion ``(w, x, y, z)`` to ZYX Euler ``(roll, pitch, yaw)`` in degrees.

    Roll and yaw are in ``[-180, 180)``, pitch in ``[-90, 90]``. At pitch +-90 (gimbal lock)
    roll and yaw turn about the same axis and only their combination is in the quaternion
    (yaw + roll at -90, yaw - roll at +90: twice ``atan2(z, w)`` either way); there the roll
    is 0 and the yaw is that combination, so a demand of pitch -90 yaw 90 (no roll, a camera
    looking down turned to the right) comes out as exactly that. Before, both formulas gave
    ``atan2(0, 0)`` = 0: PX4 asked for pitch -90 yaw 90 and the yaw servo went to 0 (issue
    38). NaN components raise ``ValueError``: callers must test :func:`is_nan_quaternion` first.
    """
    if is_nan_quaternion(q):
        raise ValueError("quaternion has NaN components (MAVLink 'no attitude')")
    w, x, y, z = normalize(q)
    sin_pitch = max(-1.0, min(1.0, 2.0 * (w * y - z * x)))
    pitch = math.asin(sin_pitch)
    if abs(sin_pitch) >= GIMBAL_LOCK_SIN:
        pitch = math.copysign(math.pi / 2.0, sin_pitch)
        return (0.0, math.degrees(pitch), wrap_180(math.degrees(2.0 * math.atan2(z, w))))
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return (wrap_180(math.degrees(roll)), math.degrees(pitch), wrap_180(math.degrees(yaw)))


def yaw_of(q: Sequence[float]) -> float:
    """Heading (ZYX yaw) of an attitude quaternion in degrees, ``[-180, 180)``."""
    return quaternion_to_euler(q)[2]


def earth_to_body_yaw(earth_yaw_deg: float, vehicle_yaw_deg: float) -> float:
    """Yaw relative to north -> yaw relative to the vehicle's nose, wrapped to ``[-180, 180)``.

    Only the heading is converted: a servo gimbal cannot level itself, so roll and pitch stay
    relative to the vehicle (see the gimbal device's documentation).
    """
    return wrap_180(earth_yaw_deg - vehicle_yaw_deg)


def body_to_earth_yaw(body_yaw_deg: float, vehicle_yaw_deg: float) -> float:
    """Inverse of :func:`earth_to_body_yaw`."""
    return wrap_180(body_yaw_deg + vehicle_yaw_deg)


def angle_difference(a_deg: float, b_deg: float) -> float:
    """Smallest signed difference ``a - b`` in degrees, ``[-180, 180)``; for comparing headings."""
    return wrap_180(a_deg - b_deg)
