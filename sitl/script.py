"""Mission-style events on a timeline: what the simulated autopilot does at which second.

The stream simulator runs a :class:`Script` alongside its profile. Events are plain frozen
dataclasses so a test can build a script inline, and :func:`parse_script` reads the same thing
from the dicts a YAML file gives (``simulation.autopilot.script`` in the bridge config)::

    - {at: 2.0, do_set_servo: {channel: 9, pwm: 1100}}
    - {at: 4.0, do_repeat_servo: {channel: 9, pwm: 1900, count: 3, cycle_s: 2.0}}
    - {at: 6.0, do_set_actuator: {values: [0.5, null], group: 1}}
    - {at: 8.0, gimbal: {roll: 0, pitch: -30, yaw: 45, flags: 0}}
    - {at: 10.0, dropout: {seconds: 3.0}}

Everything here is pure: no clock, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass


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
    """MAV_CMD_DO_SET_ACTUATOR (187): six normalized values (NaN = leave alone), 1-based group."""

    values: tuple[float, ...]
    group: int = 1

    def __post_init__(self) -> None:
        if len(self.values) > 6:
            raise ValueError("DO_SET_ACTUATOR carries at most 6 values")
        padded = tuple(self.values) + (math.nan,) * (6 - len(self.values))
        object.__setattr__(self, "values", padded)


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


def parse_event(item: Mapping[str, object]) -> Event:
    """One ``{at: t, <kind>: {...}}`` dict -> Event; raises ValueError naming what is wrong."""
    if "at" not in item:
        raise ValueError(f"script event without 'at': {dict(item)!r}")
    at = float(item["at"])  # type: ignore[arg-type]
    kinds = [k for k in item if k != "at"]
    if len(kinds) != 1:
        raise ValueError(f"script event needs exactly one action besides 'at': {dict(item)!r}")
    kind = kinds[0]
    body = item[kind]
    if not isinstance(body, Mapping):
        raise ValueError(f"script action {kind!r} needs a mapping, got {body!r}")
    args = dict(body)
    try:
        if kind == "do_set_servo":
            action: Action = SetServo(int(args["channel"]), int(args["pwm"]))
        elif kind == "do_repeat_servo":
            action = RepeatServo(
                int(args["channel"]), int(args["pwm"]), int(args["count"]), float(args["cycle_s"])
            )
        elif kind == "do_set_actuator":
            values = tuple(_float_or_nan(v) for v in args["values"])
            action = SetActuator(values, int(args.get("group", 1)))
        elif kind == "gimbal":
            action = GimbalTarget(
                float(args.get("roll", 0.0)),
                float(args.get("pitch", 0.0)),
                float(args.get("yaw", 0.0)),
                int(args.get("flags", 0)),
            )
        elif kind == "dropout":
            action = Dropout(float(args["seconds"]))
        else:
            raise ValueError(f"unknown script action {kind!r}")
    except KeyError as missing:
        raise ValueError(f"script action {kind!r} is missing {missing}") from None
    return Event(at, action)


def parse_script(items: Iterable[Mapping[str, object]]) -> Script:
    """A list of event dicts (from YAML) -> Script."""
    return Script(parse_event(item) for item in items)
