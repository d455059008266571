"""Mission-style events on a timeline: what the simulated autopilot does at which second.

The stream simulator runs a :class:`Script` alongside its profile. Events are plain frozen
dataclasses so a test can build a script inline, and :func:`parse_script` reads the same thing
from the dicts a YAML file gives (``simulation.autopilot.script`` in the bridge config)::

    - {at: 2.0, do_set_servo: {channel: 9, pwm: 1100}}
    - {at: 4.0, do_repeat_servo: {channel: 9, pwm: 1900, count: 3, cycle_s: 2.0}}
    - {at: 6.0, do_set_actuator: {values: [0.5, null], set_index: 0}}
    - {at: 8.0, gimbal: {roll: 0, pitch: -30, yaw: 45, flags: 0}}
    - {at: 10.0, dropout: {seconds: 3.0}}

Everything here is pure: no clock, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

# The bridge's own count (params 1..6 per set, param 7 the set): the script addresses actuators
# exactly as the bridge numbers them, so the two cannot drift apart.
from mavservo.mavlink import ACTUATORS_PER_SET


@dataclass(frozen=True)
class SetServo:
    """MAV_CMD_DO_SET_SERVO (183): p1 output channel, p2 PWM us."""

    channel: int
    pwm: int


@dataclass(frozen=True)
class RepeatServo:
    """MAV_CMD_DO_REPEAT_SERVO (184): toggle between ``pwm`` and trim ``count`` times."""

    channel: int
    pwm: int
    count: int
    cycle_s: float


@dataclass(frozen=True)
class SetActuator:
    """MAV_CMD_DO_SET_ACTUATOR (187): six normalized values (NaN = leave alone) for one set.

    ``set_index`` is param 7 as the MAVLink spec defines it, "index of actuator set (i.e. if set
    to 1, Actuator 1 becomes Actuator 7)": 0 addresses actuators 1..6, 1 addresses 7..12. PX4
    acts on set 0 only (its "Peripheral via Actuator Set 1..6" functions) and the bridge maps
    ``source: actuator`` channels by the same 1-based actuator number, so the default is 0.
    """

    values: tuple[float, ...]
    set_index: int = 0

    def __post_init__(self) -> None:
        if len(self.values) > ACTUATORS_PER_SET:
            raise ValueError(f"DO_SET_ACTUATOR carries at most {ACTUATORS_PER_SET} values")
        if self.set_index < 0:
            raise ValueError(f"DO_SET_ACTUATOR set_index must be >= 0, got {self.set_index}")
        padded = tuple(self.values) + (math.nan,) * (ACTUATORS_PER_SET - len(self.values))
        object.__setattr__(self, "values", padded)

    def actuators(self) -> dict[int, float]:
        """{1-based actuator number: value} of the values given (NaN = left alone)."""
        base = self.set_index * ACTUATORS_PER_SET
        return {base + i + 1: v for i, v in enumerate(self.values) if not math.isnan(v)}


@dataclass(frozen=True)
class GimbalTarget:
    """A new gimbal-manager target; ``flags`` as ArduPilot sets them in SET_ATTITUDE."""

    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0
    flags: int = 0


@dataclass(frozen=True)
class Dropout:
    """Stop sending anything (heartbeats included) for ``seconds``: a link loss."""

    seconds: float


Action = SetServo | RepeatServo | SetActuator | GimbalTarget | Dropout


@dataclass(frozen=True)
class Event:
    at: float
    action: Action


class Script:
    """A time-ordered list of events; :meth:`due` hands out each event exactly once."""

    def __init__(self, events: Iterable[Event] = ()) -> None:
        self.events = sorted(events, key=lambda e: e.at)
        self._next = 0

    def due(self, t: float) -> list[Event]:
        """Events whose time has come at ``t`` (seconds since start), in order, each only once."""
        out = []
        while self._next < len(self.events) and self.events[self._next].at <= t:
            out.append(self.events[self._next])
            self._next += 1
        return out

    @property
    def finished(self) -> bool:
        return self._next >= len(self.events)


def repeat_servo_value(action: RepeatServo, elapsed: float, trim: int = 1500) -> tuple[int, bool]:
    """Output of a DO_REPEAT_SERVO ``elapsed`` seconds after it started: (pwm, finished).

    ArduPilot's behaviour (see tests/data/README.md): start on ``pwm``, alternate with trim every
    half cycle, ``count`` times, and finish on trim.
    """
    half = action.cycle_s / 2.0
    toggles = 2 * action.count
    if half <= 0 or elapsed >= toggles * half:
        return trim, True
    index = int(max(elapsed, 0.0) // half)
    return (action.pwm if index % 2 == 0 else trim), False


def _float_or_nan(value: object) -> float:
    return math.nan if value is None else float(value)  # type: ignore[arg-type]


#: The keys each action takes (required, optional); anything else is a typo and an error.
ACTION_KEYS: dict[str, tuple[frozenset[str], frozenset[str]]] = {
    "do_set_servo": (frozenset({"channel", "pwm"}), frozenset()),
    "do_repeat_servo": (frozenset({"channel", "pwm", "count", "cycle_s"}), frozenset()),
    "do_set_actuator": (frozenset({"values"}), frozenset({"set_index"})),
    "gimbal": (frozenset(), frozenset({"roll", "pitch", "yaw", "flags"})),
    "dropout": (frozenset({"seconds"}), frozenset()),
}

#: Keys that once meant something else, with what to write instead.
RENAMED_KEYS = {
    ("do_set_actuator", "group"): (
        "'group' is gone: write 'set_index', param 7 of MAV_CMD_DO_SET_ACTUATOR as the MAVLink "
        "spec defines it (0 = actuators 1..6, 1 = actuators 7..12; the old 'group: 1' is "
        "'set_index: 0')"
    ),
}


def _check_keys(kind: str, args: Mapping[str, object]) -> None:
    required, optional = ACTION_KEYS[kind]
    for key in args:
        if (kind, key) in RENAMED_KEYS:
            raise ValueError(f"script action {kind!r}: {RENAMED_KEYS[kind, key]}")
    unknown = sorted(set(args) - required - optional)
    if unknown:
        allowed = ", ".join(sorted(required | optional))
        raise ValueError(f"script action {kind!r}: unknown key(s) {unknown} (allowed: {allowed})")
    missing = sorted(required - set(args))
    if missing:
        raise ValueError(f"script action {kind!r} is missing {missing}")


def parse_event(item: Mapping[str, object]) -> Event:
    """One ``{at: t, <kind>: {...}}`` dict -> Event; raises ValueError naming what is wrong."""
    if "at" not in item:
        raise ValueError(f"script event without 'at': {dict(item)!r}")
    at = float(item["at"])  # type: ignore[arg-type]
    kinds = [k for k in item if k != "at"]
    if len(kinds) != 1:
        raise ValueError(f"script event needs exactly one action besides 'at': {dict(item)!r}")
    kind = kinds[0]
    if kind not in ACTION_KEYS:
        raise ValueError(f"unknown script action {kind!r} (known: {', '.join(ACTION_KEYS)})")
    body = item[kind]
    if not isinstance(body, Mapping):
        raise ValueError(f"script action {kind!r} needs a mapping, got {body!r}")
    args = dict(body)
    _check_keys(kind, args)
    if kind == "do_set_servo":
        action: Action = SetServo(int(args["channel"]), int(args["pwm"]))
    elif kind == "do_repeat_servo":
        action = RepeatServo(
            int(args["channel"]), int(args["pwm"]), int(args["count"]), float(args["cycle_s"])
        )
    elif kind == "do_set_actuator":
        raw = args["values"]
        if not isinstance(raw, list | tuple):
            raise ValueError(
                f"script action 'do_set_actuator': 'values' needs a list of up to "
                f"{ACTUATORS_PER_SET} numbers in [-1, 1] (null = leave alone), got {raw!r}"
            )
        values = tuple(_float_or_nan(v) for v in raw)
        action = SetActuator(values, int(args.get("set_index", 0)))
    elif kind == "gimbal":
        action = GimbalTarget(
            float(args.get("roll", 0.0)),
            float(args.get("pitch", 0.0)),
            float(args.get("yaw", 0.0)),
            int(args.get("flags", 0)),
        )
    else:
        action = Dropout(float(args["seconds"]))
    return Event(at, action)


def parse_script(items: Iterable[Mapping[str, object]]) -> Script:
    """A list of event dicts (from YAML) -> Script; an error names the event (1-based)."""
    events = []
    for number, item in enumerate(items, 1):
        try:
            events.append(parse_event(item))
        except (ValueError, TypeError) as exc:
            where = f"event {number}" + (f" (at {item['at']})" if "at" in item else "")
            raise ValueError(f"{where}: {exc}") from None
    return Script(events)
