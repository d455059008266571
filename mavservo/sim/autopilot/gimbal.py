"""Gimbal-manager arithmetic: Euler angles <-> the (w, x, y, z) quaternions MAVLink carries.

ArduPilot's MAVLink mount backend turns its target angles into a quaternion with the usual
aerospace Z-Y-X (yaw, pitch, roll) order; the simulator uses the bridge's own conversions
(:mod:`mavservo.mavlink.quaternion`), whose agreement with real ArduPilot is tested against the
recorded gimbal session (tests/sim/autopilot/test_motion_scripts.py,
tests/mavlink/test_gimbal_replay.py).
"""

from __future__ import annotations

from mavservo.mavlink.quaternion import euler_to_quaternion, quaternion_to_euler

__all__ = ["FLAG_RETRACT", "euler_to_quaternion", "quaternion_to_euler"]

# GIMBAL_DEVICE_FLAGS as ArduPilot sets them (see tests/data/README.md).
FLAG_RETRACT = 1
