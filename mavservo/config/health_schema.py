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

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    enabled: Annotated[bool, Strict()] = True
    tolerance_deg: Positive | None = None
    speed_dps: Positive | None = None
    response_s: NonNegative | None = None
    tracking_s: NonNegative | None = None
    stopped_dps: Positive | None = None
    current_limit_a: Positive | None = None
    jam_current_a: Positive | None = None
    jam_s: NonNegative | None = None
    slip_speed_dps: Positive | None = None
    slip_s: NonNegative | None = None
    continuous_current_a: Positive | None = None
    overload_s: Positive | None = None
    temperature_warning_c: Celsius | None = None
    temperature_limit_c: Celsius | None = None
    temperature_hysteresis_c: Annotated[_Float, Field(ge=0, le=100)] | None = None
    temperature_action: Literal["warn", "slow", "hold", "release"] = "warn"
    slow_factor: Annotated[_Float, Field(gt=0, lt=1)] = 0.5
    supply_v: tuple[Volts, Volts] | None = None
    supply_s: NonNegative | None = None
    clear_s: NonNegative | None = None
    text_interval_s: NonNegative | None = None

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
