"""The bridge's settings as MAVLink parameters: names, units, ranges, and their place in a config.

A ground station tunes the bridge the way it tunes an autopilot's ``SERVOn_TRIM``: one float per
name, at most 16 characters. This table is the one place that says which config key each name
stands for, so the parameter protocol, the overlay file, ``mavservo check``, the README and the
metadata file a ground station reads all agree. A new value is never trusted on its own: it is
written into the config and the whole config is validated again by the same rules as the YAML
(:func:`with_values`), so a trim that pushes a channel's centre outside its output range is
refused exactly as it would be in the file.

Servos are numbered from 1 in config order (``SRV1_*`` is the first entry of ``servos:``);
gimbals likewise (``GMB1_*``), and a gimbal's parameters are also served by its own component.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from pydantic import ValidationError

from mavservo.config.schema import Config, KeptOptions
from mavservo.config.semantic import budget_checks, cross_checks
from mavservo.config.tunnel_plan import tunnel_checks
from mavservo.errors import MavservoError

#: MAVLink's PARAM_VALUE.param_id holds 16 characters.
MAX_NAME_LENGTH = 16

#: Failsafe actions as a ground station enumerates them (SRVn_FS_ACT).
FAILSAFE_ACTIONS = ("hold", "neutral", "position", "release")

#: Value of an optional setting that is not set (SRVn_SLEW 0: no slew limit; SRVn_FS_POS NaN
#: would be refused by ground stations, so an unset failsafe position reads as the neutral angle).
NO_SLEW_LIMIT = 0.0

RawConfig = dict[str, Any]


class ParameterError(MavservoError, ValueError):
    """A parameter value the config's rules refuse; ``str()`` is the reason for STATUSTEXT."""


@dataclass(frozen=True)
class Parameter:
    """One named setting: how to read it from a config and where a new value goes.

    ``component`` is "servo" for the servo component's parameters or a gimbal's name for those
    its own component serves too. ``values`` enumerates the meaning of integral settings.
    """

    name: str
    component: str
    unit: str
    minimum: float
    maximum: float
    description: str
    read: Callable[[Config], float]
    write: Callable[[RawConfig, float], None]
    values: Mapping[int, str] | None = None
    integral: bool = False
    range_note: str = ""
    """Why the range is what it is, said with a value outside it."""

    def __post_init__(self) -> None:
        if len(self.name) > MAX_NAME_LENGTH:
            raise ValueError(f"parameter name {self.name!r} is longer than {MAX_NAME_LENGTH}")


def parameter_table(config: Config, envelope: Config | None = None) -> list[Parameter]:
    """Every parameter of ``config``, in the order a PARAM_REQUEST_LIST sends them.

    ``envelope``: the config file as written (``config`` itself when None). The angle
    parameters (limits, failsafe position, gimbal limits) range over its limits, so the range a
    ground station shows (the component metadata) is what a PARAM_SET may take: before, they
    showed +-36,000 deg and every value past the file's limits was refused."""
    outer = config if envelope is None else envelope
    table: list[Parameter] = []
    for number, servo in enumerate(config.servos, start=1):
        table.extend(_servo_parameters(config, number, servo.name, _servo_span(outer, servo.name)))
    for number, gimbal in enumerate(config.gimbals, start=1):
        table.extend(_gimbal_parameters(number, gimbal.name, _gimbal_spans(outer, gimbal.name)))
    table.extend(_telemetry_parameters(gimbals=bool(config.gimbals)))
    return table


def parameters_by_name(config: Config, envelope: Config | None = None) -> dict[str, Parameter]:
    return {p.name: p for p in parameter_table(config, envelope)}


def _servo_span(envelope: Config, servo: str) -> tuple[float, float]:
    """The angles a servo's limit and failsafe parameters may take: its limits in the file
    (the whole angle span for a servo the file does not have)."""
    for candidate in envelope.servos:
        if candidate.name == servo:
            low, high = candidate.limits_deg
            return float(low), float(high)
    return -_ANGLE_SPAN, _ANGLE_SPAN


def _gimbal_spans(envelope: Config, gimbal: str) -> dict[str, tuple[float, float]]:
    """Per axis, the angles the gimbal's limit parameters may take: the file's limit of the
    axis (its own, or its servo's when the gimbal names none)."""
    spans: dict[str, tuple[float, float]] = {}
    for candidate in envelope.gimbals:
        if candidate.name != gimbal:
            continue
        for axis, _ in _AXES:
            limits = getattr(candidate.limits_deg, axis)
            servo = getattr(candidate, axis)
            if limits is not None:
                spans[axis] = (float(limits[0]), float(limits[1]))
            elif servo is not None:
                spans[axis] = _servo_span(envelope, servo)
    return spans


def current_values(config: Config) -> dict[str, float]:
    """Every parameter's value in ``config``."""
    return {p.name: p.read(config) for p in parameter_table(config)}


def with_values(
    config: Config,
    values: Mapping[str, float],
    *,
    envelope: Config | None = None,
    table: Mapping[str, Parameter] | None = None,
) -> Config:
    """``config`` with ``values`` set, validated again as a whole like a YAML file.

    ``envelope``: the config file as written (without the overlay); the result must stay within
    its limits (:func:`envelope_problem`). ``table``: :func:`parameters_by_name` of ``config``
    and ``envelope`` when the caller keeps it (the running bridge: no parameter changes which
    parameters exist nor the envelope's ranges, so one table serves every PARAM_SET).

    The rebuild is one validation of the whole config: the servos' and buses' typed options,
    which no parameter writes, are taken over from ``config`` (:class:`KeptOptions`), not
    validated again.

    Raises :class:`ParameterError` naming the parameter for an unknown name, a value that is
    not finite, outside the parameter's range, not one of its values, or that the config's own
    rules (models, cross-section checks, bus-load budget) refuse.
    """
    if table is None:
        table = parameters_by_name(config, envelope)
    raw = config.model_dump()
    for name, value in values.items():
        parameter = table.get(name)
        if parameter is None:
            raise ParameterError(f"{name}: no such parameter")
        value = snap_to_range(parameter, value)
        _check_value(parameter, value)
        parameter.write(raw, value)
    try:
        updated = Config.model_validate(raw, context=KeptOptions(config).context())
    except ValidationError as exc:
        first = exc.errors()[0]
        reason = first["msg"].removeprefix("Value error, ")
        key = next((str(part) for part in reversed(first["loc"]) if isinstance(part, str)), "")
        detail = reason if first["type"] == "value_error" else f"{key}: {reason}"
        raise ParameterError(f"{_names(values)}: {detail}") from None
    findings = cross_checks(updated) or budget_checks(updated) or tunnel_checks(updated)
    if findings:
        raise ParameterError(f"{_names(values)}: {findings[0][1]}")
    problem = None if envelope is None else envelope_problem(envelope, updated)
    if problem is not None:
        raise ParameterError(f"{_names(values)}: {problem}")
    return updated


def _names(values: Mapping[str, float]) -> str:
    return ", ".join(values)


def float32(value: float) -> float:
    """``value`` as MAVLink carries it (PARAM_SET.param_value is a float32)."""
    try:
        return float(struct.unpack("<f", struct.pack("<f", value))[0])
    except OverflowError:
        return math.copysign(math.inf, value)


def snap_to_range(parameter: Parameter, value: float) -> float:
    """``value``, or the range bound it equals once both are float32.

    Why: a ground station sends ``SRV1_FS_TMO 0.01`` (the documented minimum) as float32
    0.0099999998; compared in float64 it was below 0.01 and refused. A value that rounds to the
    same float32 as a bound is that bound; anything else is left as it came."""
    for bound in (parameter.minimum, parameter.maximum):
        if math.isfinite(value) and float32(value) == float32(bound):
            return float(bound)
    return value


def envelope_problem(base: Config, updated: Config) -> str | None:
    """Why ``updated`` leaves the envelope of ``base`` (the YAML file), or None.

    The YAML is the integrator's statement of what the hardware may do: a parameter may narrow
    a servo's limits, move its failsafe position or a gimbal axis's limits within them, never
    beyond. Why: one unauthenticated PARAM_SET ``SRV1_MAX=36000`` widened the limits the mapping
    takes its output from and drove the aileron to 17,985 deg (issue 32, finding 1).
    """
    for servo, outer in zip(updated.servos, base.servos, strict=True):
        low, high = outer.limits_deg
        new_low, new_high = servo.limits_deg
        if new_low < low or new_high > high:
            return (
                f"limits {new_low:g}..{new_high:g} deg of {servo.name} leave the config file's "
                f"{low:g}..{high:g} deg (parameters may only narrow them)"
            )
        position = servo.failsafe.position_deg
        if position is not None and not low <= position <= high:
            return (
                f"failsafe position {position:g} deg of {servo.name} is outside the config "
                f"file's limits {low:g}..{high:g} deg"
            )
    for gimbal, outer_gimbal in zip(updated.gimbals, base.gimbals, strict=True):
        for axis, _ in _AXES:
            new = _gimbal_limits(updated, gimbal, axis)
            old = _gimbal_limits(base, outer_gimbal, axis)
            if new[0] < old[0] or new[1] > old[1]:
                return (
                    f"gimbal {gimbal.name} {axis} limits {new[0]:g}..{new[1]:g} deg leave the "
                    f"config file's {old[0]:g}..{old[1]:g} deg (parameters may only narrow them)"
                )
    return None


def _gimbal_limits(config: Config, gimbal: Any, axis: str) -> tuple[float, float]:
    limits = getattr(gimbal.limits_deg, axis)
    if limits is None:
        servo = getattr(gimbal, axis)
        limits = config.servo(servo).limits_deg if servo is not None else (-180.0, 180.0)
    return float(limits[0]), float(limits[1])


def _check_value(parameter: Parameter, value: float) -> None:
    if not math.isfinite(value):
        raise ParameterError(f"{parameter.name}: {value!r} is not a finite number")
    if not parameter.minimum <= value <= parameter.maximum:
        raise ParameterError(
            f"{parameter.name}: {value:g} is outside {parameter.minimum:g}..{parameter.maximum:g}"
            f"{' ' + parameter.unit if parameter.unit else ''}"
            f"{' (' + parameter.range_note + ')' if parameter.range_note else ''}"
        )
    if parameter.integral and value != int(value):
        raise ParameterError(f"{parameter.name}: {value:g} is not a whole number")
    if parameter.values is not None and int(value) not in parameter.values:
        choices = ", ".join(f"{k} {v}" for k, v in parameter.values.items())
        raise ParameterError(f"{parameter.name}: {value:g} is not one of {choices}")


# ------------------------------------------------------------------------------------ servos

#: Angles a servo parameter may take at all; the config's rules narrow this further.
_ANGLE_SPAN = 36_000.0
ENVELOPE_NOTE = "the config file's limits: a parameter may narrow them, never widen them"


def _servo_parameters(
    config: Config, number: int, servo: str, span: tuple[float, float]
) -> list[Parameter]:
    prefix = f"SRV{number}_"
    index = number - 1

    def servo_of(c: Config) -> Any:
        return c.servos[index]

    def channels_of(raw: RawConfig) -> list[dict[str, Any]]:
        return [ch for ch in raw["channels"] if ch["servo"] == servo]

    def first_channel(c: Config) -> Any:
        return next((ch for ch in c.channels if ch.servo == servo), None)

    def set_channels(
        key: str, convert: Callable[[float], Any]
    ) -> Callable[[RawConfig, float], None]:
        def write(raw: RawConfig, value: float) -> None:
            entries = channels_of(raw)
            if not entries:
                raise ParameterError(f"{prefix}*: servo {servo!r} has no channel to set this on")
            for entry in entries:
                entry[key] = convert(value)

        return write

    def set_servo(
        path: tuple[str, ...], convert: Callable[[float], Any] = float
    ) -> Callable[[RawConfig, float], None]:
        def write(raw: RawConfig, value: float) -> None:
            node = raw["servos"][index]
            for key in path[:-1]:
                node = node[key]
            node[path[-1]] = convert(value)

        return write

    def set_limit(side: int) -> Callable[[RawConfig, float], None]:
        def write(raw: RawConfig, value: float) -> None:
            limits = list(raw["servos"][index]["limits_deg"])
            limits[side] = float(value)
            raw["servos"][index]["limits_deg"] = tuple(limits)

        return write

    def channel_value(read: Callable[[Any], float], default: float) -> Callable[[Config], float]:
        def get(c: Config) -> float:
            channel = first_channel(c)
            return default if channel is None else read(channel)

        return get

    def set_action(raw: RawConfig, value: float) -> None:
        failsafe = raw["servos"][index]["failsafe"]
        failsafe["action"] = FAILSAFE_ACTIONS[int(value)]

    def failsafe_position(c: Config) -> float:
        position = servo_of(c).failsafe.position_deg
        return servo_of(c).neutral_deg if position is None else position

    # TRIM, REV and SLEW act on the servo's channels: a servo no channel drives (a gimbal
    # axis) has none, and a parameter every set of which is refused is not listed at all
    driven = any(ch.servo == servo for ch in config.channels)
    on_channels = {prefix + "TRIM", prefix + "REV", prefix + "SLEW"}
    table = [
        Parameter(
            prefix + "TRIM",
            "servo",
            "deg",
            -_ANGLE_SPAN,
            _ANGLE_SPAN,
            f"{servo}: angle added to the centre the input trim maps to (all its channels)",
            channel_value(lambda ch: ch.trim_deg, 0.0),
            set_channels("trim_deg", float),
        ),
        Parameter(
            prefix + "MIN",
            "servo",
            "deg",
            span[0],
            span[1],
            f"{servo}: soft lower limit; no command goes below it",
            lambda c: servo_of(c).limits_deg[0],
            set_limit(0),
            range_note=ENVELOPE_NOTE,
        ),
        Parameter(
            prefix + "MAX",
            "servo",
            "deg",
            span[0],
            span[1],
            f"{servo}: soft upper limit; no command goes above it",
            lambda c: servo_of(c).limits_deg[1],
            set_limit(1),
            range_note=ENVELOPE_NOTE,
        ),
        Parameter(
            prefix + "REV",
            "servo",
            "",
            0,
            1,
            f"{servo}: 1 reverses the input's sense (every channel of the servo)",
            channel_value(lambda ch: float(ch.reverse), 0.0),
            set_channels("reverse", lambda v: bool(int(v))),
            values={0: "normal", 1: "reversed"},
            integral=True,
        ),
        Parameter(
            prefix + "SLEW",
            "servo",
            "deg/s",
            0,
            _ANGLE_SPAN,
            f"{servo}: fastest change of the commanded angle; 0 = no limit",
            channel_value(
                lambda ch: NO_SLEW_LIMIT if ch.max_slew_dps is None else ch.max_slew_dps,
                NO_SLEW_LIMIT,
            ),
            set_channels("max_slew_dps", lambda v: None if v == NO_SLEW_LIMIT else float(v)),
        ),
        Parameter(
            prefix + "FS_ACT",
            "servo",
            "",
            0,
            len(FAILSAFE_ACTIONS) - 1,
            f"{servo}: failsafe action when the autopilot link is lost",
            lambda c: float(FAILSAFE_ACTIONS.index(servo_of(c).failsafe.action)),
            set_action,
            values=dict(enumerate(FAILSAFE_ACTIONS)),
            integral=True,
        ),
        Parameter(
            prefix + "FS_POS",
            "servo",
            "deg",
            span[0],
            span[1],
            f"{servo}: angle of failsafe action 'position' (unset reads as the neutral angle)",
            failsafe_position,
            set_servo(("failsafe", "position_deg")),
            range_note=ENVELOPE_NOTE,
        ),
        Parameter(
            prefix + "FS_TMO",
            "servo",
            "s",
            0.01,
            3600,
            f"{servo}: wait after the link is lost before the failsafe action",
            lambda c: servo_of(c).failsafe.timeout_s,
            set_servo(("failsafe", "timeout_s")),
        ),
    ]
    return table if driven else [p for p in table if p.name not in on_channels]


# ----------------------------------------------------------------------------------- gimbals

_AXES = (("roll", "ROL"), ("pitch", "PIT"), ("yaw", "YAW"))


def _gimbal_parameters(
    number: int, gimbal: str, spans: Mapping[str, tuple[float, float]]
) -> list[Parameter]:
    index = number - 1
    table = []
    for axis, short in _AXES:
        low, high = spans.get(axis, (-_ANGLE_SPAN, _ANGLE_SPAN))
        for side, word in ((0, "MIN"), (1, "MAX")):
            table.append(
                Parameter(
                    f"GMB{number}_{short}_{word}",
                    gimbal,
                    "deg",
                    low,
                    high,
                    f"gimbal {gimbal}: {axis} {'lower' if side == 0 else 'upper'} limit "
                    "(unset reads as the axis servo's limit)",
                    _gimbal_limit_reader(index, axis, side),
                    _gimbal_limit_writer(index, axis, side),
                    range_note=ENVELOPE_NOTE,
                )
            )
    return table


def _gimbal_limit_reader(index: int, axis: str, side: int) -> Callable[[Config], float]:
    def read(c: Config) -> float:
        gimbal = c.gimbals[index]
        limits = getattr(gimbal.limits_deg, axis)
        if limits is None:
            servo = getattr(gimbal, axis)
            limits = c.servo(servo).limits_deg if servo is not None else (-180.0, 180.0)
        return float(limits[side])

    return read


def _gimbal_limit_writer(index: int, axis: str, side: int) -> Callable[[RawConfig, float], None]:
    def write(raw: RawConfig, value: float) -> None:
        gimbal = raw["gimbals"][index]
        limits = gimbal["limits_deg"][axis]
        if limits is None:
            servo_name = gimbal[axis]
            servo = next((s for s in raw["servos"] if s["name"] == servo_name), None)
            limits = servo["limits_deg"] if servo is not None else (-180.0, 180.0)
        pair = list(limits)
        pair[side] = float(value)
        gimbal["limits_deg"][axis] = tuple(pair)

    return write


# --------------------------------------------------------------------------------- telemetry

_RATES = (
    ("TEL_AOS_HZ", "actuator_output_status_hz", "ACTUATOR_OUTPUT_STATUS (measured positions)"),
    ("TEL_ESC_HZ", "esc_telemetry_hz", "ESC_TELEMETRY_x_TO_y (temperature, current, speed)"),
    ("TEL_NVF_HZ", "named_value_float_hz", "NAMED_VALUE_FLOAT per-servo values"),
    ("TEL_GAS_HZ", "gimbal_attitude_status_hz", "GIMBAL_DEVICE_ATTITUDE_STATUS"),
)


#: Rates of messages only a gimbal sends: listed only when the config has one (a ground station
#: showed TEL_GAS_HZ, the gimbal attitude rate, for a bridge without a gimbal: issue 37).
_GIMBAL_RATES = frozenset({"TEL_GAS_HZ"})


def _telemetry_parameters(*, gimbals: bool) -> list[Parameter]:
    table = []
    for name, key, what in _RATES:
        if name in _GIMBAL_RATES and not gimbals:
            continue
        table.append(
            Parameter(
                name,
                "servo",
                "Hz",
                0,
                100,
                f"rate of {what} on the autopilot link; 0 = off",
                _rate_reader(key),
                _rate_writer(key),
            )
        )
    return table


def _rate_reader(key: str) -> Callable[[Config], float]:
    return lambda c: float(getattr(c.mavlink.telemetry, key))


def _rate_writer(key: str) -> Callable[[RawConfig, float], None]:
    def write(raw: RawConfig, value: float) -> None:
        raw["mavlink"]["telemetry"][key] = float(value)

    return write


def telemetry_rate_keys() -> dict[str, str]:
    """Parameter name -> ``mavlink.telemetry`` key, for applying a rate change live."""
    return {name: key for name, key, _ in _RATES}
