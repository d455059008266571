"""The gimbal handlers under hostile values, and refused demands (findings 7 and 9).

Every handled gimbal message validates before use: a quaternion must be finite with a finite,
non-zero length; angles finite and within a turn; rates finite and sane; flags and ids finite.
A command with a bad value gets exactly one answer, DENIED, and is counted (``bad_value``); a
message with one is ignored and counted; nothing raises, and the log gets one line per kind of
problem, never a traceback. A demand the backend refused is forgotten, never retried later.
"""

from __future__ import annotations

import logging
import math

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mav

from mavservo.mavlink.backend import Outcome
from mavservo.mavlink.quaternion import euler_to_quaternion
from tests.mavlink.test_gimbal_device import (
    AXIS_SERVOS,
    LIMITS,
    NAN,
    assert_angles,
    make_device,
    mount_control,
    raw_set_attitude,
)

INF = math.inf
MAV_RESULTS = {int(o) for o in Outcome}
HOSTILE = [NAN, INF, -INF, 3.4e38, -3.4e38, 1e9, -1e9, 1e200, 0.0, -0.0, 5e-324]
hostile_floats = st.one_of(
    st.sampled_from(HOSTILE),
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=-400.0, max_value=400.0),
)
mount_modes = st.one_of(st.sampled_from([0.0, 1.0, 2.0, 3.0, 4.0]), hostile_floats)


def autopilot_state_q(q):
    return mav.MAVLink_autopilot_state_for_gimbal_device_message(
        1, 0, 0, list(q), 0, 0.0, 0.0, 0.0, 0, 0.0, 0, 0, 0.0
    )


def manager_set_attitude(q, rates=(NAN, NAN, NAN), flags=0):
    return mav.MAVLink_gimbal_manager_set_attitude_message(1, 154, flags, 0, list(q), *rates)


def usable_attitude(q) -> bool:
    """The rule the gimbal applies, restated: finite components, length near 1."""
    return all(math.isfinite(c) for c in q) and 0.5 <= math.hypot(*q) <= 2.0


def angles_within_limits(angles) -> bool:
    for axis, angle in zip(("roll", "pitch", "yaw"), angles, strict=True):
        if angle is None:
            continue
        low, high = LIMITS[axis]
        if not (math.isfinite(angle) and low - 1e-9 <= angle <= high + 1e-9):
            return False
    return True


# ---------------------------------------------------------------- DO_MOUNT_CONTROL


@pytest.mark.parametrize("mode", [INF, -INF, NAN, 1e300])
def test_mount_control_with_an_unusable_mode_gets_one_answer(mode):
    device, backend = make_device()
    result = device.handle_command(
        mav.MAV_CMD_DO_MOUNT_CONTROL, mount_control(-10, 0, 0, mode), 1.0
    )
    # +-inf raised OverflowError (no ACK at all) before; a huge finite mode is just unknown
    expected = Outcome.UNSUPPORTED if math.isfinite(mode) else Outcome.DENIED
    assert result == int(expected)
    assert backend.calls == []


@pytest.mark.parametrize("angle", [INF, -INF, 3.4e38, -3.4e38, 1e9, 361.0])
@pytest.mark.parametrize("axis", [0, 1, 2])
def test_mount_control_with_absurd_angles_is_denied_and_counted(angle, axis):
    device, backend = make_device()
    params = [0.0, 0.0, 0.0]
    params[axis] = angle
    result = device.handle_command(mav.MAV_CMD_DO_MOUNT_CONTROL, mount_control(*params, 2), 1.0)
    assert result == int(Outcome.DENIED)  # was ACCEPTED (clamped to a limit: it moved)
    assert backend.calls == []
    assert device.counters.bad_value == 1


def test_mount_control_in_range_still_works():
    device, backend = make_device()
    result = device.handle_command(mav.MAV_CMD_DO_MOUNT_CONTROL, mount_control(-60, 0, 0, 2), 1.0)
    assert result == int(Outcome.ACCEPTED)
    assert_angles(backend.last, (0.0, -60.0, 0.0))
    assert device.counters.bad_value == 0


@settings(max_examples=300, deadline=None)
@given(st.tuples(*[hostile_floats] * 6), mount_modes)
def test_mount_control_property_one_answer_and_only_sane_targets(params, mode):
    device, backend = make_device()
    result = device.handle_command(mav.MAV_CMD_DO_MOUNT_CONTROL, (*params, mode), 1.0)
    assert result in MAV_RESULTS
    for call in backend.calls:
        assert angles_within_limits(call[1:])
    if math.isfinite(mode) and int(mode) == mav.MAV_MOUNT_MODE_MAVLINK_TARGETING:
        bad = [p for p in params[:3] if not math.isnan(p) and not abs(p) <= 360.0]
        if bad:
            assert result == int(Outcome.DENIED) and backend.calls == []
            assert device.counters.bad_value == 1


# ---------------------------------------------------------------- SET_ATTITUDE messages


@pytest.mark.parametrize(
    "q",
    [
        (0.0, 0.0, 0.0, 0.0),
        (INF, 0.0, 0.0, 0.0),
        (1.0, -INF, 0.0, 0.0),
        (1e200, 1e200, 0.0, 0.0),  # overflowed when squared
        (1e-30, 0.0, 0.0, 0.0),
    ],
)
def test_set_attitude_with_an_unusable_quaternion_is_ignored_and_counted(q):
    device, backend = make_device()
    device.handle_message(raw_set_attitude(q, 0), now=1.0)  # raised ValueError before
    assert backend.calls == []
    assert device.counters.bad_value == 1
    assert device.demand is None


@pytest.mark.parametrize("rate", [INF, -INF, 1e9])
def test_set_attitude_with_absurd_rates_is_ignored(rate):
    device, backend = make_device()
    device.handle_message(raw_set_attitude((NAN, NAN, NAN, NAN), 0, (0.0, rate, 0.0)), now=1.0)
    device.periodic(2.0)
    assert backend.calls == []
    assert device.counters.bad_value == 1


@settings(max_examples=300, deadline=None)
@given(
    st.tuples(*[hostile_floats] * 4),
    st.tuples(*[hostile_floats] * 3),
    st.sampled_from([0, 4, 8, 16, 32, 64, 2, 1]),
    st.booleans(),
)
def test_set_attitude_property_never_raises_and_drives_only_sane_targets(q, rates, flags, manager):
    device, backend = make_device(act_as_manager=manager)
    msg = manager_set_attitude(q, rates, flags) if manager else raw_set_attitude(q, flags, rates)
    device.handle_message(msg, now=1.0)
    for now in (1.1, 1.5, 3.0):
        device.periodic(now)
    for call in backend.calls:
        assert angles_within_limits(call[1:])
    for angle in device.report.measured_angles():
        assert math.isfinite(angle)
    status = device.attitude_status(3.0)
    assert all(math.isfinite(c) for c in status.q)


# ---------------------------------------------------------------- vehicle attitude


@pytest.mark.parametrize(
    "q", [(0.0, 0.0, 0.0, 0.0), (INF, 0.0, 0.0, 0.0), (1e200, 0.0, 1e200, 0.0)]
)
def test_autopilot_state_with_an_unusable_quaternion_is_ignored_and_counted(q):
    device, _ = make_device()
    device.handle_message(autopilot_state_q(q), now=1.0)  # raised ValueError before
    assert device.vehicle_yaw_deg is None
    assert device.counters.bad_value == 1


@settings(max_examples=200, deadline=None)
@given(st.tuples(*[hostile_floats] * 4), hostile_floats)
# found by hypothesis: 3.1e306 rad is finite, but in degrees it overflows and wraps to NaN
@example(q=(math.nan,) * 4, yaw=3.137566414384587e306)
def test_vehicle_attitude_property(q, yaw):
    device, backend = make_device()
    flags = mav.GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME
    device.handle_message(raw_set_attitude(euler_to_quaternion(0, -10, 40), flags), now=0.5)
    device.handle_message(autopilot_state_q(q), now=1.0)
    attitude = mav.MAVLink_attitude_message(0, 0.0, 0.0, yaw, 0.0, 0.0, 0.0)
    device.handle_message(attitude, now=1.1)
    if device.vehicle_yaw_deg is not None:
        assert math.isfinite(device.vehicle_yaw_deg)
    for call in backend.calls:
        assert angles_within_limits(call[1:])
    if not any(math.isnan(c) for c in q) and not usable_attitude(q):
        assert device.counters.bad_value >= 1


# ---------------------------------------------------------------- manager commands


@settings(max_examples=300, deadline=None)
@given(st.tuples(*[hostile_floats] * 7), st.booleans())
def test_manager_commands_property_one_answer(params, configure):
    device, backend = make_device(act_as_manager=True)
    command = (
        mav.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE
        if configure
        else mav.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW
    )
    result = device.handle_command(command, params, 1.0, sender=(255, 190))
    assert result in MAV_RESULTS
    device.periodic(2.0)
    for call in backend.calls:
        assert angles_within_limits(call[1:])


@pytest.mark.parametrize(
    "params",
    [
        (INF, 0.0, NAN, NAN, 0.0, 0.0, 0.0),  # pitch
        (0.0, 3.4e38, NAN, NAN, 0.0, 0.0, 0.0),  # yaw
        (NAN, NAN, INF, NAN, 0.0, 0.0, 0.0),  # pitch rate
        (0.0, 0.0, NAN, NAN, INF, 0.0, 0.0),  # flags (int(inf) raised)
        (0.0, 0.0, NAN, NAN, -5.0, 0.0, 0.0),  # flags
        (0.0, 0.0, NAN, NAN, 0.0, 0.0, INF),  # gimbal device id (int(inf) raised)
    ],
)
def test_pitchyaw_with_a_bad_value_is_denied(params):
    device, backend = make_device(act_as_manager=True)
    result = device.handle_command(mav.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, params, 1.0)
    assert result == int(Outcome.DENIED)
    assert backend.calls == []


@pytest.mark.parametrize("value", [INF, -INF])
def test_configure_with_infinite_ids_is_denied(value):
    device, _ = make_device(act_as_manager=True)
    params = (value, 1.0, NAN, NAN, 0.0, 0.0, 0.0)
    result = device.handle_command(mav.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, params, 1.0)
    assert result == int(Outcome.DENIED)
    assert device.control.primary == (0, 0)


# ---------------------------------------------------------------- logging


def test_a_flood_of_bad_values_logs_one_line_per_kind_and_no_traceback(caplog):
    device, _ = make_device()
    with caplog.at_level(logging.WARNING, logger="mavservo.mavlink.gimbal"):
        for i in range(50):
            now = 1.0 + i * 0.01
            device.handle_message(raw_set_attitude((0.0, 0.0, 0.0, 0.0), 0), now=now)
            device.handle_message(autopilot_state_q((INF, 0, 0, 0)), now=now)
            device.handle_command(mav.MAV_CMD_DO_MOUNT_CONTROL, mount_control(INF, 0, 0, 2), now)
    assert device.counters.bad_value == 150
    assert len(caplog.records) == 3
    assert all(record.exc_info is None for record in caplog.records)
    # after the interval, one more line sums up what was only counted
    with caplog.at_level(logging.WARNING, logger="mavservo.mavlink.gimbal"):
        device.handle_message(raw_set_attitude((0.0, 0.0, 0.0, 0.0), 0), now=20.0)
    assert len(caplog.records) == 4
    assert "49 more" in caplog.records[-1].getMessage()


# ---------------------------------------------------------------- refused demands (finding 7)


def test_a_refused_mount_control_is_never_applied_when_the_servos_come_back():
    """The trial: DO_MOUNT_CONTROL pitch -51 TEMPORARILY_REJECTED during an adapter outage; the
    gimbal retried its demand every status tick and drove the servo to -51 2.2 s after the
    adapter was back."""
    device, backend = make_device()
    device.handle_command(mav.MAV_CMD_DO_MOUNT_CONTROL, mount_control(-20, 0, 0, 2), 0.5)
    assert len(backend.calls) == 1
    backend.outcome = Outcome.TEMPORARILY_REJECTED
    for i, pitch in enumerate(range(-60, -50)):
        result = device.handle_command(
            mav.MAV_CMD_DO_MOUNT_CONTROL, mount_control(pitch, 0, 0, 2), 1.0 + i * 0.1
        )
        assert result == int(Outcome.TEMPORARILY_REJECTED)
    refused_calls = len(backend.calls)
    backend.outcome = Outcome.ACCEPTED  # the adapter is back
    for i in range(100):
        device.periodic(3.0 + i * 0.05)
    assert len(backend.calls) == refused_calls  # nothing re-sent
    assert backend.position[AXIS_SERVOS["pitch"]] == pytest.approx(-20.0)
    # a fresh command moves it
    device.handle_command(mav.MAV_CMD_DO_MOUNT_CONTROL, mount_control(-51, 0, 0, 2), 9.0)
    assert backend.position[AXIS_SERVOS["pitch"]] == pytest.approx(-51.0)


def test_a_refused_rate_demand_stops_and_does_not_resume():
    device, backend = make_device()
    rates = (NAN, math.radians(10.0), NAN)
    device.handle_message(raw_set_attitude((NAN, NAN, NAN, NAN), 0, rates), now=1.0)
    device.periodic(1.5)
    assert backend.calls
    backend.outcome = Outcome.TEMPORARILY_REJECTED
    device.periodic(2.0)
    refused_calls = len(backend.calls)
    backend.outcome = Outcome.ACCEPTED
    for i in range(40):
        device.periodic(2.1 + i * 0.05)
    assert len(backend.calls) == refused_calls
