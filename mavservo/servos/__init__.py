"""Servo profiles: setpoints <-> CAN payloads, pure functions of their inputs.

Adding a servo family is one module with a :class:`ServoProfile` subclass and one entry in
:data:`PROFILES`; the YAML config names profiles by these short strings.
"""

from __future__ import annotations

from mavservo.errors import MavservoError

from .base import NO_FAULT, UNKNOWN, Fault, ServoProfile, ServoState
from .cubemars import CubeMarsAK
from .cubemars_mit import CubeMarsAKMit
from .damiao import DamiaoDM
from .rmdx import LkTech, RmdX

PROFILES: dict[str, type[ServoProfile]] = {
    RmdX.name: RmdX,
    LkTech.name: LkTech,
    CubeMarsAK.name: CubeMarsAK,
    CubeMarsAKMit.name: CubeMarsAKMit,
    DamiaoDM.name: DamiaoDM,
}


class UnknownProfileError(MavservoError, KeyError, ValueError):
    """A YAML or CLI name that no profile answers to (a KeyError and a ValueError, so both
    dictionary-style and validation-style callers catch it)."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


def get_profile(name: str) -> type[ServoProfile]:
    """The profile class for a YAML name; the error lists the names that do exist."""
    try:
        return PROFILES[name]
    except KeyError:
        known = ", ".join(sorted(PROFILES))
        message = f"unknown servo profile {name!r}; known profiles: {known}"
        raise UnknownProfileError(message) from None


__all__ = [
    "NO_FAULT",
    "PROFILES",
    "UNKNOWN",
    "CubeMarsAK",
    "CubeMarsAKMit",
    "DamiaoDM",
    "Fault",
    "LkTech",
    "RmdX",
    "ServoProfile",
    "ServoState",
    "UnknownProfileError",
    "get_profile",
]
