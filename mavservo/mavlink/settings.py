"""Settings of the MAVLink side: the typed, immutable view the MAVLink layer runs on.

The MAVLink layer sits below the config in the layers, so the view is declared here and the
config builds it, once, from its validated ``mavlink:`` section
(:func:`mavservo.config.views.mavlink_settings`); nothing here reads a mapping. The defaults are
the MAVLink side's own, for code and tests that run it without a config; the YAML schema takes
its telemetry defaults from :class:`TelemetryRates`, so they are written once.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal

from mavservo.mavlink.autopilot_flavour import ConfiguredFlavour
from mavservo.mavlink.link_carriage import LinkKind

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
    #: GIMBAL_DEVICE_SET_ATTITUDE from an autopilot that streams it (PX4: 5 Hz by default on
    #: its onboard link), asked once the autopilot is known to be one; 0: not asked
    gimbal_setpoint_hz: float = 0.0
    gimbal_setpoint_min_hz: float = 0.0

    @classmethod
    def for_mirror(
        cls,
        mirrored: tuple[str, ...],
        command_period_s: float,
        *,
        enabled: bool = True,
        rate_hz: float | None = None,
        min_rate_hz: float | None = None,
        gimbals: bool = False,
    ) -> StreamRequestSettings:
        """Every mirrored message at ``rate_hz`` (None: the scheduler's command rate,
        1 / command_period_s: a faster stream is never carried to a servo, a slower one moves
        it in steps), warning below ``min_rate_hz`` (None: MIN_RATE_FRACTION of that rate);
        with hosted ``gimbals`` the gimbal setpoints too (from an autopilot that streams them),
        at the same rates."""
        rate = 1.0 / command_period_s if rate_hz is None else rate_hz
        low = MIN_RATE_FRACTION * rate if min_rate_hz is None else min_rate_hz
        return cls(
            enabled=enabled,
            rates_hz={name: rate for name in mirrored},
            min_hz={name: low for name in mirrored},
            gimbal_setpoint_hz=rate if gimbals else 0.0,
            gimbal_setpoint_min_hz=low if gimbals else 0.0,
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
    #: "auto" (from the followed autopilot's HEARTBEAT), "ardupilot" or "px4"
    #: (:mod:`~mavservo.mavlink.autopilot_flavour`)
    autopilot_flavour: ConfiguredFlavour = "auto"
    #: what the link leads to: the autopilot's own port, or a router / the GCS directly
    #: (:mod:`~mavservo.mavlink.link_carriage`)
    autopilot_link: LinkKind = "port"
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

    def trim_us(self, channel: int) -> float:
        return float(self.channel_trims_us.get(channel, 1500.0))
