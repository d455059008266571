"""The autopilot's side of a MAVLink gimbal: ArduPilot's mount driver (MNT1_TYPE 6), simulated.

A part of its own because it is a conversation of its own with its own state: looking for the
gimbal device (MAV_CMD_REQUEST_MESSAGE for GIMBAL_DEVICE_INFORMATION every second, only in
ArduPilot's search window), remembering the device once it answered, and what attitude to set
(GIMBAL_DEVICE_SET_ATTITUDE, from the latest target). The stream sends what it says, when it
says; this class decides and does no I/O, so the search rules can be tested without a link.
"""

from __future__ import annotations

import math
from typing import Any

from mavservo.config import GimbalTarget
from mavservo.mavlink import euler_to_quaternion
from mavservo.mavlink import mavlink2 as mav

#: ArduPilot re-asks the gimbal device for its information every second
REQUEST_INTERVAL_S = 1.0
#: ArduPilot's MAVLink gimbal driver looks for a gimbal from 10 s after boot and stops past
#: 60 s once armed (libraries/AP_Mount/AP_Mount_Gremsy.cpp, find_gimbal, master 3d099b0)
ARDUPILOT_GIMBAL_SEARCH_S = (10.0, 60.0)


class MountDriver:
    """The gimbal device at ``component``: found or not, and the attitude to send it.

    ``search_s`` is the (from, until) boot time in which the device is looked for (past
    ``until`` only while disarmed; None: at any time); ``wait_for_device`` holds the attitude
    stream until the device answered, as ArduPilot does.
    """

    def __init__(
        self,
        component: int = 154,
        *,
        enabled: bool = True,
        wait_for_device: bool = True,
        search_s: tuple[float, float] | None = None,
        target: GimbalTarget | None = None,
    ) -> None:
        self.component = component
        self.enabled = enabled
        self.wait_for_device = wait_for_device
        self.search_s = search_s
        self.target = target or GimbalTarget()
        #: the GIMBAL_DEVICE_INFORMATION the device answered with (None: not found yet)
        self.device_info: Any | None = None
        self._logged: GimbalTarget | None = None
        self._next_request = 0.0

    def ready(self) -> bool:
        """The attitude may be sent: the device answered, or nobody waits for it."""
        return self.device_info is not None or not self.wait_for_device

    def request_due(self, now: float, boot_s: float, armed: bool) -> bool:
        """Send a REQUEST_MESSAGE(GIMBAL_DEVICE_INFORMATION) now? (Counts as sent when True.)"""
        if not self.enabled or self.device_info is not None:
            return False
        if self.search_s is not None:
            start, stop = self.search_s
            if boot_s < start or (boot_s > stop and armed):
                return False
        if now < self._next_request:
            return False
        self._next_request = now + REQUEST_INTERVAL_S
        return True

    def heard(self, msg: Any) -> None:
        """A GIMBAL_DEVICE_INFORMATION arrived; only the device's own component counts."""
        if msg.get_srcComponent() == self.component:
            self.device_info = msg

    def attitude(self) -> tuple[int, tuple[float, float, float, float], tuple[float, float, float]]:
        """(flags, quaternion, angular rates) of GIMBAL_DEVICE_SET_ATTITUDE for the target:
        a retract sends NaN attitude and zero rates, anything else an attitude and NaN rates."""
        target = self.target
        nan = math.nan
        if target.flags & mav.GIMBAL_DEVICE_FLAGS_RETRACT:
            return target.flags, (nan, nan, nan, nan), (0.0, 0.0, 0.0)
        q = euler_to_quaternion(target.roll, target.pitch, target.yaw)
        return target.flags, q, (nan, nan, nan)

    def new_target(self) -> GimbalTarget | None:
        """The target, the first time it is sent after a change (None: already recorded)."""
        if self.target == self._logged:
            return None
        self._logged = self.target
        return self.target
