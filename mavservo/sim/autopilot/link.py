"""Opening a MAVLink 2 / ardupilotmega pymavlink connection without touching global state.

pymavlink picks MAVLink 1 or 2 from the ``MAVLINK20`` environment variable and swaps a module-wide
dialect when ``dialect=`` is passed. Both are process-global, and the bridge runs in the same
process in tests, so the simulator instead gives its own connection a MAVLink 2 ardupilotmega
encoder/decoder and leaves everyone else's alone. SERVO_OUTPUT_RAW needs MAVLink 2 to carry
servo9..16 (extension fields).
"""

from __future__ import annotations

from typing import Any

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

__all__ = ["mavlink2", "open_link"]


def open_link(url: str, source_system: int, source_component: int, **kwargs: Any) -> Any:
    """``mavutil.mavlink_connection(url)`` speaking MAVLink 2 with the ardupilotmega dialect."""
    conn = mavutil.mavlink_connection(
        url, source_system=source_system, source_component=source_component, **kwargs
    )
    mav = mavlink2.MAVLink(conn, srcSystem=source_system, srcComponent=source_component)
    mav.robust_parsing = True
    conn.mav = mav
    conn.WIRE_PROTOCOL_VERSION = "2.0"
    conn.first_byte = False  # no auto-switch: it would swap pymavlink's global module
    return conn
