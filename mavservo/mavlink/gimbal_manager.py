"""Gimbal manager bookkeeping for a servo gimbal that acts as its own gimbal manager.

Gimbal protocol v2 splits a gimbal into a *manager* (usually the autopilot: arbitrates who may
point the gimbal, converts frames) and a *device* (moves the motors). Vehicles whose autopilot has
no manager for a MAVLink gimbal can let the bridge's gimbal component play both roles, so a ground
station or MAVSDK's gimbal plugin can drive it directly. This module holds the manager-only pieces
that do not depend on the device's motion logic: who is in control (DO_GIMBAL_MANAGER_CONFIGURE)
and which gimbal device ids a command may address. Pure: no I/O, no clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

LEAVE_UNCHANGED = -1
"""DO_GIMBAL_MANAGER_CONFIGURE value: keep the current control id."""
SET_SELF = -2
"""DO_GIMBAL_MANAGER_CONFIGURE value: the sender takes this control slot."""
RELEASE_IF_MINE = -3
"""DO_GIMBAL_MANAGER_CONFIGURE value: free the slot if the sender currently holds it."""

SAME_COMPONENT_DEVICE_ID = 1
"""``gimbal_device_id`` of a device that shares its component with its manager (spec: 1..6)."""


@dataclass
class ControlSlots:
    """Primary and secondary control ``(sysid, compid)``; ``(0, 0)`` means nobody."""

    primary: tuple[int, int] = (0, 0)
    secondary: tuple[int, int] = (0, 0)

    def configure(self, params: tuple[float, ...], sender: tuple[int, int] | None) -> bool:
        """Apply DO_GIMBAL_MANAGER_CONFIGURE p1..p4; False when the request cannot be honoured.

        The special values -2 ("me") and -3 ("release if mine") need the sender's ids; without
        them (a dispatcher that does not pass the sender) such a request is refused rather than
        guessed.
        """
        new_primary = self._resolve(self.primary, params[0], params[1], sender)
        new_secondary = self._resolve(self.secondary, params[2], params[3], sender)
        if new_primary is None or new_secondary is None:
            return False
        self.primary, self.secondary = new_primary, new_secondary
        return True

    def may_control(self, sender: tuple[int, int] | None) -> bool:
        """Whether ``sender`` may point the gimbal.

        Nobody in control means everybody may; an unknown sender is let through because the
        dispatcher may not pass sender ids (enforcing then would lock every client out).
        """
        if sender is None or self.primary == (0, 0):
            return True
        return sender in (self.primary, self.secondary)

    @staticmethod
    def _resolve(
        current: tuple[int, int],
        sysid_param: float,
        compid_param: float,
        sender: tuple[int, int] | None,
    ) -> tuple[int, int] | None:
        if math.isnan(sysid_param) or math.isnan(compid_param):
            return current
        if not (math.isfinite(sysid_param) and math.isfinite(compid_param)):
            return None  # int() of an infinity raises; no slot is infinite anyway
        sysid, compid = int(sysid_param), int(compid_param)
        if sysid == LEAVE_UNCHANGED:
            return current
        if sysid == SET_SELF:
            return sender
        if sysid == RELEASE_IF_MINE:
            if sender is None:
                return None
            return (0, 0) if current == sender else current
        if not (0 <= sysid <= 255 and 0 <= compid <= 255):
            return None
        return (sysid, compid)


def addresses_this_gimbal(device_id_param: float, component_id: int) -> bool:
    """Whether a manager command's gimbal device id selects this gimbal.

    0 means "primary/all gimbals"; a MAVLink gimbal is also addressed by its component id, and a
    device that shares the manager's component by :data:`SAME_COMPONENT_DEVICE_ID`.
    """
    if math.isnan(device_id_param):
        return True
    if not math.isfinite(device_id_param):
        return False  # int() of an infinity raises; no gimbal has an infinite id
    device_id = int(device_id_param)
    return device_id in (0, SAME_COMPONENT_DEVICE_ID, component_id)
