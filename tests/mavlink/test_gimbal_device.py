"""GimbalDevice behaviour: frames, retract, limits, rates, status, failure flags, manager role."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mav

from mavservo.mavlink.backend import ApplyResult, Outcome, ServoStatus
from mavservo.mavlink.gimbal import GimbalDevice, GimbalSettings
from mavservo.mavlink.quaternion import euler_to_quaternion, quaternion_to_euler, wrap_180
from mavservo.servos.base import NO_FAULT, Fault, ServoState

NAN = math.nan
NAN_Q = [NAN, NAN, NAN, NAN]
AXIS_SERVOS = {"roll": "gimbal_roll", "pitch": "gimbal_pitch", "yaw": "gimbal_yaw"}
LIMITS = {"roll": (-30.0, 30.0), "pitch": (-90.0, 30.0), "yaw": (-160.0, 160.0)}


class FollowingBackend:
    """A backend whose gimbal servos reach every accepted target at once (ideal servos).

    Tests can take a servo offline, inject faults or refuse requests, and read every
    ``apply_gimbal`` call back from ``calls``.
    """

    def __init__(self, servo_names: dict[str, str]) -> None:
        self.axis_servo = servo_names
        self.calls: list[tuple[float, float | None, float | None, float | None]] = []
        self.position = {name: 0.0 for name in servo_names.values()}
        self.online = {name: True for name in servo_names.values()}
        self.faults = {name: NO_FAULT for name in servo_names.values()}
        self.outcome = Outcome.ACCEPTED

    def mapped_servo_channels(self) -> set[int]:
        return set()

    def mapped_actuator_indices(self) -> set[int]:
        return set()

    def apply_servo_output(self, channel, pwm_us, source, now) -> ApplyResult:
        return ApplyResult(Outcome.DENIED, "no servo channels")

    def apply_actuator(self, index, value, source, now) -> ApplyResult:
        return ApplyResult(Outcome.DENIED, "no actuators")

    def apply_gimbal(self, gimbal, roll_deg, pitch_deg, yaw_deg, source, now) -> ApplyResult:
        assert gimbal == "cam"
        self.calls.append((now, roll_deg, pitch_deg, yaw_deg))
        if self.outcome is not Outcome.ACCEPTED:
            return ApplyResult(self.outcome, "refused by test")
        for axis, angle in zip(
            ("roll", "pitch", "yaw"), (roll_deg, pitch_deg, yaw_deg), strict=True
        ):
            if angle is not None and axis in self.axis_servo:
                self.position[self.axis_servo[axis]] = angle
        return ApplyResult(Outcome.ACCEPTED)

    def servo_statuses(self) -> list[ServoStatus]:
        statuses = [ServoStatus("elevator", 0, None, True, None, None, 2, None)]
        for index, name in enumerate(self.axis_servo.values(), start=1):
            state = ServoState(self.position[name], 0.0, 0.1, 30.0, self.faults[name], 0.0)
            statuses.append(
                ServoStatus(
                    name, index, state, self.online[name], self.position[name], None, None, None
                )
            )
        return statuses

    def enter_failsafe(self, reason, now) -> None:
        pass

    def leave_failsafe(self, now) -> None:
        pass

    def health(self) -> dict[str, float]:
        return {}

    @property
    def last(self) -> tuple[float | None, float | None, float | None]:
        return self.calls[-1][1:]


def make_device(**overrides) -> tuple[GimbalDevice, FollowingBackend]:
    params = dict(name="cam", axis_servos=AXIS_SERVOS, limits_deg=LIMITS, component_id=154)
    params.update(overrides)
    gimbal_settings = GimbalSettings(**params)
    backend = FollowingBackend(gimbal_settings.axis_servos)
    return GimbalDevice(gimbal_settings, backend, boot_time=0.0), backend


def set_attitude(roll, pitch, yaw, flags=0, target_component=154, rates=(NAN, NAN, NAN)):
    q = list(euler_to_quaternion(roll, pitch, yaw))
    return mav.MAVLink_gimbal_device_set_attitude_message(1, target_component, flags, q, *rates)


def raw_set_attitude(q, flags, rates=(NAN, NAN, NAN)):
    return mav.MAVLink_gimbal_device_set_attitude_message(1, 154, flags, list(q), *rates)


def autopilot_state(vehicle_yaw_deg, roll=0.0, pitch=0.0):
    q = list(euler_to_quaternion(roll, pitch, vehicle_yaw_deg))
    return mav.MAVLink_autopilot_state_for_gimbal_device_message(
        1, 0, 0, q, 0, 0.0, 0.0, 0.0, 0, 0.0, 0, 0, 0.0
    )


def status_angles(device: GimbalDevice, now: float) -> tuple[float, float, float]:
    return quaternion_to_euler(device.attitude_status(now).q)


def assert_angles(actual, expected, tol=1e-3):
    for a, e in zip(actual, expected, strict=True):
        if e is None:
            assert a is None
        else:
            assert a is not None and abs(wrap_180(a - e)) <= tol, (actual, expected)


# ---------------------------------------------------------------- frames


@settings(max_examples=60, deadline=None)
@given(
    st.floats(min_value=-30.0, max_value=30.0),
    st.floats(min_value=-85.0, max_value=30.0),
    st.floats(min_value=-160.0, max_value=160.0),
)
def test_body_frame_attitude_reads_back_in_status(roll, pitch, yaw):
    device, backend = make_device()
    device.handle_message(set_attitude(roll, pitch, yaw), now=1.0)
    assert_angles(backend.last, (roll, pitch, yaw), tol=1e-6)
    status = device.attitude_status(1.01)
    assert status.flags & mav.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME
    assert not status.flags & mav.GIMBAL_DEVICE_FLAGS_YAW_LOCK
    assert status.failure_flags == 0
    assert_angles(quaternion_to_euler(status.q), (roll, pitch, yaw), tol=1e-6)


@pytest.mark.parametrize(
    "flags",
    [
        mav.GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME,
        # ArduPilot's old way: ROLL|PITCH|YAW_LOCK = 28 means the yaw in q is relative to north
        mav.GIMBAL_DEVICE_FLAGS_ROLL_LOCK
        | mav.GIMBAL_DEVICE_FLAGS_PITCH_LOCK
        | mav.GIMBAL_DEVICE_FLAGS_YAW_LOCK,
    ],
)
def test_earth_frame_yaw_is_converted_with_vehicle_yaw(flags):
    device, backend = make_device()
    device.handle_message(autopilot_state(-7.0), now=1.0)
    device.handle_message(set_attitude(0.0, -30.0, -45.0, flags=flags), now=1.02)
    assert_angles(backend.last, (0.0, -30.0, -38.0))
    status = device.attitude_status(1.03)
    assert status.flags & mav.GIMBAL_DEVICE_FLAGS_YAW_LOCK
    assert status.delta_yaw == pytest.approx(math.radians(-7.0), abs=1e-5)
    assert_angles(quaternion_to_euler(status.q), (0.0, -30.0, -38.0))

    # The vehicle turns; the gimbal keeps pointing at earth-frame -45 without a new demand.
    device.handle_message(autopilot_state(20.0), now=1.04)
    assert_angles(backend.last, (0.0, -30.0, -65.0))


def test_yaw_lock_with_vehicle_frame_flag_stays_in_body_frame():
    device, backend = make_device()
    device.handle_message(autopilot_state(-7.0), now=1.0)
    flags = mav.GIMBAL_DEVICE_FLAGS_YAW_LOCK | mav.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME
    device.handle_message(set_attitude(0.0, -30.0, -45.0, flags=flags), now=1.02)
    assert_angles(backend.last, (0.0, -30.0, -45.0))


def test_attitude_message_also_gives_vehicle_yaw_and_wraps_across_180():
    device, backend = make_device()
    device.handle_message(
        mav.MAVLink_attitude_message(0, 0.0, 0.0, math.radians(170.0), 0, 0, 0), 1.0
    )
    device.handle_message(
        set_attitude(0.0, 0.0, -170.0, flags=mav.GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME), 1.01
    )
    # north-relative -170 seen from a vehicle heading 170 is 20 deg to the right, not -340
    assert_angles(backend.last, (0.0, 0.0, 20.0))


def test_earth_frame_yaw_without_vehicle_yaw_leaves_yaw_axis_alone():
    device, backend = make_device()
    device.handle_message(
        set_attitude(5.0, -20.0, 45.0, flags=mav.GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME), 1.0
    )
    assert_angles(backend.last, (5.0, -20.0, None))
    device.handle_message(autopilot_state(15.0), now=1.1)
    assert_angles(backend.last, (5.0, -20.0, 30.0))


def test_message_for_another_component_is_ignored():
    device, backend = make_device()
    device.handle_message(set_attitude(0.0, -30.0, 0.0, target_component=155), now=1.0)
    assert backend.calls == []
    assert device.counters.not_for_me == 1


# ---------------------------------------------------------------- limits and rates


def test_target_outside_limits_is_clamped_and_reported():
    device, backend = make_device()
    device.handle_message(set_attitude(0.0, -30.0, 170.0), now=1.0)
    assert_angles(backend.last, (0.0, -30.0, 160.0))
    flags = device.attitude_status(1.01).failure_flags
    assert flags == mav.GIMBAL_DEVICE_ERROR_FLAGS_AT_YAW_LIMIT
    assert device.counters.clamped == 1

    device.handle_message(set_attitude(0.0, -30.0, 10.0), now=1.1)
    assert device.attitude_status(1.11).failure_flags == 0


def test_missing_axis_is_never_driven_and_reports_zero():
    device, backend = make_device(
        axis_servos={"pitch": "gimbal_pitch", "yaw": "gimbal_yaw"},
        limits_deg={"pitch": (-90.0, 30.0), "yaw": (-160.0, 160.0)},
    )
    device.handle_message(set_attitude(10.0, -30.0, 20.0), now=1.0)
    assert_angles(backend.last, (None, -30.0, 20.0))
    info = device.report.device_information(1.0)
    assert not info.cap_flags & mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_ROLL_AXIS
    assert info.cap_flags & mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_PITCH_AXIS
    assert_angles(status_angles(device, 1.01), (0.0, -30.0, 20.0))


def test_rates_only_demand_is_integrated_and_clamped():
    device, backend = make_device()
    device.handle_message(set_attitude(0.0, -20.0, 100.0), now=0.0)
    yaw_rate = math.radians(10.0)
    device.handle_message(raw_set_attitude(NAN_Q, 0, rates=(NAN, NAN, yaw_rate)), now=1.0)
    device.periodic(3.0)
    assert_angles(backend.last, (0.0, -20.0, 120.0), tol=1e-6)
    device.periodic(20.0)
    assert_angles(backend.last, (0.0, -20.0, 160.0), tol=1e-6)


def test_nan_quaternion_without_rates_is_ignored():
    device, backend = make_device()
    device.handle_message(raw_set_attitude(NAN_Q, 0), now=1.0)
    assert backend.calls == []
    assert device.counters.no_target == 1


# ---------------------------------------------------------------- retract / neutral


def test_retract_survives_arducopter_shadow_identity_messages():
    device, backend = make_device(retract_hold_s=0.25)
    device.handle_message(set_attitude(0.0, -30.0, 0.0), now=0.0)
    retract = raw_set_attitude(NAN_Q, mav.GIMBAL_DEVICE_FLAGS_RETRACT, rates=(0.0, 0.0, 0.0))
    shadow = raw_set_attitude([1.0, 0.0, 0.0, 0.0], 0)
    now = 1.0
    for _ in range(50):  # the recorded pattern: RETRACT, then identity, every 20 ms
        device.handle_message(retract, now)
        device.handle_message(shadow, now + 0.001)
        now += 0.02
    retract_pose = (0.0, LIMITS["pitch"][0], 0.0)
    assert_angles(backend.last, retract_pose)
    assert all(call[1:] == retract_pose for call in backend.calls[1:])
    assert device.counters.shadow_ignored == 50
    assert device.attitude_status(now).flags & mav.GIMBAL_DEVICE_FLAGS_RETRACT

    # RETRACT stops: identity within the hold time is still a shadow, after it it is neutral.
    device.handle_message(shadow, now + 0.1)
    assert_angles(backend.last, retract_pose)
    device.handle_message(shadow, now + 0.3)
    assert_angles(backend.last, (0.0, 0.0, 0.0))
    assert not device.attitude_status(now + 0.31).flags & mav.GIMBAL_DEVICE_FLAGS_RETRACT


def test_non_identity_target_ends_retract_immediately():
    device, backend = make_device(retract_pose_deg=(0.0, 20.0, 0.0))
    device.handle_message(raw_set_attitude(NAN_Q, mav.GIMBAL_DEVICE_FLAGS_RETRACT), 1.0)
    assert_angles(backend.last, (0.0, 20.0, 0.0))
    device.handle_message(set_attitude(0.0, -45.0, 30.0), 1.01)
    assert_angles(backend.last, (0.0, -45.0, 30.0))


def test_neutral_flag_goes_to_the_configured_neutral_pose():
    device, backend = make_device(neutral_pose_deg=(0.0, -10.0, 0.0))
    device.handle_message(set_attitude(0.0, -60.0, 20.0), 1.0)
    device.handle_message(raw_set_attitude(NAN_Q, mav.GIMBAL_DEVICE_FLAGS_NEUTRAL), 1.1)
    assert_angles(backend.last, (0.0, -10.0, 0.0))
    assert device.attitude_status(1.2).flags & mav.GIMBAL_DEVICE_FLAGS_NEUTRAL


# ---------------------------------------------------------------- DO_MOUNT_CONTROL


def mount_control(pitch, roll, yaw, mode):
    return (pitch, roll, yaw, 0.0, 0.0, 0.0, float(mode))


def test_do_mount_control_modes():
    device, backend = make_device()
    cmd = mav.MAV_CMD_DO_MOUNT_CONTROL
    result = device.handle_command(cmd, mount_control(-45, 0, 30, 2), 1.0)
    assert result == mav.MAV_RESULT_ACCEPTED
    assert_angles(backend.last, (0.0, -45.0, 30.0))
    assert device.handle_command(cmd, mount_control(0, 0, 0, 1), 2.0) == mav.MAV_RESULT_ACCEPTED
    assert_angles(backend.last, (0.0, 0.0, 0.0))
    assert device.handle_command(cmd, mount_control(0, 0, 0, 0), 3.0) == mav.MAV_RESULT_ACCEPTED
    assert_angles(backend.last, (0.0, -90.0, 0.0))
    gps_point = mav.MAV_MOUNT_MODE_GPS_POINT
    assert device.handle_command(cmd, mount_control(0, 0, 0, gps_point), 4.0) == (
        mav.MAV_RESULT_UNSUPPORTED
    )
    # NaN angle in targeting mode: that axis is left where it is
    device.handle_command(cmd, mount_control(-10, NAN, NAN, 2), 5.0)
    assert_angles(backend.last, (None, -10.0, None))


def test_do_mount_control_reports_backend_refusal_and_does_not_retry():
    # a refused demand is forgotten (finding 7; details in
    # tests/mavlink/test_gimbal_hostile_values.py)
    device, backend = make_device()
    backend.outcome = Outcome.TEMPORARILY_REJECTED
    result = device.handle_command(mav.MAV_CMD_DO_MOUNT_CONTROL, mount_control(-20, 0, 0, 2), 1.0)
    assert result == mav.MAV_RESULT_TEMPORARILY_REJECTED
    backend.outcome = Outcome.ACCEPTED
    calls_before = len(backend.calls)
    device.periodic(1.5)
    assert len(backend.calls) == calls_before


def test_unknown_command_is_not_mine():
    device, _ = make_device()
    assert device.handle_command(mav.MAV_CMD_DO_SET_SERVO, (9, 1500, 0, 0, 0, 0, 0), 1.0) is None
    # manager commands belong to the manager, which this device is not
    pitchyaw = (0.0, 0.0, NAN, NAN, 0.0, 0.0, 0.0)
    assert device.handle_command(mav.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, pitchyaw, 1.0) is None


# ---------------------------------------------------------------- status and failure flags


def test_status_reflects_measured_not_commanded_position():
    device, backend = make_device()
    device.handle_message(set_attitude(0.0, -30.0, 0.0), 1.0)
    backend.position["gimbal_pitch"] = -27.5  # the servo has not got there yet
    assert_angles(status_angles(device, 1.01), (0.0, -27.5, 0.0))


def test_offline_axis_servo_sets_comms_error():
    device, backend = make_device()
    assert device.attitude_status(1.0).failure_flags == 0
    backend.online["gimbal_yaw"] = False
    assert device.attitude_status(1.1).failure_flags & mav.GIMBAL_DEVICE_ERROR_FLAGS_COMMS_ERROR
    backend.online["gimbal_yaw"] = True
    assert device.attitude_status(1.2).failure_flags == 0


@pytest.mark.parametrize(
    ("fault", "expected"),
    [
        (Fault.NO_REPLY, mav.GIMBAL_DEVICE_ERROR_FLAGS_COMMS_ERROR),
        (Fault.ENCODER, mav.GIMBAL_DEVICE_ERROR_FLAGS_ENCODER_ERROR),
        (Fault.LOW_VOLTAGE, mav.GIMBAL_DEVICE_ERROR_FLAGS_POWER_ERROR),
        (Fault.OVER_TEMPERATURE, mav.GIMBAL_DEVICE_ERROR_FLAGS_MOTOR_ERROR),
        (
            Fault.STALL | Fault.POWER,
            mav.GIMBAL_DEVICE_ERROR_FLAGS_MOTOR_ERROR | mav.GIMBAL_DEVICE_ERROR_FLAGS_POWER_ERROR,
        ),
    ],
)
def test_servo_faults_map_to_failure_flags(fault, expected):
    device, backend = make_device()
    backend.faults["gimbal_pitch"] = fault
    assert device.attitude_status(1.0).failure_flags == expected


def test_gimbal_servo_missing_from_backend_is_a_comms_error():
    gimbal_settings = GimbalSettings(
        "cam", {**AXIS_SERVOS, "roll": "not_in_config"}, LIMITS, component_id=154
    )
    device = GimbalDevice(gimbal_settings, FollowingBackend(AXIS_SERVOS), boot_time=0.0)
    assert device.attitude_status(1.0).failure_flags == mav.GIMBAL_DEVICE_ERROR_FLAGS_COMMS_ERROR


def test_periodic_emits_status_at_configured_rate_without_bursts():
    device, _ = make_device(status_rate_hz=10.0)
    sent = []
    for step in range(200):  # 2 s of 100 Hz calls
        now = step * 0.01
        sent += [m for m in device.periodic(now) if m.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS"]
    assert 19 <= len(sent) <= 21
    times = [m.time_boot_ms for m in sent]
    assert times == sorted(times)
    # a long stall produces one message, not a catch-up burst
    assert len(device.periodic(10.0)) == 1


def test_status_rate_below_5_hz_is_refused():
    with pytest.raises(ValueError):
        make_device(status_rate_hz=2.0)


def test_status_message_survives_a_mavlink_round_trip():
    device, _ = make_device()
    device.handle_message(set_attitude(0.0, -30.0, 45.0), 1.0)
    encoder = mav.MAVLink(None, srcSystem=1, srcComponent=154)
    packed = device.attitude_status(1.5).pack(encoder)
    decoded = mav.MAVLink(None).decode(bytearray(packed))
    assert decoded.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS"
    assert decoded.time_boot_ms == 1500
    assert_angles(quaternion_to_euler(decoded.q), (0.0, -30.0, 45.0), tol=1e-3)


# ---------------------------------------------------------------- information and manager role


def test_device_information_describes_the_configured_gimbal():
    device, _ = make_device(vendor_name="Acme", model_name="ServoCam", firmware_version=0x00030201)
    assert device.supports_message(mav.MAVLINK_MSG_ID_GIMBAL_DEVICE_INFORMATION)
    info = device.requested_message(mav.MAVLINK_MSG_ID_GIMBAL_DEVICE_INFORMATION, 2.0)
    assert (info.vendor_name, info.model_name) == ("Acme", "ServoCam")
    assert info.firmware_version == 0x00030201
    assert info.pitch_min == pytest.approx(math.radians(-90.0))
    assert info.yaw_max == pytest.approx(math.radians(160.0))
    assert info.cap_flags & mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_RETRACT
    assert info.gimbal_device_id == 0
    packed = info.pack(mav.MAVLink(None, srcSystem=1, srcComponent=154))
    assert mav.MAVLink(None).decode(bytearray(packed)).model_name == "ServoCam"


def test_manager_requests_are_unsupported_when_not_a_manager():
    device, _ = make_device(act_as_manager=False)
    for message_id in (
        mav.MAVLINK_MSG_ID_GIMBAL_MANAGER_INFORMATION,
        mav.MAVLINK_MSG_ID_GIMBAL_MANAGER_STATUS,
    ):
        assert not device.supports_message(message_id)
        assert device.requested_message(message_id, 1.0) is None
    assert not any(m.get_type() == "GIMBAL_MANAGER_STATUS" for m in device.periodic(1.0))


def pitchyaw(pitch, yaw, flags=0, device_id=0, pitch_rate=NAN, yaw_rate=NAN):
    return (pitch, yaw, pitch_rate, yaw_rate, float(flags), 0.0, float(device_id))


def test_manager_answers_information_and_streams_status():
    device, _ = make_device(act_as_manager=True, manager_status_rate_hz=2.0)
    info = device.requested_message(mav.MAVLINK_MSG_ID_GIMBAL_MANAGER_INFORMATION, 1.0)
    assert info.get_type() == "GIMBAL_MANAGER_INFORMATION"
    assert info.gimbal_device_id == 1
    assert info.pitch_min == pytest.approx(math.radians(-90.0))
    manager_statuses = []
    for step in range(300):  # 3 s of 100 Hz calls
        manager_statuses += [
            m for m in device.periodic(step * 0.01) if m.get_type() == "GIMBAL_MANAGER_STATUS"
        ]
    assert 5 <= len(manager_statuses) <= 7
    assert device.attitude_status(3.0).gimbal_device_id == 1


def test_manager_pitchyaw_in_body_and_earth_frame_and_retract():
    device, backend = make_device(act_as_manager=True)
    cmd = mav.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW
    device.handle_message(autopilot_state(-7.0), 0.5)
    assert device.handle_command(cmd, pitchyaw(-30.0, -45.0), 1.0) == mav.MAV_RESULT_ACCEPTED
    assert_angles(backend.last, (0.0, -30.0, -45.0))
    yaw_lock = mav.GIMBAL_MANAGER_FLAGS_YAW_LOCK
    assert device.handle_command(cmd, pitchyaw(-30.0, -45.0, yaw_lock), 2.0) == 0
    assert_angles(backend.last, (0.0, -30.0, -38.0))
    retract = mav.GIMBAL_MANAGER_FLAGS_RETRACT
    assert device.handle_command(cmd, pitchyaw(NAN, NAN, retract), 3.0) == 0
    assert_angles(backend.last, (0.0, -90.0, 0.0))
    assert device.manager_status(3.1).flags & mav.GIMBAL_MANAGER_FLAGS_RETRACT
    # another gimbal's device id is not ours to move
    assert device.handle_command(cmd, pitchyaw(0.0, 0.0, device_id=171), 4.0) == (
        mav.MAV_RESULT_DENIED
    )


def test_manager_pitchyaw_rates():
    device, backend = make_device(act_as_manager=True)
    cmd = mav.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW
    device.handle_command(cmd, pitchyaw(-10.0, 0.0), 0.0)
    assert device.handle_command(cmd, pitchyaw(NAN, NAN, pitch_rate=-5.0), 1.0) == 0
    device.periodic(3.0)
    assert_angles(backend.last, (0.0, -20.0, 0.0), tol=1e-6)
    assert device.handle_command(cmd, pitchyaw(NAN, NAN), 4.0) == mav.MAV_RESULT_DENIED


def test_manager_configure_controls_who_may_point():
    device, backend = make_device(act_as_manager=True)
    configure = mav.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE
    pitchyaw_cmd = mav.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW
    gcs, companion = (255, 190), (1, 191)
    take = (-2.0, -2.0, -1.0, -1.0, 0.0, 0.0, 0.0)
    assert device.handle_command(configure, take, 1.0, sender=gcs) == mav.MAV_RESULT_ACCEPTED
    assert device.manager_status(1.1).primary_control_sysid == 255
    assert device.manager_status(1.1).primary_control_compid == 190
    assert device.handle_command(pitchyaw_cmd, pitchyaw(-30, 0), 2.0, sender=companion) == (
        mav.MAV_RESULT_DENIED
    )
    assert device.handle_command(pitchyaw_cmd, pitchyaw(-30, 0), 2.1, sender=gcs) == 0
    # a GIMBAL_MANAGER_SET_ATTITUDE from a client not in control is dropped
    msg = mav.MAVLink_gimbal_manager_set_attitude_message(
        1, 154, 0, 0, list(euler_to_quaternion(0, -60, 0)), NAN, NAN, NAN
    )
    msg.pack(mav.MAVLink(None, srcSystem=1, srcComponent=191))  # sets the header's source ids
    calls = len(backend.calls)
    device.handle_message(msg, 2.2)
    assert len(backend.calls) == calls
    assert device.counters.denied_control == 2  # the refused PITCHYAW and this message
    # release by the holder, then anyone may point again
    release = (-3.0, -3.0, -1.0, -1.0, 0.0, 0.0, 0.0)
    assert device.handle_command(configure, release, 3.0, sender=gcs) == 0
    device.handle_message(msg, 3.1)
    assert_angles(backend.last, (0.0, -60.0, 0.0))
    # "me" without knowing who "me" is cannot be honoured
    assert device.handle_command(configure, take, 4.0) == mav.MAV_RESULT_DENIED


GIMBAL_YAML = """
servos:
  - {name: gimbal_roll, profile: cubemars-ak, can_id: 1, limits_deg: [-30, 30]}
  - {name: gimbal_pitch, profile: cubemars-ak, can_id: 2, limits_deg: [-90, 30]}
  - {name: gimbal_yaw, profile: cubemars-ak, can_id: 3, limits_deg: [-160, 160]}
gimbals:
  - name: camera
    roll: gimbal_roll
    pitch: gimbal_pitch
    yaw: gimbal_yaw
    limits_deg: {roll: [-30, 30], pitch: [-90, 30]}   # yaw: the servo's own limits
    act_as_manager: true
    model_name: AK gimbal
"""


def test_settings_from_a_gimbal_config():
    from mavservo.config import load_config_text
    from mavservo.config.views import gimbal_settings as settings_of

    yaml = GIMBAL_YAML + "mavlink: {telemetry: {gimbal_attitude_status_hz: 20}}\n"
    [gimbal_settings] = settings_of(load_config_text(yaml, "gimbal.yaml"))
    assert gimbal_settings.axis_servos == AXIS_SERVOS
    assert gimbal_settings.limits_deg == LIMITS
    assert gimbal_settings.retract_pose() == (0.0, -90.0, 0.0)
    assert gimbal_settings.component_id == 154 and gimbal_settings.act_as_manager
    assert gimbal_settings.model_name == "AK gimbal"
    assert gimbal_settings.status_rate_hz == 20.0


def test_repeated_target_is_not_resent_but_a_refused_one_is():
    device, backend = make_device()
    for step in range(5):  # ArduPilot repeats the same target at 50 Hz
        device.handle_message(set_attitude(0.0, -30.0, 0.0), now=1.0 + step * 0.02)
    assert len(backend.calls) == 1
    backend.outcome = Outcome.TEMPORARILY_REJECTED
    device.handle_message(set_attitude(0.0, -40.0, 0.0), now=2.0)
    device.handle_message(set_attitude(0.0, -40.0, 0.0), now=2.02)
    assert len(backend.calls) == 3
    assert device.counters.rejected == 2


# ---------------------------------------------------------------- settings replaced (PARAM_SET)


def test_replaced_settings_reach_the_pointing_and_the_report_at_once():
    """The bridge replaces ``device.settings`` on a PARAM_SET of the limits: the next demand
    is clamped to the new limits and the information reports them (both parts follow)."""
    device, backend = make_device()
    device.settings = GimbalSettings(
        name="cam",
        axis_servos=AXIS_SERVOS,
        limits_deg={**LIMITS, "pitch": (-45.0, 10.0)},
        component_id=154,
    )
    device.handle_message(set_attitude(0.0, -80.0, 0.0), 1.0)
    assert_angles(backend.last, (0.0, -45.0, 0.0))
    info = device.requested_message(mav.MAVLINK_MSG_ID_GIMBAL_DEVICE_INFORMATION, 1.0)
    assert math.isclose(info.pitch_min, math.radians(-45.0), abs_tol=1e-6)
