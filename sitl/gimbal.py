"""Gimbal-manager arithmetic: Euler angles <-> the (w, x, y, z) quaternions MAVLink carries.

ArduPilot's MAVLink mount backend turns its target angles into a quaternion with the usual
aerospace Z-Y-X (yaw, pitch, roll) order; the simulator does the same so a bridge that decodes
GIMBAL_DEVICE_SET_ATTITUDE from real ArduPilot decodes ours identically. Pure functions.
"""

from __future__ import annotations

import math

# GIMBAL_DEVICE_FLAGS as ArduPilot sets them (see tests/data/README.md).
FLAG_RETRACT = 1
FLAG_NEUTRAL = 2
FLAG_ROLL_LOCK = 4
FLAG_PITCH_LOCK = 8
FLAG_YAW_LOCK = 16
FLAG_YAW_IN_EARTH_FRAME = 64


def euler_to_quaternion(roll_deg: float, pitch_deg: float, yaw_deg: float) -> tuple[float, ...]:
    """Z-Y-X Euler angles in degrees -> unit quaternion (w, x, y, z)."""
    hr, hp, hy = (math.radians(a) / 2.0 for a in (roll_deg, pitch_deg, yaw_deg))
    cr, sr = math.cos(hr), math.sin(hr)
    cp, sp = math.cos(hp), math.sin(hp)
    cy, sy = math.cos(hy), math.sin(hy)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def quaternion_to_euler(q: tuple[float, ...]) -> tuple[float, float, float]:
    """Unit quaternion (w, x, y, z) -> Z-Y-X Euler angles (roll, pitch, yaw) in degrees."""
    w, x, y, z = q
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    sinp = max(-1.0, min(1.0, 2.0 * (w * y - z * x)))
    pitch = math.asin(sinp)
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return math.degrees(roll), math.degrees(pitch), math.degrees(yaw)
