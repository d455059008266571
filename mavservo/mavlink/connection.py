"""The one way mavservo opens a pymavlink connection: MAVLink 2, ardupilotmega, nothing global.

pymavlink chooses MAVLink 1 or 2 from the process-wide ``MAVLINK20`` environment variable, swaps
its module-wide dialect when ``mavlink_connection(dialect=...)`` or ``set_dialect`` is called,
and on the first MAVLink 2 byte a MAVLink 1 connection sets ``MAVLINK20`` and swaps the dialect
for everyone (``auto_mavlink_version``). The bridge, the monitor and the simulated autopilot can
run in one process (the tests do), so one of them changing that state would change what the
others encode. This opener gives each connection its own MAVLink 2 ardupilotmega encoder and
decoder and turns the auto-switch off, leaving ``os.environ`` and ``mavutil`` untouched.
SERVO_OUTPUT_RAW needs MAVLink 2 for servo9..16, ESC_TELEMETRY_* exist only there.

A ``tcp:`` client is connected here, attempt by attempt, rather than by pymavlink's own retries:
``mavtcp.do_connect`` prints every refused attempt to stdout (``print(e, "sleeping")``,
pymavlink mavutil.py, class mavtcp), which put two "[Errno 111] Connection refused sleeping"
lines before the bridge's one clear error (issue 37).
"""

from __future__ import annotations

import logging
import time
from typing import Any

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

__all__ = ["mavlink2", "open_connection"]

log = logging.getLogger(__name__)

#: ``tcp:`` connect attempts and the pause between them: pymavlink's ``mavlink_connection``
#: defaults (retries=3, reconnect_delay=1), so a peer that is still starting gets the same time.
TCP_CONNECT_ATTEMPTS = 3
TCP_RECONNECT_DELAY_S = 1.0

#: pymavlink's own defaults: a ground station's system id, no component
DEFAULT_SOURCE_SYSTEM = 255
DEFAULT_SOURCE_COMPONENT = 0
DEFAULT_BAUD = 115200


def open_connection(
    url: str,
    *,
    source_system: int = DEFAULT_SOURCE_SYSTEM,
    source_component: int = DEFAULT_SOURCE_COMPONENT,
    baud: int = DEFAULT_BAUD,
    **kwargs: Any,
) -> Any:
    """``mavutil.mavlink_connection(url)`` speaking MAVLink 2 with the ardupilotmega dialect.

    ``kwargs`` go to pymavlink (``autoreconnect``, ``input``...), except ``dialect``: passing
    it would swap pymavlink's module-wide dialect, which is what this opener exists to avoid.
    """
    if "dialect" in kwargs:
        raise TypeError("open_connection always uses ardupilotmega; do not pass dialect=")
    if url.startswith("tcp:") and "retries" not in kwargs:
        conn = _connect_tcp(
            url, baud=baud, source_system=source_system, source_component=source_component, **kwargs
        )
    else:
        conn = mavutil.mavlink_connection(
            url,
            baud=baud,
            source_system=source_system,
            source_component=source_component,
            **kwargs,
        )
    mav = mavlink2.MAVLink(conn, srcSystem=source_system, srcComponent=source_component)
    mav.robust_parsing = True
    conn.mav = mav
    conn.WIRE_PROTOCOL_VERSION = "2.0"
    conn.first_byte = False  # no auto-switch: it would set MAVLINK20 and swap the dialect
    return conn


def _connect_tcp(url: str, **kwargs: Any) -> Any:
    """``mavlink_connection(url)`` for a ``tcp:`` client, tried ``TCP_CONNECT_ATTEMPTS`` times
    without pymavlink's stdout print per refused attempt (``retries=0``: one attempt, no print);
    the last attempt's error is raised for the caller to report once."""
    delay = float(kwargs.get("reconnect_delay", TCP_RECONNECT_DELAY_S))
    for attempt in range(1, TCP_CONNECT_ATTEMPTS + 1):
        try:
            return mavutil.mavlink_connection(url, retries=0, **kwargs)
        except OSError as exc:
            if attempt == TCP_CONNECT_ATTEMPTS:
                raise
            log.debug("%s: attempt %d of %d: %s", url, attempt, TCP_CONNECT_ATTEMPTS, exc)
            time.sleep(delay)
    raise AssertionError("unreachable")  # the last attempt returned or raised
