"""The typed views the other layers run on, built from a validated :class:`Config` only.

The config is parsed once: the loader (or a PARAM_SET's :func:`~mavservo.config.parameters.
with_values`) validates the YAML into :class:`Config`, whose models keep what they validated
(a servo's typed options, a bus's node options); the functions here turn that into what the
MAVLink side and the schedulers are given. None of them reads a mapping or has a default of
its own, so a key added to the schema has one place to reach the layer that uses it.
"""

from __future__ import annotations

from mavservo.config.schema import BusConfig, Config, MavlinkConfig, TelemetryConfig
from mavservo.mavlink import (
    GimbalSettings,
    MavlinkSettings,
    SigningSettings,
    StreamRequestSettings,
    TelemetryRates,
)
from mavservo.scheduling import ServoSpec, TimingConfig


def telemetry_rates(section: TelemetryConfig) -> TelemetryRates:
    """The MAVLink side's telemetry rates of the ``mavlink.telemetry`` section."""
    return TelemetryRates(
        actuator_output_status_hz=section.actuator_output_status_hz,
        esc_telemetry_hz=section.esc_telemetry_hz,
        named_value_float_hz=section.named_value_float_hz,
        gimbal_attitude_status_hz=section.gimbal_attitude_status_hz,
        esc_first_index=section.esc_first_index,
        name_prefix=section.name_prefix,
    )


def signing_settings(section: MavlinkConfig) -> SigningSettings | None:
    """The signing secret and rules, or None: unsigned. Reads a ``key_file`` (already checked by
    the schema) again, so a rotated key is picked up at the next start."""
    signing = section.signing
    if signing is None:
        return None
    return SigningSettings(
        key=signing.secret_key(),
        accept_unsigned=signing.accept_unsigned,
        max_clock_ahead_s=signing.max_clock_ahead_s,
    )


def mavlink_settings(config: Config) -> MavlinkSettings:
    """Everything the MAVLink side is told: the ``mavlink:`` section, the PWM trims of the
    mapped servo output channels (DO_REPEAT_SERVO returns to them) and the scheduler's command
    period (the fastest a setpoint reaches a servo, and the default stream request rate)."""
    section = config.mavlink
    mirror = section.mirror
    period = config.scheduler.command_period_s
    mirrored = tuple(
        name
        for name, on in (
            ("SERVO_OUTPUT_RAW", mirror.servo_output_raw),
            ("ACTUATOR_OUTPUT_STATUS", mirror.actuator_output_status),
        )
        if on
    )
    streams = section.request_streams
    return MavlinkSettings(
        url=section.url,
        baud=section.baud,
        system_id=section.system_id,
        autopilot_system=section.autopilot.system,
        autopilot_component=section.autopilot.component,
        autopilot_flavour=section.autopilot.flavour,
        autopilot_link=section.autopilot.link,
        heartbeat_timeout_s=section.heartbeat_timeout_s,
        signing=signing_settings(section),
        allowed_sources=frozenset((s.system, s.component) for s in section.allowed_sources),
        parameter_writers=section.parameter_writers,
        act_on_autopilot_commands=section.act_on_autopilot_commands,
        repeat_servo_cycle=section.repeat_servo_cycle,
        command_hold_s=section.command_hold_s,
        mirror_servo_output_raw=mirror.servo_output_raw,
        mirror_actuator_output_status=mirror.actuator_output_status,
        actuator_output_status_units=mirror.actuator_output_status_units,
        servo_output_port_width=section.servo_output_port_width,
        telemetry=telemetry_rates(section.telemetry),
        servo_component_id=section.servo_component_id,
        channel_trims_us={
            c.channel: c.input.resolved_trim for c in config.channels if c.source == "servo_output"
        },
        command_period_s=period,
        monitor_outputs=tuple(section.monitor_outputs),
        link_budget_bytes_s=section.link_budget_bytes_s,
        stream_request=StreamRequestSettings.for_mirror(
            mirrored,
            period,
            enabled=streams.enabled,
            rate_hz=streams.rate_hz,
            min_rate_hz=streams.min_rate_hz,
            gimbals=bool(config.gimbals),
        ),
    )


def servo_specs(config: Config, bus_name: str) -> list[ServoSpec]:
    """What the scheduler of ``bus_name`` is told about each of its servos: the profile built from
    the options the schema validated (:meth:`~mavservo.config.schema.ServoConfig.make_profile`)."""
    return [
        ServoSpec(
            name=s.name,
            profile=s.make_profile(),
            command_mode=s.command_mode,
            telemetry_hz=s.telemetry_hz,
            max_speed_dps=s.max_speed_dps,
        )
        for s in config.servos
        if config.bus_of(s).name == bus_name
    ]


def timing_config(config: Config, bus: BusConfig) -> TimingConfig:
    """The scheduler settings of the config, with ``bus``'s bitrate and load budget."""
    sched = config.scheduler
    return TimingConfig(
        command_period_s=sched.command_period_s,
        telemetry_period_s=sched.telemetry_period_s,
        refresh_interval_s=sched.refresh_interval_s,
        immediate_min_spacing_s=sched.immediate_min_spacing_s,
        reply_timeout_s=sched.reply_timeout_s,
        max_load=bus.max_load,
        bitrate=bus.bitrate,
        realtime=sched.realtime,
    )


def gimbal_settings(config: Config) -> list[GimbalSettings]:
    """The MAVLink gimbal devices' settings, in ``gimbals:`` order: an axis without gimbal
    limits takes its servo's ``limits_deg``; the status rate is ``mavlink.telemetry``'s
    ``gimbal_attitude_status_hz``; the system id the fixed ``mavlink.system_id`` (None when it
    follows the autopilot)."""
    servo_limits = {s.name: s.limits_deg for s in config.servos}
    fixed_sysid = None if config.mavlink.system_id == "follow" else config.mavlink.system_id
    settings = []
    for gimbal in config.gimbals:
        axis_servos = gimbal.axes()
        own = {
            "roll": gimbal.limits_deg.roll,
            "pitch": gimbal.limits_deg.pitch,
            "yaw": gimbal.limits_deg.yaw,
        }
        limits = {
            axis: own[axis] or servo_limits.get(servo, (-180.0, 180.0))
            for axis, servo in axis_servos.items()
        }
        settings.append(
            GimbalSettings(
                name=gimbal.name,
                axis_servos=axis_servos,
                limits_deg=limits,
                component_id=gimbal.component_id,
                act_as_manager=gimbal.act_as_manager,
                vendor_name=gimbal.vendor_name,
                model_name=gimbal.model_name,
                status_rate_hz=config.mavlink.telemetry.gimbal_attitude_status_hz,
                retract_pose_deg=gimbal.retract_pose_deg,
                neutral_pose_deg=gimbal.neutral_pose_deg,
                system_id=fixed_sysid,
            )
        )
    return settings
