"""The one table of servo profiles: the built-in families and the plug-ins of other packages.

The schema, ``check``, the bus-load budget, the scheduler's set-up, the simulator and the CLI all
ask here. A built-in family is one folder ``servos/<family>/`` plus one line of :data:`BUILT_IN`,
which names its profile (and simulated device) as ``"module:Class"`` and is imported on first
use, the way python-can keeps its interfaces: naming or checking one family imports no other.
Other packages register through the entry-point group :data:`ENTRY_POINT_GROUP`, the way
python-can finds buses::

    [project.entry-points."mavservo.profiles"]
    my-servo = "my_package.my_servo:MyServo"

Entry points are loaded once, on first use. One that fails to load (an import error, not a
:class:`ServoProfile`, a name clash) is kept with its reason in :func:`load_errors` and reported
by its entry-point name; the others stay usable.
"""

from __future__ import annotations

import difflib
import functools
import importlib
import inspect
import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from importlib.metadata import EntryPoint, entry_points

from mavservo.errors import MavservoError

from .base import ServoProfile


@dataclass(frozen=True)
class BuiltIn:
    """Where a built-in family lives, as ``"module:Class"`` paths below ``mavservo.servos``."""

    profile: str
    device: str | None = None
    """Its simulated device (:mod:`.sim_registry`); None when the profile builds its own."""
    link: str | None = None
    """A function ``(devices) -> None`` that lets the simulated devices of one bus meet (the
    servos of one DroneCAN node are one node), None when they are independent."""


ENTRY_POINT_GROUP = "mavservo.profiles"
BUILT_IN: dict[str, BuiltIn] = {
    "rmd-x": BuiltIn("rmdx.profile:RmdX", "rmdx.sim:RmdXV4Device"),
    "lk": BuiltIn("lk.profile:LkTech", "lk.sim:LkMotorDevice"),
    "cubemars-ak": BuiltIn("cubemars.profile:CubeMarsAK", "cubemars.sim:AkServoModeDevice"),
    "cubemars-ak-mit": BuiltIn(
        "cubemars.mit_mode:CubeMarsAKMit", "cubemars.mit_mode_sim:AkMitModeDevice"
    ),
    "damiao-dm": BuiltIn("damiao.profile:DamiaoDM", "damiao.sim:DmJMotorDevice"),
    "odrive": BuiltIn("odrive.profile:ODrive", "odrive.sim:OdriveAxisDevice"),
    "dronecan": BuiltIn(
        "dronecan.profile:DroneCanServo", "dronecan.sim:DroneCanDevice", "dronecan.sim:link_devices"
    ),
    "robstride": BuiltIn("robstride.profile:Robstride", "robstride.sim:RsMotorDevice"),
}
"""The built-in families by YAML name, in the order ``check --profiles`` lists them."""
PLUGIN_HINT = (
    f"plug-in profiles come from installed packages' {ENTRY_POINT_GROUP!r} entry points "
    "(see docs/profiles.md; `mavservo check --profiles` lists them)"
)
_NAME = re.compile(r"^[a-z][a-z0-9_\-]{0,31}$")


def import_built_in(path: str) -> object:
    """The object a ``"module:Class"`` path of :data:`BUILT_IN` names, imported now."""
    module_name, _, attribute = path.partition(":")
    module = importlib.import_module(f"{__package__}.{module_name}")
    return vars(module)[attribute]


@functools.cache
def _built_in(name: str) -> type[ServoProfile]:
    """The built-in profile class of ``name`` (KeyError if none), imported on first use."""
    cls = import_built_in(BUILT_IN[name].profile)
    if not (isinstance(cls, type) and issubclass(cls, ServoProfile) and cls.name == name):
        raise TypeError(f"BUILT_IN[{name!r}] does not name a ServoProfile called {name!r}")
    return cls


class _BuiltInProfiles(Mapping[str, type[ServoProfile]]):
    """:data:`BUILT_IN` as classes: iterating lists names, looking one up imports that family."""

    def __getitem__(self, name: str) -> type[ServoProfile]:
        return _built_in(name)

    def __iter__(self) -> Iterator[str]:
        return iter(BUILT_IN)

    def __len__(self) -> int:
        return len(BUILT_IN)


PROFILES: Mapping[str, type[ServoProfile]] = _BuiltInProfiles()
"""The built-in families by name, imported on lookup (plug-ins included: :func:`profiles`)."""


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


_plugins: dict[str, RegisteredProfile] | None = None
_errors: list[LoadError] = []


def _origin_of(entry_point: EntryPoint) -> str:
    dist_name = entry_point.dist.name if entry_point.dist is not None else "unknown package"
    return f"plug-in {dist_name} ({entry_point.value})"


def _problem(name: str, cls: object, taken: Mapping[str, str]) -> str | None:
    """Why a loaded entry point is not a usable profile, or None."""
    if not (isinstance(cls, type) and issubclass(cls, ServoProfile)):
        return f"{cls!r} is not a mavservo.servos.ServoProfile subclass"
    if name in taken:
        return f"name {name!r} is already taken by {taken[name]}"
    if inspect.isabstract(cls):
        missing = ", ".join(sorted(cls.__abstractmethods__))
        return f"{cls.__name__} does not implement {missing}"
    if cls.name != name:
        return f"the entry point is named {name!r} but the class says name = {cls.name!r}"
    if not _NAME.match(name):
        return f"name {name!r} must be lower case letters, digits, '-' or '_' (at most 32)"
    return None


def _load_plugins() -> dict[str, RegisteredProfile]:
    """Every entry point of the group, once; a plug-in cannot replace a built-in."""
    global _plugins
    if _plugins is not None:
        return _plugins
    plugins: dict[str, RegisteredProfile] = {}
    taken = dict.fromkeys(BUILT_IN, "built-in")
    errors: list[LoadError] = []
    for entry_point in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
        origin = _origin_of(entry_point)
        try:
            cls = entry_point.load()
        except Exception as exc:  # a broken plug-in must not hide the others
            errors.append(LoadError(entry_point.name, origin, f"{type(exc).__name__}: {exc}"))
            continue
        reason = _problem(entry_point.name, cls, taken)
        if reason is not None:
            errors.append(LoadError(entry_point.name, origin, reason))
            continue
        plugins[entry_point.name] = RegisteredProfile(cls, origin)
        taken[entry_point.name] = origin
    _plugins = plugins
    _errors[:] = errors
    return plugins


def reload() -> None:
    """Forget the plug-ins so the next call loads the entry points again (tests, after installs)."""
    global _plugins
    _plugins = None
    _errors.clear()


def profiles() -> dict[str, RegisteredProfile]:
    """Every usable profile by YAML name, built-ins first (this imports every family)."""
    built_in = {name: RegisteredProfile(PROFILES[name], "built-in") for name in BUILT_IN}
    return built_in | _load_plugins()


def names() -> list[str]:
    """The YAML names of every usable profile, sorted (no built-in family is imported)."""
    return sorted([*BUILT_IN, *_load_plugins()])


def load_errors() -> list[LoadError]:
    """Entry points that failed to load, each with its name and reason."""
    _load_plugins()
    return list(_errors)


def _folded(name: str) -> str:
    return name.lower().replace("-", "").replace("_", "").replace(" ", "")


def did_you_mean(name: object, known: list[str]) -> str:
    """`` (did you mean 'rmd-x'?)`` for a near miss (``rmdx``, ``RMD_X``, ``lkk``), else ``""``."""
    if not isinstance(name, str):
        return ""
    folded = {_folded(k): k for k in known}
    close = folded.get(_folded(name)) or next(
        iter(difflib.get_close_matches(name.lower(), known, n=1)), None
    )
    return f" (did you mean {close!r}?)" if close else ""


def get_profile(name: str) -> type[ServoProfile]:
    """The profile class for a YAML name; the error lists the names that do exist, where
    plug-ins come from, and any plug-in that failed to load (it may be the one meant)."""
    if isinstance(name, str) and name in BUILT_IN:
        return PROFILES[name]
    plugins = _load_plugins()
    entry = plugins.get(name) if isinstance(name, str) else None
    if entry is not None:
        return entry.profile
    known = names()
    message = f"unknown servo profile {name!r}{did_you_mean(name, known)}; known profiles: "
    message += ", ".join(known)
    message += f"; {PLUGIN_HINT}"
    failed = [error.describe() for error in _errors]
    if failed:
        message += "; " + "; ".join(failed)
    raise UnknownProfileError(message)
