"""The simulated autopilot's spelling of :func:`mavservo.mavlink.connection.open_connection`.

Kept so the simulator's callers (and the test helpers) can say ``open_link(url, system,
component)``; the opening itself, MAVLink 2 ardupilotmega without process-wide side effects, is
the one opener's.
"""

from __future__ import annotations

from typing import Any

from mavservo.mavlink.connection import mavlink2, open_connection

__all__ = ["mavlink2", "open_link"]


def open_link(url: str, source_system: int, source_component: int, **kwargs: Any) -> Any:
    """:func:`open_connection` with the system and component ids given positionally."""
    return open_connection(
        url, source_system=source_system, source_component=source_component, **kwargs
    )
