"""Settings of the MAVLink side, decoupled from the YAML schema.

The ``mavlink:`` section of the config is validated by ``mavservo/config.py``; the MAVLink layer
only needs a small, typed, immutable view of it. Keeping this view here means the MAVLink code and
its tests do not depend on the config module, and the bridge builds it with
:meth:`MavlinkSettings.from_mapping` from the validated section (a dict or a pydantic model dump).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

FOLLOW: Literal["follow"] = "follow"

#: MAV_COMP_ID_SERVO1: the component every servo group is published as by default.
DEFAULT_SERVO_COMPONENT = 140


@dataclass(frozen=True)
class SigningSettings:
    """MAVLink 2 signing: a 32-byte secret; unsigned input is refused unless ``accept_unsigned``."""

    key: bytes
    accept_unsigned: bool = False
    #: Largest accepted lead of a signed timestamp over this computer's clock (s); None: no bound.
    max_clock_ahead_s: float | None = 60.0

    @classmethod
    def from_mapping(cls, raw: Mapping[str, Any] | None) -> SigningSettings | None:
        if not raw:
            return None
        if raw.get("key"):
            key_hex = str(raw["key"])
        elif raw.get("key_file"):
            with open(raw["key_file"], encoding="ascii") as handle:
                key_hex = handle.read().strip()
        else:
            raise ValueError("signing needs 'key' or 'key_file'")
        key = bytes.fromhex(key_hex)
        if len(key) != 32:
            raise ValueError("signing key must be 64 hex characters (32 bytes)")
        return cls(key=key, accept_unsigned=bool(raw.get("accept_unsigned", False)))


@dataclass(frozen=True)
class TelemetryRates:
    """Publication rates in Hz; 0 disables a stream (SET_MESSAGE_INTERVAL can change them)."""

    actuator_output_status_hz: float = 10.0
    esc_telemetry_hz: float = 4.0
    named_value_float_hz: float = 2.0
    gimbal_attitude_status_hz: float = 10.0
    esc_first_index: int | Literal["auto"] = "auto"
    name_prefix: str = "s"


#: Default warning threshold as a fraction of the requested rate: ArduPilot's 50 Hz loop
#: delivers a 20 Hz request as 20.0 Hz on average with intervals of 30-70 ms (recorded SITL).
MIN_RATE_FRACTION = 0.75


@dataclass(frozen=True)
class StreamRequestSettings:
    """What to ask the autopilot for (:mod:`mavservo.mavlink.stream_request`): ``rates_hz`` by
    message name; a stream arriving below its ``min_hz`` is a warning.

    ``enabled`` False keeps the measurement and the warning but sends nothing (for autopilots
    that refuse or mishandle SET_MESSAGE_INTERVAL)."""

    enabled: bool = True
    rates_hz: Mapping[str, float] = field(default_factory=dict)
    min_hz: Mapping[str, float] = field(default_factory=dict)

    @classmethod
    def for_mirror(
        cls,
        raw: Mapping[str, Any] | None,
        mirrored: tuple[str, ...],
        command_period_s: float,
    ) -> StreamRequestSettings:
        """From the validated ``mavlink.request_streams`` section: every mirrored message at
        ``rate_hz`` (default: the scheduler's command rate, 1 / command_period_s: a faster
        stream is never carried to a servo, a slower one moves it in steps), warning below
        ``min_rate_hz`` (default: MIN_RATE_FRACTION of that rate)."""
        raw = raw or {}
        rate = raw.get("rate_hz")
        rate_hz = float(rate) if rate is not None else 1.0 / command_period_s
        low = raw.get("min_rate_hz")
        min_hz = float(low) if low is not None else MIN_RATE_FRACTION * rate_hz
        return cls(
            enabled=bool(raw.get("enabled", True)),
            rates_hz={name: rate_hz for name in mirrored},
            min_hz={name: min_hz for name in mirrored},
        )


@dataclass(frozen=True)
class MavlinkSettings:
    """Everything the MAVLink side needs to know, in MAVLink units.

    ``system_id`` is ``"follow"`` (take the autopilot's system id from its first HEARTBEAT) or a
    fixed int. ``servo_output_port_width`` is how many channels one SERVO_OUTPUT_RAW ``port``
    covers: 16 is what ArduPilot sends in MAVLink 2 (port 1 = servo 17..32); the spec's older
    wording says 8. ``channel_trims_us`` holds the PWM trim of each mapped servo output channel,
    which DO_REPEAT_SERVO returns to (1500 when missing).
    """

    url: str = "udpin:127.0.0.1:14551"
    baud: int = 115200
    system_id: int | Literal["follow"] = FOLLOW
    autopilot_system: int = 1
    autopilot_component: int = 1
    heartbeat_timeout_s: float = 2.0
    signing: SigningSettings | None = None
    allowed_sources: frozenset[tuple[int, int]] = frozenset()
    #: "verified" (signed senders and allowed_sources may set parameters) or "anyone"
    parameter_writers: Literal["verified", "anyone"] = "verified"
    act_on_autopilot_commands: bool = False
    repeat_servo_cycle: Literal["seconds", "milliseconds"] = "seconds"
    command_hold_s: float = 2.0
    mirror_servo_output_raw: bool = True
    mirror_actuator_output_status: bool = False
    actuator_output_status_units: Literal["pwm", "normalized"] = "pwm"
    servo_output_port_width: int = 16
    telemetry: TelemetryRates = field(default_factory=TelemetryRates)
    servo_component_id: int = DEFAULT_SERVO_COMPONENT
    channel_trims_us: Mapping[int, float] = field(default_factory=dict)
    retry_window_s: float = 2.0
    #: The scheduler's command period (scheduler.command_period_s): the fastest a new setpoint
    #: reaches a servo, hence the shortest DO_REPEAT_SERVO half cycle the bridge can carry.
    command_period_s: float = 0.05
    #: Extra endpoints that get a copy of every frame the bridge sends (``mavservo monitor``).
    monitor_outputs: tuple[str, ...] = ()
    #: Bytes/s the periodic telemetry may use on the autopilot link (None: no budget).
    link_budget_bytes_s: float | None = None
    #: SET_MESSAGE_INTERVAL requests for the mirrored streams (none unless built from a config).
    stream_request: StreamRequestSettings = field(default_factory=StreamRequestSettings)

    @classmethod
    def from_mapping(
        cls,
        raw: Mapping[str, Any],
        channel_trims_us: Mapping[int, float] | None = None,
        command_period_s: float | None = None,
    ) -> MavlinkSettings:
        """Build from the (already validated) ``mavlink:`` config section as a plain mapping."""
        autopilot = raw.get("autopilot") or {}
        mirror = raw.get("mirror") or {}
        telemetry = raw.get("telemetry") or {}
        sources = frozenset(
            (int(s["system"]), int(s["component"])) for s in raw.get("allowed_sources") or []
        )
        system_id = raw.get("system_id", FOLLOW)
        defaults = cls()
        period = defaults.command_period_s if command_period_s is None else float(command_period_s)
        mirrored = tuple(
            name
            for name, on in (
                ("SERVO_OUTPUT_RAW", mirror.get("servo_output_raw", True)),
                ("ACTUATOR_OUTPUT_STATUS", mirror.get("actuator_output_status", False)),
            )
            if on
        )
        return cls(
            url=str(raw.get("url", defaults.url)),
            baud=int(raw.get("baud", defaults.baud)),
            system_id=_system_id(system_id),
            autopilot_system=int(autopilot.get("system", 1)),
            autopilot_component=int(autopilot.get("component", 1)),
            heartbeat_timeout_s=float(raw.get("heartbeat_timeout_s", 2.0)),
            signing=SigningSettings.from_mapping(raw.get("signing")),
            allowed_sources=sources,
            parameter_writers="anyone" if raw.get("parameter_writers") == "anyone" else "verified",
            act_on_autopilot_commands=bool(raw.get("act_on_autopilot_commands", False)),
            repeat_servo_cycle=raw.get("repeat_servo_cycle", "seconds"),
            command_hold_s=float(raw.get("command_hold_s", 2.0)),
            mirror_servo_output_raw=bool(mirror.get("servo_output_raw", True)),
            mirror_actuator_output_status=bool(mirror.get("actuator_output_status", False)),
            actuator_output_status_units=mirror.get("actuator_output_status_units", "pwm"),
            servo_output_port_width=int(raw.get("servo_output_port_width", 16)),
            telemetry=_telemetry(telemetry),
            monitor_outputs=tuple(str(u) for u in raw.get("monitor_outputs") or ()),
            link_budget_bytes_s=_optional_float(raw.get("link_budget_bytes_s")),
            servo_component_id=int(raw.get("servo_component_id", DEFAULT_SERVO_COMPONENT)),
            channel_trims_us=dict(channel_trims_us or {}),
            command_period_s=period,
            stream_request=StreamRequestSettings.for_mirror(
                raw.get("request_streams"), mirrored, period
            ),
        )

    def trim_us(self, channel: int) -> float:
        return float(self.channel_trims_us.get(channel, 1500.0))


def _system_id(value: object) -> int | Literal["follow"]:
    """``"follow"`` or the fixed system id of an (already validated) ``system_id``."""
    if value == FOLLOW:
        return FOLLOW
    if isinstance(value, (int, str)):
        return int(value)
    raise TypeError(f"mavlink.system_id: expected an int or {FOLLOW!r}, got {value!r}")


def _telemetry(raw: Mapping[str, Any]) -> TelemetryRates:
    """The telemetry section: rates as floats, the ESC index and the name prefix as they are."""
    fields: dict[str, Any] = {}
    for key, value in raw.items():
        if key == "esc_first_index":
            fields[key] = value if value == "auto" else int(value)
        elif key == "name_prefix":
            fields[key] = str(value)
        else:
            fields[key] = float(value)
    return TelemetryRates(**fields)


def _optional_float(value: object) -> float | None:
    return None if value is None else float(value)  # type: ignore[arg-type]
