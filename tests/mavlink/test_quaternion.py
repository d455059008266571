"""ZYX quaternion/Euler conversions and yaw frame changes (mavservo.mavlink.quaternion)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mavservo.mavlink.quaternion import (
    IDENTITY,
    angle_difference,
    body_to_earth_yaw,
    earth_to_body_yaw,
    euler_to_quaternion,
    is_nan_quaternion,
    normalize,
    quaternion_to_euler,
    wrap_180,
    yaw_of,
)

finite_angles = st.floats(min_value=-1e4, max_value=1e4, allow_nan=False)
roll_or_yaw = st.floats(min_value=-179.0, max_value=179.0)
pitch_away_from_lock = st.floats(min_value=-85.0, max_value=85.0)


def _close_angle(a: float, b: float, tol: float = 1e-6) -> bool:
    return abs(angle_difference(a, b)) <= tol


@given(finite_angles)
def test_wrap_180_is_half_open_and_congruent(angle):
    wrapped = wrap_180(angle)
    assert -180.0 <= wrapped < 180.0
    turns = (angle - wrapped) / 360.0
    assert abs(turns - round(turns)) < 1e-9


def test_wrap_180_maps_plus_180_to_minus_180():
    assert wrap_180(180.0) == -180.0
    assert wrap_180(-180.0) == -180.0
    assert wrap_180(190.0) == pytest.approx(-170.0)
    assert wrap_180(-180.0 - 1e-14) == -180.0  # float modulo rounds up to 360 here


@given(roll_or_yaw, pitch_away_from_lock, roll_or_yaw)
def test_euler_round_trip_away_from_gimbal_lock(roll, pitch, yaw):
    q = euler_to_quaternion(roll, pitch, yaw)
    assert math.isclose(sum(c * c for c in q), 1.0, rel_tol=1e-12)
    back = quaternion_to_euler(q)
    assert _close_angle(back[0], roll, 1e-6)
    assert back[1] == pytest.approx(pitch, abs=1e-6)
    assert _close_angle(back[2], yaw, 1e-6)


@given(roll_or_yaw, pitch_away_from_lock, roll_or_yaw)
def test_negated_quaternion_is_the_same_attitude(roll, pitch, yaw):
    q = euler_to_quaternion(roll, pitch, yaw)
    a = quaternion_to_euler(q)
    b = quaternion_to_euler(tuple(-c for c in q))
    assert all(_close_angle(x, y, 1e-6) for x, y in zip(a, b, strict=True))


@given(roll_or_yaw, pitch_away_from_lock, roll_or_yaw, st.floats(min_value=0.5, max_value=2.0))
def test_unnormalised_quaternion_decodes_like_the_unit_one(roll, pitch, yaw, scale):
    q = euler_to_quaternion(roll, pitch, yaw)
    scaled = tuple(c * scale for c in q)
    assert normalize(scaled) == pytest.approx(q, abs=1e-12)
    assert quaternion_to_euler(scaled) == pytest.approx(quaternion_to_euler(q), abs=1e-6)


def test_recorded_arducopter_quaternions_decode_to_their_commanded_angles():
    # q values as ArduPilot sent them in tests/data/plane-gimbal.tlog (float32, 4 decimals here)
    recorded = {
        (0.9659, 0.0, -0.2588, 0.0): (0.0, -30.0, 0.0),
        (0.866, 0.0, -0.5, 0.0): (0.0, -60.0, 0.0),
        (0.8924, -0.099, -0.2391, -0.3696): (0.0, -30.0, -45.0),
        (0.8924, 0.099, -0.3696, 0.2391): (0.0, -45.0, 30.0),
    }
    for q, expected in recorded.items():
        assert quaternion_to_euler(q) == pytest.approx(expected, abs=0.05)


def test_pure_pitch_down_is_a_rotation_about_y():
    w, x, y, z = euler_to_quaternion(0.0, -90.0, 0.0)
    assert (x, z) == (pytest.approx(0.0), pytest.approx(0.0))
    assert w == pytest.approx(math.sqrt(0.5))
    assert y == pytest.approx(-math.sqrt(0.5))
    assert quaternion_to_euler((w, x, y, z))[1] == pytest.approx(-90.0)


def test_identity_is_zero_angles():
    assert quaternion_to_euler(IDENTITY) == (0.0, 0.0, 0.0)


def test_nan_quaternion_is_recognised_and_refused():
    nan_q = (math.nan,) * 4
    assert is_nan_quaternion(nan_q)
    assert not is_nan_quaternion(IDENTITY)
    with pytest.raises(ValueError):
        quaternion_to_euler(nan_q)
    with pytest.raises(ValueError):
        normalize((0.0, 0.0, 0.0, 0.0))


@given(roll_or_yaw, roll_or_yaw)
def test_earth_body_yaw_are_inverse(earth_yaw, vehicle_yaw):
    body = earth_to_body_yaw(earth_yaw, vehicle_yaw)
    assert -180.0 <= body < 180.0
    assert _close_angle(body_to_earth_yaw(body, vehicle_yaw), earth_yaw, 1e-9)


def test_earth_to_body_yaw_examples():
    # Vehicle heading 353 deg (= -7): pointing north means looking 7 deg right of the nose.
    assert earth_to_body_yaw(0.0, -7.0) == pytest.approx(7.0)
    assert earth_to_body_yaw(-45.0, -7.0) == pytest.approx(-38.0)
    # Crossing the +-180 seam wraps instead of asking for a 350 deg swing.
    assert earth_to_body_yaw(170.0, -170.0) == pytest.approx(-20.0)


@given(roll_or_yaw, pitch_away_from_lock, roll_or_yaw)
def test_yaw_of_matches_euler_yaw(roll, pitch, yaw):
    assert _close_angle(yaw_of(euler_to_quaternion(roll, pitch, yaw)), yaw, 1e-6)


@given(
    st.sampled_from([-90.0, 90.0]),
    st.floats(-179.0, 179.0),
    st.floats(-30.0, 30.0),
    st.booleans(),
)
def test_at_gimbal_lock_the_yaw_asked_for_comes_back(pitch, yaw, roll, float32):
    """Pitch +-90: a demand without roll comes back with exactly its yaw (PX4 asked for pitch
    -90 yaw 90 and the yaw servo went to 0, issue 38); with roll, the decoded angles are the
    same rotation (roll 0, the combination in the yaw); float32-rounded quaternions (as they
    travel) too."""
    import struct

    def as_sent(q):
        return tuple(struct.unpack("<4f", struct.pack("<4f", *q))) if float32 else q

    r, p, y = quaternion_to_euler(as_sent(euler_to_quaternion(0.0, pitch, yaw)))
    assert (r, p) == (0.0, pitch)
    assert abs(angle_difference(y, yaw)) < 1e-3
    q = euler_to_quaternion(roll, pitch, yaw)
    back = euler_to_quaternion(*quaternion_to_euler(as_sent(q)))
    assert abs(sum(a * b for a, b in zip(q, back, strict=True))) == pytest.approx(1.0, abs=1e-9)
