"""The bridge's parameters while it runs: validated changes, applied at once, kept in the overlay.

:class:`LiveParameters` is the :class:`~mavservo.mavlink.params.ParameterStore` the MAVLink
parameter protocol talks to. A PARAM_SET becomes a whole new config, validated by the same rules
as the YAML (:func:`mavservo.config.parameters.with_values`); only a config that passes is
applied (through the ``apply`` callback: the backend's mapping, the gimbals' limits, telemetry
rates) and written to the overlay file next to the config, so the value survives a restart. A
refused value changes nothing and the reason goes back to the ground station.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Mapping
from pathlib import Path

from mavservo.config.overlay import write_overlay
from mavservo.config.parameters import (
    ParameterError,
    current_values,
    parameter_table,
    with_values,
)
from mavservo.config.schema import Config
from mavservo.mavlink.params import SetResult

log = logging.getLogger(__name__)


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
        overlay_file: Path | None,
        config_name: str,
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
        self._overlay_file = overlay_file
        self._config_name = config_name
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
            try:
                updated = with_values(self.config, {name: value}, envelope=self._base)
            except ParameterError as exc:
                return SetResult(False, old, str(exc))
            self._apply(updated)
            self.config = updated
            self._values = current_values(updated)
            self._remember(name, self._values[name])
            saved = self._save()
            return SetResult(True, self._values[name], "" if saved else "not saved")

    def _remember(self, name: str, value: float) -> None:
        if value == self._base_values.get(name):
            self.overlay.pop(name, None)
        else:
            self.overlay[name] = value

    def _save(self) -> bool:
        """Write the overlay; a failure (read-only or full disk) is logged, not fatal: the value
        is in force until the bridge stops, and the log says it will not survive a restart."""
        if self._overlay_file is None:
            return True
        try:
            if self.overlay or self._overlay_file.exists():
                write_overlay(self._overlay_file, self.overlay, self._config_name)
        except OSError as exc:
            log.error(
                "parameters: cannot write %s (%s); the new value is in force but will not "
                "survive a restart",
                self._overlay_file,
                exc,
            )
            return False
        return True
