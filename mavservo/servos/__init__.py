"""Servo profiles: setpoints <-> CAN payloads, pure functions of their inputs.

A servo family is one module with a :class:`ServoProfile` subclass that describes itself (see
``docs/profiles.md``): built-in families are listed in :mod:`mavservo.servos.registry`, other
packages register through the entry-point group ``mavservo.profiles``. The YAML config names
profiles by their short ``name``.
"""

from __future__ import annotations

from . import simulators  # noqa: F401  (fills sim_registry with the built-in devices)
from .base import (
    NO_FAULT,
    UNKNOWN,
    Fault,
    FrameId,
    ProfileOptions,
    ServoProfile,
    ServoState,
    SimDevice,
    SimMotor,
)
from .cubemars.mit_mode import CubeMarsAKMit
from .cubemars.profile import CubeMarsAK
from .damiao.profile import DamiaoDM
from .dronecan.profile import DroneCanServo
from .lk.profile import LkTech
from .odrive.profile import ODrive
from .registry import PROFILES, UnknownProfileError, get_profile, load_errors, profiles
from .rmdx.profile import RmdX
from .robstride.profile import Robstride

__all__ = [
    "NO_FAULT",
    "PROFILES",
    "UNKNOWN",
    "CubeMarsAK",
    "CubeMarsAKMit",
    "DamiaoDM",
    "DroneCanServo",
    "Fault",
    "FrameId",
    "LkTech",
    "ODrive",
    "ProfileOptions",
    "RmdX",
    "Robstride",
    "ServoProfile",
    "ServoState",
    "SimDevice",
    "SimMotor",
    "UnknownProfileError",
    "get_profile",
    "load_errors",
    "profiles",
]
