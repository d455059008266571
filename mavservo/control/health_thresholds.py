"""Each servo's health thresholds: the YAML's ``servos[].health`` over defaults derived from
what the config says the servo can do (speed limit, slew, telemetry rate, command period) and
from its physics (on the built-in simulation, the simulated servo's; elsewhere the simulator's
defaults, a small gimbal-class actuator, which ``docs/health.md`` says to replace with the
servo's data sheet figures: ``current_limit_a``, ``continuous_current_a``, temperatures).

``describe_limits`` is what ``mavservo check`` prints, so the numbers in force are never a guess.
"""

from __future__ import annotations

from mavservo.config import Config, Physics, ServoConfig
from mavservo.control.health import HealthLimits

#: the built-in simulation: an aa55 bus on the adapter emulator
SIM_CHANNEL = "sim"
TOLERANCE_DEG = 3.0
"""Three times the coarsest position a family reports (an RMD-X status reply: whole degrees)."""
TRACKING_S = 0.5
JAM_FRACTION = 0.7
"""Jammed at 70 % of the current limit: a loop pushing against an obstacle saturates there,
a healthy move's acceleration peaks are short (``jam_s`` filters them)."""
CONTINUOUS_FRACTION = 0.5
SUPPLY_BAND = 0.15
WARNING_BELOW_TRIP_C = 15.0
LIMIT_BELOW_TRIP_C = 5.0


def is_simulated(config: Config, servo: ServoConfig) -> bool:
    """True when ``servo`` is on the built-in simulation (its physics are known exactly)."""
    bus = config.bus_of(servo)
    return bus.interface == "aa55" and bus.channel == SIM_CHANNEL


def servo_physics(config: Config, servo: ServoConfig) -> Physics:
    """The simulated servo's physics, or the simulator's defaults for a real one."""
    if not is_simulated(config, servo):
        return Physics()
    physics, _ = config.simulated_settings(servo)
    return Physics.from_dict(physics)


def servo_limits(config: Config, servo: ServoConfig) -> HealthLimits:
    """The thresholds in force for ``servo``: its ``health:`` keys over the derived defaults."""
    cfg = servo.health
    physics = servo_physics(config, servo)
    simulated = is_simulated(config, servo)
    slews = [c.max_slew_dps for c in config.channels if c.servo == servo.name and c.max_slew_dps]
    speed = min([servo.max_speed_dps, *slews] + ([physics.max_speed_dps] if simulated else []))
    if cfg.speed_dps is not None:
        speed = cfg.speed_dps
    # a healthy servo's lag: reaching speed, the loop's final approach, the age of a state
    # (two telemetry periods) and of a setpoint (two command periods)
    response = (
        speed / physics.max_accel_dps2
        + 3.0 / physics.position_gain
        + 2.0 / servo.telemetry_hz
        + 2.0 * config.scheduler.command_period_s
    )
    current_limit = cfg.current_limit_a or physics.stall_current_a
    warning = physics.over_temperature_c - WARNING_BELOW_TRIP_C
    limit = physics.over_temperature_c - LIMIT_BELOW_TRIP_C
    if cfg.temperature_warning_c is not None:
        warning = cfg.temperature_warning_c
        limit = max(limit, warning + LIMIT_BELOW_TRIP_C)
    if cfg.temperature_limit_c is not None:
        limit = cfg.temperature_limit_c
        warning = min(warning, limit - LIMIT_BELOW_TRIP_C)
    supply: tuple[float | None, float | None] = (None, None)
    if cfg.supply_v is not None:
        supply = cfg.supply_v
    elif simulated:
        nominal = physics.voltage_v
        supply = ((1 - SUPPLY_BAND) * nominal, (1 + SUPPLY_BAND) * nominal)
    defaults = HealthLimits()
    return HealthLimits(
        enabled=cfg.enabled,
        tolerance_deg=_pick(cfg.tolerance_deg, TOLERANCE_DEG),
        speed_dps=speed,
        response_s=_pick(cfg.response_s, response),
        tracking_s=_pick(cfg.tracking_s, TRACKING_S),
        stopped_dps=_pick(cfg.stopped_dps, defaults.stopped_dps),
        jam_current_a=_pick(cfg.jam_current_a, JAM_FRACTION * current_limit),
        jam_s=_pick(cfg.jam_s, defaults.jam_s),
        slip_speed_dps=_pick(cfg.slip_speed_dps, min(defaults.slip_speed_dps, 0.5 * speed)),
        slip_s=_pick(cfg.slip_s, defaults.slip_s),
        continuous_current_a=_pick(cfg.continuous_current_a, CONTINUOUS_FRACTION * current_limit),
        overload_s=_pick(cfg.overload_s, defaults.overload_s),
        temperature_warning_c=warning,
        temperature_limit_c=limit,
        temperature_hysteresis_c=_pick(
            cfg.temperature_hysteresis_c, defaults.temperature_hysteresis_c
        ),
        temperature_action=cfg.temperature_action,
        slow_factor=cfg.slow_factor,
        supply_min_v=supply[0],
        supply_max_v=supply[1],
        supply_s=_pick(cfg.supply_s, defaults.supply_s),
        clear_s=_pick(cfg.clear_s, defaults.clear_s),
        text_interval_s=_pick(cfg.text_interval_s, defaults.text_interval_s),
    )


def health_limits(config: Config) -> dict[str, HealthLimits]:
    """Every servo's thresholds, by name."""
    return {servo.name: servo_limits(config, servo) for servo in config.servos}


def describe_limits(name: str, lim: HealthLimits) -> list[str]:
    """What ``mavservo check`` prints for one servo (the thresholds in force)."""
    if not lim.enabled:
        return [f"  {name}: health checks off"]
    supply = (
        f"{lim.supply_min_v:.1f}-{lim.supply_max_v:.1f} V"
        if lim.supply_min_v is not None and lim.supply_max_v is not None
        else "learned from the first readings -22 %/+15 %"
    )
    return [
        f"  {name}: tracking > {lim.tolerance_deg:g} deg (+ setpoint motion in "
        f"{lim.response_s:.2f} s) for the move at {lim.speed_dps:g} deg/s + {lim.tracking_s:g} s",
        f"    jammed: not moving (< {lim.stopped_dps:g} deg/s) at >= {lim.jam_current_a:.1f} A "
        f"for {lim.jam_s:g} s; slipping: motor > {lim.slip_speed_dps:g} deg/s, output still, "
        f"for {lim.slip_s:g} s",
        f"    overload: I2t above {lim.continuous_current_a:.1f} A continuous, budget "
        f"{lim.overload_s:g} s; temperature: warning {lim.temperature_warning_c:g} C, limit "
        f"{lim.temperature_limit_c:g} C ({lim.temperature_action}), hysteresis "
        f"{lim.temperature_hysteresis_c:g} C",
        f"    supply: {supply} for {lim.supply_s:g} s; clears after {lim.clear_s:g} s",
    ]


def _pick(value: float | None, default: float) -> float:
    return default if value is None else value
