"""``servos[].health`` in the YAML: the thresholds of the bridge's own health checks.

Every key is optional: left out (or null), it takes the default that
``mavservo.control.health_thresholds`` derives from the servo's speed limit, slew, telemetry
rate and (simulated) physics, which ``mavservo check`` prints. Strict like every section:
unknown keys, YAML booleans for numbers and non-finite numbers are errors with their FILE:LINE.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, Strict, model_validator

_Float = Annotated[float, Strict()]
Positive = Annotated[_Float, Field(gt=0, le=1e6)]
NonNegative = Annotated[_Float, Field(ge=0, le=1e6)]
Celsius = Annotated[_Float, Field(ge=-60, le=250)]
Volts = Annotated[_Float, Field(gt=0, le=1000)]


class HealthConfig(BaseModel):
    """Per-servo health thresholds (``docs/health.md``: what each check means and how to tune).

    ``supply_v``: [min, max] volts; left out, the range is learned around the first readings
    (-22 % / +15 %) on hardware, and taken from the simulated supply on the built-in simulation.
    """

    model_config = ConfigDict(
        extra="forbid", frozen=True, allow_inf_nan=False, use_attribute_docstrings=True
    )

    enabled: Annotated[bool, Strict()] = True
    """Judge this servo at all (off for a servo whose feedback is known to be meaningless)."""
    tolerance_deg: Positive | None = None
    """Position error accepted at rest, deg (backlash, compliant linkage)."""
    speed_dps: Positive | None = None
    """The speed the servo really reaches, deg/s, for how long a move may take."""
    response_s: NonNegative | None = None
    """Lag of a healthy servo behind a moving setpoint, s."""
    tracking_s: NonNegative | None = None
    """How late is late once the move's own time is allowed for, s."""
    stopped_dps: Positive | None = None
    """Below this speed the servo is not moving, deg/s."""
    current_limit_a: Positive | None = None
    """The drive's current limit (what it gives at stall), A: set it on hardware."""
    jam_current_a: Positive | None = None
    """Current at or above which a servo that does not move is jammed, A."""
    jam_s: NonNegative | None = None
    """How long the jam condition must last, s."""
    slip_speed_dps: Positive | None = None
    """Reported speed above which an output that does not follow is slipping, deg/s."""
    slip_s: NonNegative | None = None
    """How long the slip condition must last, s."""
    continuous_current_a: Positive | None = None
    """The rated continuous current, A (the I^2 t overload check): set it on hardware."""
    overload_s: Positive | None = None
    """The time allowed above ``continuous_current_a`` (at twice it: a third of this), s."""
    temperature_warning_c: Celsius | None = None
    """Temperature of the ``hot`` warning, degC: below the servo's own trip."""
    temperature_limit_c: Celsius | None = None
    """Temperature of ``overheated``, degC: ``temperature_action`` applies."""
    temperature_hysteresis_c: Annotated[_Float, Field(ge=0, le=100)] | None = None
    """How far below a temperature level the servo must cool to clear it, degC."""
    temperature_action: Literal["warn", "slow", "hold", "release"] = "warn"
    """At the temperature limit: ``warn``, ``slow`` (moves at ``slow_factor`` of the speed),
    ``hold`` (new setpoints refused) or ``release`` (motor off)."""
    slow_factor: Annotated[_Float, Field(gt=0, lt=1)] = 0.5
    """The share of the speed limit left under ``temperature_action: slow``."""
    supply_v: tuple[Volts, Volts] | None = None
    """Supply voltage range [min, max], V; null: learned from the first readings (-22 % / +15
    %)."""
    supply_s: NonNegative | None = None
    """How long the supply must be out of range, s."""
    clear_s: NonNegative | None = None
    """How long a condition must be gone before it clears, s."""
    text_interval_s: NonNegative | None = None
    """Least time between two onset STATUSTEXTs of one check of one servo, s."""

    @model_validator(mode="after")
    def _ordered(self) -> HealthConfig:
        if self.supply_v is not None and not self.supply_v[0] < self.supply_v[1]:
            raise ValueError(f"supply_v must be [min, max] with min < max, got {self.supply_v}")
        warning, limit = self.temperature_warning_c, self.temperature_limit_c
        if warning is not None and limit is not None and not warning < limit:
            raise ValueError(
                f"temperature_warning_c ({warning}) must be below temperature_limit_c ({limit})"
            )
        return self
