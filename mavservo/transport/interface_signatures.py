"""What a python-can interface accepts as keyword arguments, to check a bus's ``options:``.

python-can passes unknown keyword arguments of most interfaces on to ``BusABC`` silently, so a
typo (``tty_baudrat: 921600``) would be ignored and the adapter opened with its default. This
module reads the interface class's constructor signature and the parameters its docstring
documents (``inspect``: the interface's own declaration, no copy of it kept here), names
unknown keys with the closest accepted one, and checks a value against the parameter's
annotation where that is a plain type (bool, int, float, str). The keys the bus has its own
YAML key for (``channel``, ``bitrate``) are refused, so one setting is never given in two
places. An interface whose module cannot be imported here (a vendor library missing on this
machine) is not checked: the config stays loadable by ``mavservo check`` on a laptop, and the
bus's open says what is missing.
"""

from __future__ import annotations

import difflib
import inspect
import math
import re
import types
import typing
from collections.abc import Mapping
from functools import lru_cache
from typing import Any, Union

import can
from can.interface import _get_class_for_interface

#: Keys with a YAML key of their own on the bus (or set by the bridge itself).
RESERVED = {
    "channel": "use the bus's own `channel:` key",
    "bitrate": "use the bus's own `bitrate:` key",
    "interface": "use the bus's own `interface:` key",
    "bustype": "use the bus's own `interface:` key",
    "on_reject": "set by the bridge (the run log's rejections)",
    "ignore_config": "set by the bridge (the YAML is the only configuration)",
    "config_context": "the YAML is the only configuration: give the option itself",
    "carrier": "set by the bridge (its MAVLink link, for interface mavlink-can)",
}

#: Keys an interface's bus has its own YAML key for, per interface.
OWN_KEYS = {
    "aa55": {
        "serial_baud": "use the bus's own `serial_baud:` key",
        "protocol": "use the bus's own `protocol:` key",
        "read_interval_s": "use the bus's own `read_interval_s:` key",
    },
    "mavlink-can": {
        "clock": "set by the bridge",
        "startup_grace_s": "set by the bridge (the first open waits for the autopilot)",
        "confirm_s": "set by the bridge (a reopen waits for the autopilot's answer)",
        "forward_filter_ids": "set by the bridge from the servos' reply ids",
    },
}

#: BusABC's own keyword arguments, accepted by every interface.
_BUS_ABC = ("can_filters",)

_PLAIN = (bool, int, float, str)

#: ``:param bool fd:`` / ``:param fd:`` in an interface's docstring: keyword arguments it reads
#: from ``**kwargs`` (PCAN's ``fd``, ``f_clock``, ...), documented but not in its signature.
_DOC_PARAM = re.compile(r":param\s+(?:[\w\[\], .|]+\s+)?(\w+)\s*:")


class InterfaceOptions:
    """An interface's keyword parameters and their plain types (None: any value)."""

    def __init__(self, interface: str, parameters: Mapping[str, type | tuple[type, ...] | None]):
        self.interface = interface
        self.parameters = dict(parameters)

    def problems(self, options: Mapping[str, Any]) -> list[tuple[str, str]]:
        """``(key, message)`` for every option the interface would not take as given."""
        out: list[tuple[str, str]] = []
        for key, value in options.items():
            key = str(key)
            reserved = RESERVED.get(key) or OWN_KEYS.get(self.interface, {}).get(key)
            if reserved:
                out.append((key, f"{key!r} is not an option here: {reserved}"))
                continue
            if key not in self.parameters:
                out.append((key, self._unknown(key)))
                continue
            kinds = self.parameters[key]
            if kinds is not None and not _fits(value, kinds):
                names = " or ".join(k.__name__ for k in _as_tuple(kinds))
                out.append(
                    (key, f"{key!r} of interface {self.interface!r} takes {names}, found {value!r}")
                )
            elif kinds is not None and not _in_range(value):
                out.append((key, f"{key!r} must be a finite number >= 0, found {value!r}"))
            elif key == "can_filters" and (problem := _filters_problem(value)):
                out.append((key, problem))
        return out

    def _unknown(self, key: str) -> str:
        accepted = sorted(self.parameters)
        close = difflib.get_close_matches(key, accepted, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        return (
            f"unknown option {key!r} for python-can interface {self.interface!r}{hint}; "
            f"it accepts: {', '.join(accepted) or 'none'}"
        )


def _as_tuple(kinds: type | tuple[type, ...]) -> tuple[type, ...]:
    return kinds if isinstance(kinds, tuple) else (kinds,)


def _fits(value: Any, kinds: type | tuple[type, ...]) -> bool:
    for kind in _as_tuple(kinds):
        if kind is bool and isinstance(value, bool):
            return True
        if kind is int and isinstance(value, int) and not isinstance(value, bool):
            return True
        if kind is float and isinstance(value, (int, float)) and not isinstance(value, bool):
            return True
        if kind is str and isinstance(value, str):
            return True
    return False


def _in_range(value: Any) -> bool:
    """Numbers a python-can interface takes (seconds, baud rates, clocks, sizes) are finite and
    not negative: ``sleep_after_open: -1`` or ``.nan`` reached ``time.sleep`` and stopped the
    bridge's start with a traceback."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return True
    return math.isfinite(value) and value >= 0


#: ``can_filters`` (python-can's ``CanFilter``): a list of these mappings.
_FILTER_KEYS = {"can_id": int, "can_mask": int, "extended": bool}


def _filters_problem(value: Any) -> str | None:
    """Why ``value`` is not python-can's filter list (None: it is), so a malformed one is a
    FILE:LINE error instead of a bus that drops every frame at run time."""
    shape = (
        "'can_filters' takes a list of {can_id: int, can_mask: int, extended: bool} "
        f"(extended optional), found {value!r}"
    )
    if value is None:
        return None
    if not isinstance(value, list):
        return shape
    if len(value) > MAX_FILTERS:
        return f"'can_filters': at most {MAX_FILTERS} filters, found {len(value)}"
    for entry in value:
        if not isinstance(entry, Mapping) or not {"can_id", "can_mask"} <= set(entry):
            return shape
        for key, item in entry.items():
            kind = _FILTER_KEYS.get(str(key))
            if kind is None or not _fits(item, kind):
                return shape
            if kind is int and not 0 <= item <= 0x1FFFFFFF:
                return f"'can_filters' {key} {item!r} is not a CAN id (0..0x1FFFFFFF)"
    return None


#: More filters than any adapter has hardware for.
MAX_FILTERS = 64


def _plain_kinds(annotation: Any) -> type | tuple[type, ...] | None:
    """The plain types an annotation allows, None when it allows anything else too."""
    if annotation in _PLAIN:
        return typing.cast(type, annotation)
    origin = typing.get_origin(annotation)
    if origin is Union or origin is types.UnionType:
        members = [a for a in typing.get_args(annotation) if a is not type(None)]
        if members and all(a in _PLAIN for a in members):
            return tuple(members)
    return None


class UnknownInterfaceError(ValueError):
    """No python-can interface of that name (installed entry points included)."""


@lru_cache(maxsize=64)
def interface_options(interface: str) -> InterfaceOptions | None:
    """The options ``interface`` accepts; None when its module cannot be imported here.

    Raises :class:`UnknownInterfaceError` for a name python-can does not know.
    """
    if interface not in can.interfaces.VALID_INTERFACES:
        known = ", ".join(sorted(can.interfaces.VALID_INTERFACES))
        close = difflib.get_close_matches(interface, can.interfaces.VALID_INTERFACES, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise UnknownInterfaceError(
            f"unknown python-can interface {interface!r}{hint}; known: {known}"
        )
    try:
        bus_class = _get_class_for_interface(interface)
    except (can.CanInterfaceNotImplementedError, ImportError):
        return None
    parameters: dict[str, type | tuple[type, ...] | None] = dict.fromkeys(_BUS_ABC)
    try:
        hints = typing.get_type_hints(bus_class.__init__)
    except Exception:  # noqa: BLE001 - an annotation this Python cannot evaluate: no types
        hints = {}
    for name, parameter in inspect.signature(bus_class.__init__).parameters.items():
        if name == "self" or parameter.kind in (parameter.VAR_KEYWORD, parameter.VAR_POSITIONAL):
            continue
        parameters[name] = _plain_kinds(hints.get(name))
    for name in _DOC_PARAM.findall(inspect.getdoc(bus_class.__init__) or ""):
        parameters.setdefault(name, None)
    for varargs in ("args", "kwargs"):
        parameters.pop(varargs, None)
    for reserved in RESERVED:
        parameters.pop(reserved, None)
    return InterfaceOptions(interface, parameters)


def option_problems(interface: str, options: Mapping[str, Any]) -> list[tuple[str, str]]:
    """``(key, message)`` for each problem of ``options`` under ``interface`` (see module)."""
    try:
        accepted = interface_options(interface)
    except UnknownInterfaceError:
        return []  # the interface key itself is reported, not each option
    if accepted is None:
        return [(str(k), RESERVED[str(k)]) for k in options if str(k) in RESERVED]
    return accepted.problems(options)
