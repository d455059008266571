"""The vocabulary of ``simulation.servos`` in the YAML: a simulated servo's physics and injected
faults, as plain dataclasses.

They live in the config layer (below the simulator) so that the schema can check these keys with
FILE:LINE errors when a config is loaded, without importing the simulator; the simulated servo
(:mod:`mavservo.sim.servo`) builds on them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any


def _from_mapping(cls: type, values: Mapping[str, Any] | None, what: str) -> Any:
    """Build a dataclass from a YAML mapping, naming unknown keys instead of ignoring them."""
    values = dict(values or {})
    types = {f.name: str(f.type) for f in fields(cls)}
    unknown = sorted(set(values) - set(types))
    if unknown:
        raise ValueError(f"unknown {what} option(s) {unknown}; known: {sorted(types)}")
    for name, value in values.items():
        problem = _type_problem(types[name], value)
        if problem:
            raise ValueError(f"{what} option {name!r}: {problem}, got {value!r}")
    return cls(**values)


def _type_problem(annotation: str, value: Any) -> str | None:
    """Strict like the rest of the schema: a YAML ``yes`` is not 1 deg, ``"18"`` not 18 V, and
    a number must be finite."""
    if value is None:
        return None if "None" in annotation else "expected a value, not null"
    if annotation == "bool":
        return None if isinstance(value, bool) else "expected true or false"
    if "float" in annotation:
        if isinstance(value, bool) or not isinstance(value, int | float):
            return "expected a number"
        return None if math.isfinite(value) else "expected a finite number"
    return None


@dataclass
class Physics:
    """Mechanical and thermal model of one servo (defaults: a small gimbal-class actuator)."""

    max_speed_dps: float = 720.0
    """The servo's own speed ceiling; a command's speed limit can only lower it."""
    max_accel_dps2: float = 3600.0
    position_gain: float = 20.0
    """1/s: velocity demand per degree of error near the target (smooth final approach)."""
    current_per_accel: float = 0.0005
    """A per deg/s^2: current needed to accelerate the rotor and load inertia."""
    viscous_current: float = 0.002
    """A per deg/s of speed (viscous friction)."""
    friction_current: float = 0.15
    """A of Coulomb friction while moving."""
    load_current: float = 0.0
    """A needed to hold a constant external load torque (e.g. an off-balance camera)."""
    current_noise_a: float = 0.01
    ambient_c: float = 25.0
    heating_c_per_a2s: float = 0.05
    """degC per second per A^2 of winding loss."""
    cooling_per_s: float = 0.01
    """Fraction of the excess over ambient shed per second."""
    over_current_a: float = 10.0
    stall_current_a: float = 4.0
    """A the drive's current limit lets through while the output is blocked (a jam): what a
    position loop saturates at, below ``over_current_a`` so the servo itself reports nothing."""
    over_temperature_c: float = 80.0
    voltage_v: float = 24.0
    initial_position_deg: float = 0.0
    relax_after_s: float | None = None
    """Seconds without a command after which the servo goes limp; None: never."""
    relax_rate_dps: float = 5.0
    """Speed of the limp drift toward ``relax_rest_deg`` (gravity, spring of the cable...)."""
    relax_rest_deg: float = 0.0

    @classmethod
    def from_dict(cls, values: Mapping[str, Any] | None) -> Physics:
        return _from_mapping(cls, values, "physics")


@dataclass
class Faults:
    """Faults injected into one servo; all mutable at run time so tests can flip them."""

    drop_reply_prob: float = 0.0
    """Probability that any one reply or status push is lost."""
    reply_delay_s: float = 0.0
    """Extra delay before every reply (a slow or overloaded servo)."""
    silent: bool = False
    """Stop answering altogether (commands still move the servo: a lost TX path)."""
    over_current: bool = False
    """Report the over-current fault flag regardless of the physics."""
    over_temperature: bool = False
    """Report the over-temperature fault flag regardless of the physics."""
    jammed_at_deg: float | None = None
    """An obstruction at this angle: the output cannot pass it (it stops there, and while the
    position loop pushes against it the current rises to ``stall_current_a``); None: none."""
    slipping: bool = False
    """A slipped horn or coupling: the motor turns (velocity and current reported) but the
    output, whose angle the servo reports, stays where it is."""
    supply_v: float | None = None
    """The supply sags (or surges) to this voltage, reported instead of ``physics.voltage_v``."""

    @classmethod
    def from_dict(cls, values: Mapping[str, Any] | None) -> Faults:
        return _from_mapping(cls, values, "fault")
