"""Servo profiles: setpoints <-> CAN payloads, pure functions of their inputs.

A servo family is one folder ``servos/<family>/`` with a :class:`ServoProfile` subclass that
describes itself (see ``docs/profiles.md``): built-in families are one line each of the lazy
table :data:`mavservo.servos.registry.BUILT_IN`, other
packages register through the entry-point group ``mavservo.profiles``. The YAML config names
profiles by their short ``name``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from mavservo.faces import lazy_face

from .base import (
    NO_FAULT,
    UNKNOWN,
    ActuatorOptions,
    Advising,
    BusNode,
    BusNodeError,
    BusNodeFamily,
    CommTimeout,
    ConfigWarnings,
    CountingNode,
    Fault,
    FrameId,
    NodeHealth,
    NodeReports,
    ProfileOptions,
    Releasing,
    ServoProfile,
    ServoState,
    SimDevice,
    SimMotor,
    SplitStartup,
    UnsolicitedFrames,
    comm_timeout_of,
    node_family,
    node_reports_of,
    release_frames_of,
    unsolicited_hz_of,
)
from .registry import (
    BUILT_IN,
    PLUGIN_HINT,
    PROFILES,
    UnknownProfileError,
    get_profile,
    load_errors,
    profiles,
)

if TYPE_CHECKING:
    from .dronecan.get_node_info import NodeInfo, NodeInfoReader, get_node_info_request

_CLASSES = {line.profile.partition(":")[2]: name for name, line in BUILT_IN.items()}
"""Each built-in family's class name -> its YAML name (``RmdX`` -> ``rmd-x``), from the table."""


_FAMILY_TOOLS = lazy_face(
    __name__,
    {
        "NodeInfo": "dronecan.get_node_info",
        "NodeInfoReader": "dronecan.get_node_info",
        "get_node_info_request": "dronecan.get_node_info",
    },
)
"""A family's tools another layer uses (the doctor asks DroneCAN nodes who they are), imported
on first use like the families."""


def __getattr__(attribute: str) -> Any:
    """The family classes by their class names and the families' tools, imported on first use
    (PEP 562), so importing the package imports no family."""
    if attribute in _CLASSES:
        return PROFILES[_CLASSES[attribute]]
    return _FAMILY_TOOLS(attribute)


__all__ = [
    "NO_FAULT",
    "PLUGIN_HINT",
    "PROFILES",
    "UNKNOWN",
    "ActuatorOptions",
    "Advising",
    "BusNode",
    "BusNodeError",
    "NodeHealth",
    "NodeInfo",
    "NodeInfoReader",
    "get_node_info_request",
    "BusNodeFamily",
    "CommTimeout",
    "ConfigWarnings",
    "CountingNode",
    "CubeMarsAK",
    "CubeMarsAKMit",
    "DamiaoDM",
    "DroneCanServo",
    "Fault",
    "FrameId",
    "LkTech",
    "NodeReports",
    "ODrive",
    "ProfileOptions",
    "Releasing",
    "RmdX",
    "Robstride",
    "ServoProfile",
    "ServoState",
    "SimDevice",
    "SimMotor",
    "SplitStartup",
    "UnknownProfileError",
    "UnsolicitedFrames",
    "comm_timeout_of",
    "get_profile",
    "load_errors",
    "node_family",
    "node_reports_of",
    "profiles",
    "release_frames_of",
    "unsolicited_hz_of",
]
