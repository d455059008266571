"""GimbalReport alone: the status and information built from servo statuses."""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import ardupilotmega as mav

from mavservo.mavlink.backend import Health, ServoStatus
from mavservo.mavlink.gimbal_manager import ControlSlots
from mavservo.mavlink.gimbal_report import GimbalReport
from mavservo.mavlink.gimbal_settings import GimbalSettings
from mavservo.mavlink.quaternion import quaternion_to_euler
from mavservo.servos.base import NO_FAULT, Fault, ServoState

SETTINGS = GimbalSettings(
    name="cam",
    axis_servos={"roll": "r", "pitch": "p", "yaw": "y"},
    limits_deg={"pitch": (-90.0, 30.0)},
    act_as_manager=True,
)


def status(name, position=math.nan, *, online=True, setpoint=None, faults=NO_FAULT, health=None):
    state = ServoState(position, math.nan, 0.1, 30.0, faults, 0.0)
    kwargs = {} if health is None else {"health": health}
    return ServoStatus(name, 0, state, online, setpoint, None, None, None, **kwargs)


class Servos:
    def __init__(self, *statuses: ServoStatus) -> None:
        self.statuses = list(statuses)

    def servo_statuses(self) -> list[ServoStatus]:
        return self.statuses


class Pointing:
    vehicle_yaw_deg: float | None = 90.0
    clamped_axes = frozenset({"pitch"})

    def status_flags(self) -> int:
        return mav.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME


def test_attitude_status_reports_measured_angles_else_the_setpoint() -> None:
    servos = Servos(status("r", 5.0), status("p", setpoint=-30.0), status("y", 20.0))
    report = GimbalReport(SETTINGS, servos, ControlSlots())
    report.note_time(10.0)
    msg = report.attitude_status(10.5, Pointing())
    roll, pitch, yaw = quaternion_to_euler(msg.q)
    assert (round(roll, 3), round(pitch, 3), round(yaw, 3)) == (5.0, -30.0, 20.0)
    assert msg.time_boot_ms == 500
    assert math.isclose(msg.delta_yaw, math.pi / 2)
    assert msg.failure_flags == mav.GIMBAL_DEVICE_ERROR_FLAGS_AT_PITCH_LIMIT
    assert msg.gimbal_device_id == 1  # its own manager


def test_failure_flags_name_what_is_wrong_with_each_axis() -> None:
    servos = Servos(
        status("r", 0.0, online=False),
        status("p", 0.0, faults=Fault.ENCODER),
        status("y", 0.0, health=Health.SUPPLY),
    )
    report = GimbalReport(SETTINGS, servos, ControlSlots())
    assert report.failure_flags(frozenset()) == (
        mav.GIMBAL_DEVICE_ERROR_FLAGS_COMMS_ERROR
        | mav.GIMBAL_DEVICE_ERROR_FLAGS_ENCODER_ERROR
        | mav.GIMBAL_DEVICE_ERROR_FLAGS_POWER_ERROR
    )


def test_a_missing_axis_servo_is_a_comms_error() -> None:
    report = GimbalReport(SETTINGS, Servos(status("r", 0.0), status("p", 0.0)), ControlSlots())
    assert report.failure_flags(frozenset()) == mav.GIMBAL_DEVICE_ERROR_FLAGS_COMMS_ERROR


def test_manager_status_names_who_is_in_control() -> None:
    control = ControlSlots(primary=(255, 190), secondary=(1, 1))
    report = GimbalReport(SETTINGS, Servos(), control, boot_time=0.0)
    msg = report.manager_status(2.0, flags=mav.GIMBAL_MANAGER_FLAGS_NEUTRAL)
    assert (msg.primary_control_sysid, msg.primary_control_compid) == (255, 190)
    assert (msg.secondary_control_sysid, msg.secondary_control_compid) == (1, 1)
    assert msg.flags == mav.GIMBAL_MANAGER_FLAGS_NEUTRAL and msg.time_boot_ms == 2000


def test_information_follows_replaced_settings() -> None:
    report = GimbalReport(SETTINGS, Servos(), ControlSlots(), boot_time=0.0)
    before = report.device_information(1.0)
    assert math.isclose(before.pitch_min, math.radians(-90.0))
    report.settings = GimbalSettings(
        name="cam", axis_servos={"pitch": "p"}, limits_deg={"pitch": (-45.0, 10.0)}
    )
    after = report.device_information(1.0)
    assert math.isclose(after.pitch_min, math.radians(-45.0))
    assert after.yaw_min == after.yaw_max == 0.0  # no yaw servo any more
    assert not after.cap_flags & mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_AXIS
