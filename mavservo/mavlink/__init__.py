"""MAVLink side of the bridge: link, commands in, telemetry out, gimbal device."""

from __future__ import annotations

from typing import TYPE_CHECKING

from mavservo.faces import lazy_face

# The face: what the other layers use from this package (``tests/test_package_faces.py``), each
# name imported from its module on first use (:func:`mavservo.faces.lazy_face`); the modules'
# other names are the package's own business.
if TYPE_CHECKING:
    from .backend import ACCEPTED, NO_HEALTH_PROBLEM, ApplyResult, Health, Outcome, ServoStatus
    from .bandwidth import BudgetPlan, plan_budget
    from .can_tunnel import CanTunnel, TunnelWireBytes, tunnel_wire_bytes
    from .connection import mavlink2, open_connection
    from .ftp import crc32
    from .gimbal import GimbalDevice
    from .gimbal_settings import GimbalSettings
    from .link_carriage import carriage_lines, left_out_streams
    from .metadata_service import (
        COMP_METADATA_TYPE_PARAMETER,
        GENERAL_FILE,
        PARAMETER_FILE,
        mftp_uri,
    )
    from .params import SetResult, WritePolicy
    from .quaternion import euler_to_quaternion, quaternion_to_euler
    from .servo_commands import ACTUATORS_PER_SET
    from .settings import MavlinkSettings, SigningSettings, TelemetryRates
    from .side import MavlinkSide
    from .stream_request import WINDOW_S, StreamRequestSettings
    from .telemetry import AUTO_ESC_FIRST, join_statustext_chunks
    from .tunnel_link import TunnelLink

__all__ = [
    "StreamRequestSettings",
    "GimbalSettings",
    "ACCEPTED",
    "ACTUATORS_PER_SET",
    "AUTO_ESC_FIRST",
    "ApplyResult",
    "BudgetPlan",
    "CanTunnel",
    "TunnelWireBytes",
    "tunnel_wire_bytes",
    "COMP_METADATA_TYPE_PARAMETER",
    "GENERAL_FILE",
    "GimbalDevice",
    "Health",
    "MavlinkSettings",
    "MavlinkSide",
    "NO_HEALTH_PROBLEM",
    "Outcome",
    "PARAMETER_FILE",
    "ServoStatus",
    "SetResult",
    "SigningSettings",
    "TelemetryRates",
    "TunnelLink",
    "WINDOW_S",
    "WritePolicy",
    "carriage_lines",
    "crc32",
    "left_out_streams",
    "euler_to_quaternion",
    "mavlink2",
    "mftp_uri",
    "open_connection",
    "plan_budget",
    "quaternion_to_euler",
    "join_statustext_chunks",
]
__getattr__ = lazy_face(
    __name__,
    {
        "StreamRequestSettings": "settings",
        "GimbalSettings": "gimbal_settings",
        "ACCEPTED": "backend",
        "ACTUATORS_PER_SET": "servo_commands",
        "AUTO_ESC_FIRST": "telemetry",
        "join_statustext_chunks": "telemetry",
        "ApplyResult": "backend",
        "BudgetPlan": "bandwidth",
        "CanTunnel": "can_tunnel",
        "TunnelWireBytes": "can_tunnel",
        "tunnel_wire_bytes": "can_tunnel",
        "COMP_METADATA_TYPE_PARAMETER": "metadata_service",
        "GENERAL_FILE": "metadata_service",
        "GimbalDevice": "gimbal",
        "Health": "backend",
        "MavlinkSettings": "settings",
        "MavlinkSide": "side",
        "NO_HEALTH_PROBLEM": "backend",
        "Outcome": "backend",
        "PARAMETER_FILE": "metadata_service",
        "ServoStatus": "backend",
        "SetResult": "params",
        "SigningSettings": "settings",
        "TelemetryRates": "settings",
        "TunnelLink": "tunnel_link",
        "WINDOW_S": "stream_request",
        "WritePolicy": "params",
        "carriage_lines": "link_carriage",
        "crc32": "ftp",
        "left_out_streams": "link_carriage",
        "euler_to_quaternion": "quaternion",
        "mavlink2": "connection",
        "mftp_uri": "metadata_service",
        "open_connection": "connection",
        "plan_budget": "bandwidth",
        "quaternion_to_euler": "quaternion",
    },
)
