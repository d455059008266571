"""What the parts of one gimbal share: its settings from the YAML and its tallies.

A gimbal is three parts (``gimbal.GimbalDevice`` reads MAVLink, ``gimbal_pointing`` drives the
servos, ``gimbal_report`` publishes the status); each reads the same :class:`GimbalSettings`
(replaced as a whole by a PARAM_SET) and counts into the same :class:`GimbalCounters`, which the
MAVLink core reports per gimbal. Kept apart so that no part imports another for them.
"""

from __future__ import annotations

from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mav

AXES = ("roll", "pitch", "yaw")

#: Roll, pitch, yaw in degrees; None: leave that axis alone (or it has no servo).
Angles = tuple[float | None, float | None, float | None]


@dataclass(frozen=True)
class GimbalSettings:
    """What a gimbal group in the YAML config says about one gimbal.

    ``axis_servos`` maps "roll"/"pitch"/"yaw" to servo names (a 2-axis gimbal omits one);
    ``limits_deg`` maps each axis to ``(min, max)`` body-frame degrees.
    """

    name: str
    axis_servos: dict[str, str]
    limits_deg: dict[str, tuple[float, float]]
    component_id: int = mav.MAV_COMP_ID_GIMBAL  # 154
    act_as_manager: bool = False
    vendor_name: str = "mavservo"
    model_name: str = "CAN servo gimbal"
    custom_name: str = ""
    firmware_version: int = 0
    uid: int = 0
    status_rate_hz: float = 10.0
    manager_status_rate_hz: float = 2.0
    retract_pose_deg: tuple[float, float, float] | None = None
    neutral_pose_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    retract_hold_s: float = 0.25
    apply_deadband_deg: float = 0.05
    system_id: int | None = None

    def __post_init__(self) -> None:
        unknown = (set(self.axis_servos) | set(self.limits_deg)) - set(AXES)
        if unknown:
            raise ValueError(f"gimbal {self.name!r}: unknown axes {sorted(unknown)}")
        if not self.axis_servos:
            raise ValueError(f"gimbal {self.name!r}: no axis servos")
        for axis, (low, high) in self.limits_deg.items():
            if not low <= high:
                raise ValueError(f"gimbal {self.name!r}: {axis} limits {low} > {high}")
        if self.status_rate_hz < 5.0:
            raise ValueError(
                f"gimbal {self.name!r}: status_rate_hz {self.status_rate_hz} < 5 "
                "(ArduPilot marks a gimbal unhealthy without frequent status)"
            )
        if self.manager_status_rate_hz <= 0:
            raise ValueError(f"gimbal {self.name!r}: manager_status_rate_hz must be > 0")
        if not 1 <= self.component_id <= 255:
            raise ValueError(f"gimbal {self.name!r}: component_id {self.component_id}")

    def limits(self, axis: str) -> tuple[float, float]:
        """Limits of ``axis``; an axis without limits is free over a full turn."""
        return self.limits_deg.get(axis, (-180.0, 180.0))

    def retract_pose(self) -> tuple[float, float, float]:
        """Configured retract pose, or roll 0 / pitch at its lower limit / yaw 0."""
        if self.retract_pose_deg is not None:
            return self.retract_pose_deg
        return (0.0, self.limits("pitch")[0], 0.0)


@dataclass
class GimbalCounters:
    """Why messages were ignored or changed, for logs and tests."""

    applied: int = 0
    rejected: int = 0
    clamped: int = 0
    shadow_ignored: int = 0
    not_for_me: int = 0
    no_target: int = 0
    denied_control: int = 0
    bad_value: int = 0
    """Messages ignored and commands DENIED for a hostile value (non-finite or absurd angle,
    rate or flags; a zero, infinite or overflowing quaternion)."""
