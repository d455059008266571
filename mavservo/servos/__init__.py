"""Servo profiles: setpoints <-> CAN payloads, pure functions of their inputs.

A servo family is one folder ``servos/<family>/`` with a :class:`ServoProfile` subclass that
describes itself (see ``docs/profiles.md``): built-in families are one line each of the lazy
table :data:`mavservo.servos.registry.BUILT_IN`, other
packages register through the entry-point group ``mavservo.profiles``. The YAML config names
profiles by their short ``name``.
"""

from __future__ import annotations

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
from .registry import BUILT_IN, PROFILES, UnknownProfileError, get_profile, load_errors, profiles

_CLASSES = {line.profile.partition(":")[2]: name for name, line in BUILT_IN.items()}
"""Each built-in family's class name -> its YAML name (``RmdX`` -> ``rmd-x``), from the table."""


def __getattr__(attribute: str) -> type[ServoProfile]:
    """The family classes by their class names, imported on first use (PEP 562), so importing
    the package imports no family."""
    if attribute in _CLASSES:
        return PROFILES[_CLASSES[attribute]]
    raise AttributeError(f"module {__name__!r} has no attribute {attribute!r}")


__all__ = [
    "NO_FAULT",
    "PROFILES",
    "UNKNOWN",
    "ActuatorOptions",
    "Advising",
    "BusNode",
    "BusNodeError",
    "NodeHealth",
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
