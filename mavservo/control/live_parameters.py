"""The bridge's parameters while it runs: validated changes, applied at once, kept in the overlay.

:class:`LiveParameters` is the :class:`~mavservo.mavlink.params.ParameterStore` the MAVLink
parameter protocol talks to. A PARAM_SET becomes a whole new config, validated by the same rules
as the YAML (:func:`mavservo.config.parameters.with_values`); only a config that passes is
applied (through the ``apply`` callback: the backend's mapping, the gimbals' limits, telemetry
rates) and handed to the overlay's saver (:class:`~mavservo.control.overlay_saver.OverlaySaver`,
its own thread, at most one write a second), so the value survives a restart. A refused value
changes nothing and the reason goes back to the ground station. The config file (without the
overlay) is the envelope: no value may take a servo past what the file allows.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Mapping

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


class LiveParameters:
    """Names, values and validated changes of one running bridge's parameters.

    ``servo_component`` serves every parameter (one place to tune the whole bridge); each gimbal
    component (``gimbal_components``: component id -> gimbal name) also serves its own.
    ``base`` is the config file without the overlay: a value set back to the file's value
    leaves the overlay, so the overlay holds only real differences.
    """

    def __init__(
        self,
        config: Config,
        *,
        base: Config,
        overlay: Mapping[str, float],
        saver: OverlaySaver | None,
        servo_component: int,
        gimbal_components: Mapping[int, str],
        apply: Callable[[Config], None],
    ) -> None:
        self._lock = threading.Lock()
        self.config = config
        self._base = base
        self._base_values = current_values(base)
        self._values = current_values(config)
        self.overlay = dict(overlay)
        self._saver = saver
        self._apply = apply
        table = parameter_table(config)
        self._names: dict[int, list[str]] = {servo_component: [p.name for p in table]}
        for component_id, gimbal in gimbal_components.items():
            self._names[component_id] = [p.name for p in table if p.component == gimbal]

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
                updated = with_values(self.config, {name: value}, envelope=self._base)
            except ParameterError as exc:
                return SetResult(False, old, str(exc))
            self._apply(updated)
            self.config = updated
            self._values = current_values(updated)
            self._remember(name, self._values[name])
            if self._saver is not None:
                self._saver.submit(self.overlay)
            return SetResult(True, self._values[name])

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
