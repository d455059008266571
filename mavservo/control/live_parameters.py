"""The bridge's parameters while it runs: the owner of every PARAM_SET.

:class:`LiveParameters` is the :class:`~mavservo.mavlink.params.ParameterOwner` the MAVLink
parameter protocol hands a request to (a name the component serves, a value decoded from the
wire, a sender allowed to write, within its rate: all checked on the MAVLink side). The owner
takes it in one walk down the layers: one validated rebuild of the config
(:func:`mavservo.config.parameters.with_values`: the same rules as the YAML, inside the config
file's envelope), applied where it takes effect (a :class:`ConfigTarget`, the running bridge's
:class:`~mavservo.control.config_targets.ConfigTargets`), then handed to the overlay's saver
(:class:`~mavservo.control.overlay_saver.OverlaySaver`, its own thread, at most one write a
second), so the value survives a restart. A refused value changes nothing and the reason goes
back to the ground station.

Why one owner here: the walk used to leave the owner for the application layer (a callback into
the bridge that rebuilt the views and set them) and came back down; the control layer has the
config (below it) and the servo side (its own), so nothing above it is needed.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Mapping
from typing import Protocol

from mavservo.config import (
    Config,
    ParameterError,
    current_values,
    float32,
    parameter_table,
    with_values,
)
from mavservo.control.overlay_saver import OverlaySaver
from mavservo.mavlink import SetResult


class ConfigTarget(Protocol):
    """Where a validated config takes effect (the servo mapping, health thresholds, gimbal
    limits, telemetry rates): :class:`~mavservo.control.config_targets.ConfigTargets`."""

    def apply(self, config: Config, now: float) -> None:
        """Put ``config`` in force at once (it passed every rule of the YAML)."""
        ...


class LiveParameters:
    """Names, values and validated changes of one running bridge's parameters.

    The servo component (``mavlink.servo_component_id``) serves every parameter (one place to
    tune the whole bridge); each gimbal's component also serves its own. ``base`` is the config
    file without the overlay: the envelope no value may leave, and a value set back to the
    file's value leaves the overlay, so the overlay holds only real differences.
    """

    def __init__(
        self,
        config: Config,
        *,
        base: Config,
        overlay: Mapping[str, float],
        saver: OverlaySaver | None,
        target: ConfigTarget,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._lock = threading.Lock()
        self.config = config
        self._base = base
        self._base_values = current_values(base)
        # which parameters exist and the envelope's ranges do not change with a value: one
        # table for every PARAM_SET (its readers take the config they read)
        self._table = {p.name: p for p in parameter_table(config, base)}
        self._values = self._read(config)
        self.overlay = dict(overlay)
        self._saver = saver
        self._target = target
        self._clock = clock
        names = list(self._table)
        self._names: dict[int, list[str]] = {config.mavlink.servo_component_id: names}
        for gimbal in config.gimbals:
            own = [p.name for p in self._table.values() if p.component == gimbal.name]
            self._names[gimbal.component_id] = own

    def names(self, component_id: int) -> list[str]:
        return self._names.get(component_id, [])

    def value(self, name: str) -> float:
        with self._lock:
            return self._values[name]

    def set(self, name: str, value: float, sender: tuple[int, int]) -> SetResult:
        with self._lock:
            old = self._values[name]
            value = self._as_sent(name, value, old)
            try:
                updated = with_values(
                    self.config, {name: value}, envelope=self._base, table=self._table
                )
            except ParameterError as exc:
                return SetResult(False, old, str(exc))
            self._target.apply(updated, self._clock())
            self.config = updated
            self._values = self._read(updated)
            self._remember(name, self._values[name])
            if self._saver is not None:
                self._saver.submit(self.overlay)
            return SetResult(True, self._values[name])

    def _read(self, config: Config) -> dict[str, float]:
        return {name: parameter.read(config) for name, parameter in self._table.items()}

    def _as_sent(self, name: str, value: float, old: float) -> float:
        """``value``, or the current value or the config file's when it is that one as a
        float32 (what PARAM_VALUE carried and a ground station writes back).

        Why (review3): SRV1_MAX of a servo limited to [-30.1, 30.1] reads as 30.100000381; a
        ground station writing back what it read was refused, "limits -30.1..30.1 deg of left
        leave the config file's -30.1..30.1 deg": compared in float64, it left the envelope."""
        for known in (old, self._base_values.get(name)):
            if known is not None and math.isfinite(value) and float32(value) == float32(known):
                return known
        return value

    def _remember(self, name: str, value: float) -> None:
        if value == self._base_values.get(name):
            self.overlay.pop(name, None)
        else:
            self.overlay[name] = value
