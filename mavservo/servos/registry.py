"""The one table of servo profiles: the built-in families and the plug-ins of other packages.

The schema, ``check``, the bus-load budget, the scheduler's set-up, the simulator and the CLI all
ask here, so a family is one module (or one out-of-tree package) and nothing else. Other packages
register through the entry-point group :data:`ENTRY_POINT_GROUP`, the way python-can finds buses::

    [project.entry-points."mavservo.profiles"]
    my-servo = "my_package.my_servo:MyServo"

Entry points are loaded once, on first use. One that fails to load (an import error, not a
:class:`ServoProfile`, a name clash) is kept with its reason in :func:`load_errors` and reported
by its entry-point name; the others stay usable.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from importlib.metadata import entry_points

from mavservo.errors import MavservoError

from .base import ServoProfile
from .cubemars.mit_mode import CubeMarsAKMit
from .cubemars.profile import CubeMarsAK
from .damiao.profile import DamiaoDM
from .dronecan.profile import DroneCanServo
from .lk.profile import LkTech
from .odrive.profile import ODrive
from .rmdx.profile import RmdX
from .robstride.profile import Robstride

ENTRY_POINT_GROUP = "mavservo.profiles"
BUILT_IN: tuple[type[ServoProfile], ...] = (
    RmdX,
    LkTech,
    CubeMarsAK,
    CubeMarsAKMit,
    DamiaoDM,
    ODrive,
    DroneCanServo,
    Robstride,
)
PLUGIN_HINT = (
    f"plug-in profiles come from installed packages' {ENTRY_POINT_GROUP!r} entry points "
    "(see docs/profiles.md; `mavservo check --profiles` lists them)"
)
PROFILES: dict[str, type[ServoProfile]] = {cls.name: cls for cls in BUILT_IN}
"""The built-in families by name (plug-ins included: :func:`profiles`)."""
_NAME = re.compile(r"^[a-z][a-z0-9_\-]{0,31}$")


class UnknownProfileError(MavservoError, KeyError, ValueError):
    """A YAML or CLI name that no profile answers to (a KeyError and a ValueError, so both
    dictionary-style and validation-style callers catch it)."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


@dataclass(frozen=True)
class RegisteredProfile:
    """A profile class and where it comes from (``built-in`` or ``plug-in <dist> (<value>)``)."""

    profile: type[ServoProfile]
    origin: str


@dataclass(frozen=True)
class LoadError:
    """An entry point that did not give a usable profile, and why."""

    entry_point: str
    origin: str
    reason: str

    def describe(self) -> str:
        return f"plug-in profile {self.entry_point!r} ({self.origin}) failed to load: {self.reason}"


_registry: dict[str, RegisteredProfile] | None = None
_errors: list[LoadError] = []


def _origin_of(entry_point: object) -> str:
    dist = getattr(entry_point, "dist", None)
    dist_name = getattr(dist, "name", None) or "unknown package"
    return f"plug-in {dist_name} ({getattr(entry_point, 'value', '?')})"


def _problem(name: str, cls: object, registry: dict[str, RegisteredProfile]) -> str | None:
    """Why a loaded entry point is not a usable profile, or None."""
    if not (isinstance(cls, type) and issubclass(cls, ServoProfile)):
        return f"{cls!r} is not a mavservo.servos.ServoProfile subclass"
    if name in registry:
        return f"name {name!r} is already taken by {registry[name].origin}"
    if getattr(cls, "__abstractmethods__", None):
        missing = ", ".join(sorted(cls.__abstractmethods__))
        return f"{cls.__name__} does not implement {missing}"
    if cls.name != name:
        return f"the entry point is named {name!r} but the class says name = {cls.name!r}"
    if not _NAME.match(name):
        return f"name {name!r} must be lower case letters, digits, '-' or '_' (at most 32)"
    return None


def _load() -> dict[str, RegisteredProfile]:
    """Built-ins first (a plug-in cannot replace one), then every entry point of the group."""
    global _registry
    if _registry is not None:
        return _registry
    registry = {cls.name: RegisteredProfile(cls, "built-in") for cls in BUILT_IN}
    errors: list[LoadError] = []
    for entry_point in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
        origin = _origin_of(entry_point)
        try:
            cls = entry_point.load()
        except Exception as exc:  # a broken plug-in must not hide the others
            errors.append(LoadError(entry_point.name, origin, f"{type(exc).__name__}: {exc}"))
            continue
        reason = _problem(entry_point.name, cls, registry)
        if reason is not None:
            errors.append(LoadError(entry_point.name, origin, reason))
            continue
        registry[entry_point.name] = RegisteredProfile(cls, origin)
    _registry = registry
    _errors[:] = errors
    return registry


def reload() -> None:
    """Forget the table so the next call loads the entry points again (tests, after installs)."""
    global _registry
    _registry = None
    _errors.clear()


def profiles() -> dict[str, RegisteredProfile]:
    """Every usable profile by YAML name, built-ins first."""
    return dict(_load())


def names() -> list[str]:
    """The YAML names of every usable profile, sorted."""
    return sorted(_load())


def load_errors() -> list[LoadError]:
    """Entry points that failed to load, each with its name and reason."""
    _load()
    return list(_errors)


def get_profile(name: str) -> type[ServoProfile]:
    """The profile class for a YAML name; the error lists the names that do exist, where
    plug-ins come from, and any plug-in that failed to load (it may be the one meant)."""
    registry = _load()
    entry = registry.get(name) if isinstance(name, str) else None
    if entry is not None:
        return entry.profile
    message = f"unknown servo profile {name!r}; known profiles: {', '.join(sorted(registry))}"
    message += f"; {PLUGIN_HINT}"
    failed = [error.describe() for error in _errors]
    if failed:
        message += "; " + "; ".join(failed)
    raise UnknownProfileError(message)
