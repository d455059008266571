"""The gimbal device end to end: real pymavlink UDP peers on 127.0.0.1 talk to a MavlinkSide that
hosts a GimbalDevice whose backend servos reach their targets at once. Attitudes set in body and
earth frames come back in GIMBAL_DEVICE_ATTITUDE_STATUS from component 154; a servo that goes
offline shows up as COMMS_ERROR; as its own manager the gimbal takes MAVSDK-style commands."""

from __future__ import annotations

import math
import os

os.environ.setdefault("MAVLINK20", "1")

import pytest  # noqa: E402
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mav  # noqa: E402

from mavservo.mavlink.gimbal import GimbalDevice, GimbalSettings  # noqa: E402
from mavservo.mavlink.quaternion import euler_to_quaternion, quaternion_to_euler  # noqa: E402
from mavservo.mavlink.settings import MavlinkSettings  # noqa: E402
from mavservo.mavlink.side import MavlinkSide  # noqa: E402
from tests.mavlink.test_gimbal_device import AXIS_SERVOS, LIMITS, FollowingBackend  # noqa: E402
from tests.support.waiting import free_udp_port, wait_for_message  # noqa: E402

WAIT_S = 3.0
NAN = math.nan


def status_from_gimbal(after_ms: int):
    """Predicate: a GIMBAL_DEVICE_ATTITUDE_STATUS from 1/154 stamped after ``after_ms``."""

    def predicate(msg) -> bool:
        return (
            msg.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS"
            and (msg.get_srcSystem(), msg.get_srcComponent()) == (1, 154)
            and msg.time_boot_ms > after_ms
        )

    return predicate


def ack_for(command, to=(255, 190)):
    """Predicate: the ACK of ``command`` addressed to ``to`` (peers also see others' ACKs)."""
    return lambda m: (
        m.get_type() == "COMMAND_ACK"
        and m.command == command
        and (m.target_system, m.target_component) == to
    )


@pytest.fixture(params=[False, True], ids=["device", "manager"])
def gimbal_bridge(request):
    port = free_udp_port()
    gimbal_settings = GimbalSettings(
        name="cam", axis_servos=AXIS_SERVOS, limits_deg=LIMITS, act_as_manager=request.param
    )
    backend = FollowingBackend(AXIS_SERVOS)
    device = GimbalDevice(gimbal_settings, backend)
    side = MavlinkSide(
        MavlinkSettings(url=f"udpin:127.0.0.1:{port}", mirror_servo_output_raw=False),
        backend,
        gimbals=[device],
    )
    side.start()
    autopilot = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{port}", source_system=1, source_component=1, dialect="ardupilotmega"
    )
    gcs = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{port}",
        source_system=255,
        source_component=190,
        dialect="ardupilotmega",
    )
    try:
        autopilot.mav.heartbeat_send(1, 3, 0, 0, 4)
        gcs.mav.heartbeat_send(6, 8, 0, 0, 4)
        yield device, backend, autopilot, gcs
    finally:
        side.stop()
        autopilot.close()
        gcs.close()


def send_set_attitude(autopilot, roll, pitch, yaw, flags):
    q = list(euler_to_quaternion(roll, pitch, yaw))
    autopilot.mav.gimbal_device_set_attitude_send(1, 154, flags, q, NAN, NAN, NAN)


def latest_status_angles(conn, after_ms):
    status = wait_for_message(conn, status_from_gimbal(after_ms))
    assert status is not None, "no GIMBAL_DEVICE_ATTITUDE_STATUS from 1/154"
    return status, quaternion_to_euler(status.q)


def test_arducopter_style_session_over_udp(gimbal_bridge):
    device, backend, autopilot, gcs = gimbal_bridge
    # discovery, as ArduPilot does it: REQUEST_MESSAGE(283) to the gimbal component
    autopilot.mav.command_long_send(1, 154, mav.MAV_CMD_REQUEST_MESSAGE, 0, 283, 0, 0, 0, 0, 0, 0)
    info = wait_for_message(autopilot, lambda m: m.get_type() == "GIMBAL_DEVICE_INFORMATION")
    assert info is not None and info.get_srcComponent() == 154
    assert info.pitch_min == pytest.approx(math.radians(-90.0))

    # body frame
    send_set_attitude(autopilot, 0.0, -30.0, 45.0, flags=0)
    status, angles = latest_status_angles(autopilot, 0)
    for _ in range(20):  # the status may predate the demand; a few more at 10 Hz settle it
        if angles[1] == pytest.approx(-30.0, abs=0.01):
            break
        status, angles = latest_status_angles(autopilot, status.time_boot_ms)
    assert angles == pytest.approx((0.0, -30.0, 45.0), abs=0.01)
    assert status.failure_flags == 0

    # earth frame (ArduPilot's flags 28) with the vehicle heading -7 deg
    vehicle_q = list(euler_to_quaternion(0.0, 0.0, -7.0))
    autopilot.mav.autopilot_state_for_gimbal_device_send(1, 0, 0, vehicle_q, 0, 0, 0, 0, 0, 0, 0, 0)
    send_set_attitude(autopilot, 0.0, -30.0, -45.0, flags=28)
    for _ in range(20):
        status, angles = latest_status_angles(autopilot, status.time_boot_ms)
        if angles[2] == pytest.approx(-38.0, abs=0.01):
            break
    assert angles == pytest.approx((0.0, -30.0, -38.0), abs=0.01)
    assert status.flags & mav.GIMBAL_DEVICE_FLAGS_YAW_LOCK

    # a servo stops answering
    backend.online["gimbal_pitch"] = False
    for _ in range(20):
        status, _ = latest_status_angles(autopilot, status.time_boot_ms)
        if status.failure_flags:
            break
    assert status.failure_flags == mav.GIMBAL_DEVICE_ERROR_FLAGS_COMMS_ERROR

    # manager information: only from a gimbal that is its own manager
    gcs.mav.command_long_send(1, 154, mav.MAV_CMD_REQUEST_MESSAGE, 0, 280, 0, 0, 0, 0, 0, 0)
    ack = wait_for_message(gcs, ack_for(mav.MAV_CMD_REQUEST_MESSAGE))
    assert ack is not None
    expected = mav.MAV_RESULT_ACCEPTED if device.settings.act_as_manager else 3  # UNSUPPORTED
    assert ack.result == expected


def test_mavsdk_style_manager_commands_over_udp(gimbal_bridge):
    device, backend, _, gcs = gimbal_bridge
    configure = mav.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE
    pitchyaw = mav.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW
    gcs.mav.command_long_send(1, 154, configure, 0, -2, -2, -1, -1, 0, 0, 0)
    ack = wait_for_message(gcs, ack_for(configure))
    assert ack is not None and ack.get_srcComponent() == 154
    if not device.settings.act_as_manager:
        assert ack.result == mav.MAV_RESULT_UNSUPPORTED
        return
    assert ack.result == mav.MAV_RESULT_ACCEPTED
    gcs.mav.command_long_send(1, 154, pitchyaw, 0, -20, 30, NAN, NAN, 0, 0, 0)
    ack = wait_for_message(gcs, ack_for(pitchyaw))
    assert ack is not None and ack.result == mav.MAV_RESULT_ACCEPTED
    assert backend.last == pytest.approx((0.0, -20.0, 30.0))
    manager_status = wait_for_message(gcs, lambda m: m.get_type() == "GIMBAL_MANAGER_STATUS")
    assert manager_status is not None
    assert (manager_status.primary_control_sysid, manager_status.primary_control_compid) == (
        255,
        190,
    )
