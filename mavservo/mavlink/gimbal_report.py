"""What a gimbal says about itself: attitude status, device and manager information and status.

Why a part of its own: the status is built from what the servos MEASURE (their statuses from the
backend), not from what was asked, and the information messages from the settings alone; none
of it changes the gimbal. It reads the pointing through a narrow view (:class:`PointingView`:
the flags in effect, the clamped axes, the vehicle yaw), so it is tested alone with a fake
status source. Sans-I/O: ``now`` comes in as an argument; the boot time is the first ``now``
seen unless given.

* q comes from the MEASURED servo positions (falling back to the last setpoint, then 0, for an
  axis with no reading yet), in the vehicle frame (flag 32).
* Failure flags: offline servo or ``Fault.NO_REPLY`` -> COMMS_ERROR, ENCODER -> ENCODER_ERROR,
  voltage/power faults -> POWER_ERROR, every other fault -> MOTOR_ERROR; the bridge's health
  findings per :data:`HEALTH_TO_FAILURE_FLAG`; an axis held at a limit -> AT_*_LIMIT.
"""

from __future__ import annotations

import math
from typing import Any, Protocol

from pymavlink.dialects.v20 import ardupilotmega as mav

from mavservo.mavlink.backend import Health, ServoStatus
from mavservo.mavlink.gimbal_manager import SAME_COMPONENT_DEVICE_ID, ControlSlots
from mavservo.mavlink.gimbal_settings import AXES, GimbalSettings
from mavservo.mavlink.quaternion import euler_to_quaternion
from mavservo.mavlink.telemetry import float32_field
from mavservo.servos import Fault

AT_LIMIT_FLAG = {
    "roll": mav.GIMBAL_DEVICE_ERROR_FLAGS_AT_ROLL_LIMIT,
    "pitch": mav.GIMBAL_DEVICE_ERROR_FLAGS_AT_PITCH_LIMIT,
    "yaw": mav.GIMBAL_DEVICE_ERROR_FLAGS_AT_YAW_LIMIT,
}
COMMS_ERROR = mav.GIMBAL_DEVICE_ERROR_FLAGS_COMMS_ERROR
MOTOR_ERROR = mav.GIMBAL_DEVICE_ERROR_FLAGS_MOTOR_ERROR
ENCODER_ERROR = mav.GIMBAL_DEVICE_ERROR_FLAGS_ENCODER_ERROR
POWER_ERROR = mav.GIMBAL_DEVICE_ERROR_FLAGS_POWER_ERROR

FAULT_TO_FAILURE_FLAG: dict[Fault, int] = {
    Fault.NO_REPLY: COMMS_ERROR,
    Fault.COMMUNICATION_LOST: COMMS_ERROR,
    Fault.ENCODER: ENCODER_ERROR,
    Fault.LOW_VOLTAGE: POWER_ERROR,
    Fault.OVER_VOLTAGE: POWER_ERROR,
    Fault.POWER: POWER_ERROR,
}
"""Servo faults with a specific gimbal failure flag; any other fault reports MOTOR_ERROR."""

HEALTH_TO_FAILURE_FLAG: dict[Health, int] = {
    Health.TRACKING: MOTOR_ERROR,
    Health.JAMMED: MOTOR_ERROR,
    Health.SLIPPING: MOTOR_ERROR,
    Health.OVERLOAD: MOTOR_ERROR,
    Health.OVERHEATED: MOTOR_ERROR,
    Health.SUPPLY: POWER_ERROR,
}
"""The bridge's own health findings on an axis (issue 33; docs/health.md) as failure flags, so
ArduPilot's mount reports the gimbal unhealthy; a temperature warning (``HOT``) is a warning,
not a failure, and sets none."""


class ServoStatusSource(Protocol):
    """Where the report reads the servos (``ActuatorBackend.servo_statuses``)."""

    def servo_statuses(self) -> list[ServoStatus]:
        """Snapshot of every servo, in config order."""
        ...


class PointingView(Protocol):
    """What the report needs of the pointing (``gimbal_pointing.GimbalPointing``)."""

    @property
    def vehicle_yaw_deg(self) -> float | None:
        """The vehicle heading last heard (the status's delta_yaw), None before any."""
        ...

    @property
    def clamped_axes(self) -> frozenset[str]:
        """Axes whose target is held at a limit."""
        ...

    def status_flags(self) -> int:
        """GIMBAL_DEVICE_FLAGS in effect."""
        ...


class GimbalReport:
    """The messages one gimbal publishes, built when asked (nothing is cached).

    ``settings`` may be replaced (a PARAM_SET of the limits); ``control`` is the manager's
    control slots, read for GIMBAL_MANAGER_STATUS.
    """

    def __init__(
        self,
        settings: GimbalSettings,
        servos: ServoStatusSource,
        control: ControlSlots,
        boot_time: float | None = None,
    ) -> None:
        self.settings = settings
        self._servos = servos
        self._control = control
        self._boot_time = boot_time

    def note_time(self, now: float) -> None:
        """The first time the gimbal hears of is its boot (time_boot_ms counts from it)."""
        if self._boot_time is None:
            self._boot_time = now

    def axis_statuses(self) -> dict[str, ServoStatus | None]:
        """The backend's status of each configured axis servo (None if the backend lacks it)."""
        by_name = {status.name: status for status in self._servos.servo_statuses()}
        return {axis: by_name.get(servo) for axis, servo in self.settings.axis_servos.items()}

    def measured_angles(self) -> tuple[float, float, float]:
        """Measured roll/pitch/yaw (body); setpoint, then 0, where nothing was measured yet."""
        statuses = self.axis_statuses()
        angles = []
        for axis in AXES:
            status = statuses.get(axis)
            angles.append(_measured_or_setpoint(status))
        return (angles[0], angles[1], angles[2])

    def failure_flags(self, clamped_axes: frozenset[str]) -> int:
        """GIMBAL_DEVICE_ERROR_FLAGS from servo faults, offline servos and clamped targets."""
        flags = 0
        for status in self.axis_statuses().values():
            if status is None or not status.online:
                flags |= COMMS_ERROR
                continue
            if status.state is None:
                continue
            for fault in Fault:
                if fault in status.state.faults:
                    flags |= FAULT_TO_FAILURE_FLAG.get(fault, MOTOR_ERROR)
            for check, flag in HEALTH_TO_FAILURE_FLAG.items():
                if check in status.health:
                    flags |= flag
        for axis in clamped_axes:
            flags |= AT_LIMIT_FLAG[axis]
        return flags

    def attitude_status(self, now: float, pointing: PointingView) -> Any:
        """GIMBAL_DEVICE_ATTITUDE_STATUS from the measured servo positions."""
        roll, pitch, yaw = self.measured_angles()
        rates = [math.nan, math.nan, math.nan]
        for i, status in enumerate(self.axis_statuses().get(axis) for axis in AXES):
            if status is not None and status.state is not None:
                velocity = status.state.velocity_dps
                if not math.isnan(velocity):
                    rates[i] = float32_field(math.radians(velocity))  # 1e41: an infinity
        vehicle_yaw = pointing.vehicle_yaw_deg
        delta_yaw = math.nan if vehicle_yaw is None else math.radians(vehicle_yaw)
        return mav.MAVLink_gimbal_device_attitude_status_message(
            target_system=0,
            target_component=0,
            time_boot_ms=self._time_boot_ms(now),
            flags=pointing.status_flags(),
            q=list(euler_to_quaternion(roll, pitch, yaw)),
            angular_velocity_x=rates[0],
            angular_velocity_y=rates[1],
            angular_velocity_z=rates[2],
            failure_flags=self.failure_flags(pointing.clamped_axes),
            delta_yaw=delta_yaw,
            delta_yaw_velocity=math.nan,
            gimbal_device_id=self._device_id_field(),
        )

    def capability_flags(self) -> int:
        """GIMBAL_DEVICE_CAP_FLAGS (same bits as GIMBAL_MANAGER_CAP_FLAGS) of this gimbal."""
        caps = mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_RETRACT | mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_NEUTRAL
        axis_caps = {
            "roll": mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_ROLL_AXIS
            | mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_ROLL_FOLLOW,
            "pitch": mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_PITCH_AXIS
            | mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_PITCH_FOLLOW,
            "yaw": mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_AXIS
            | mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_FOLLOW
            | mav.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_LOCK
            | mav.GIMBAL_DEVICE_CAP_FLAGS_SUPPORTS_YAW_IN_EARTH_FRAME,
        }
        for axis in self.settings.axis_servos:
            caps |= axis_caps[axis]
        return caps

    def device_information(self, now: float) -> Any:
        """GIMBAL_DEVICE_INFORMATION (ArduPilot requests it every second until it gets one)."""
        s = self.settings
        return mav.MAVLink_gimbal_device_information_message(
            time_boot_ms=self._time_boot_ms(now),
            vendor_name=s.vendor_name.encode()[:32],
            model_name=s.model_name.encode()[:32],
            custom_name=s.custom_name.encode()[:32],
            firmware_version=s.firmware_version,
            hardware_version=0,
            uid=s.uid,
            cap_flags=self.capability_flags(),
            custom_cap_flags=0,
            gimbal_device_id=self._device_id_field(),
            **self._limits_rad(),
        )

    def manager_information(self, now: float) -> Any:
        """GIMBAL_MANAGER_INFORMATION, only meaningful when acting as manager."""
        return mav.MAVLink_gimbal_manager_information_message(
            time_boot_ms=self._time_boot_ms(now),
            cap_flags=self.capability_flags(),
            gimbal_device_id=SAME_COMPONENT_DEVICE_ID,
            **self._limits_rad(),
        )

    def manager_status(self, now: float, flags: int) -> Any:
        """GIMBAL_MANAGER_STATUS: ``flags`` in effect and who is in control."""
        return mav.MAVLink_gimbal_manager_status_message(
            time_boot_ms=self._time_boot_ms(now),
            flags=flags,
            gimbal_device_id=SAME_COMPONENT_DEVICE_ID,
            primary_control_sysid=self._control.primary[0],
            primary_control_compid=self._control.primary[1],
            secondary_control_sysid=self._control.secondary[0],
            secondary_control_compid=self._control.secondary[1],
        )

    def _limits_rad(self) -> dict[str, float]:
        limits: dict[str, float] = {}
        for axis in AXES:
            if axis in self.settings.axis_servos:
                low, high = self.settings.limits(axis)
            else:
                low = high = 0.0
            limits[f"{axis}_min"] = math.radians(low)
            limits[f"{axis}_max"] = math.radians(high)
        return limits

    def _device_id_field(self) -> int:
        """``gimbal_device_id``: 1 when device and manager share the component, else 0 (spec)."""
        return SAME_COMPONENT_DEVICE_ID if self.settings.act_as_manager else 0

    def _time_boot_ms(self, now: float) -> int:
        boot = self._boot_time if self._boot_time is not None else now
        return int(max(0.0, now - boot) * 1000.0) & 0xFFFFFFFF


def _measured_or_setpoint(status: ServoStatus | None) -> float:
    if status is None:
        return 0.0
    if status.state is not None and not math.isnan(status.state.position_deg):
        return status.state.position_deg
    if status.setpoint_deg is not None:
        return status.setpoint_deg
    return 0.0
