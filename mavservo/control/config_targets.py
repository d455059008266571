"""Where a PARAM_SET takes effect while the bridge runs: the views of a rebuilt config, in force.

:class:`ConfigTargets` is the :class:`~mavservo.control.live_parameters.ConfigTarget` of a running
bridge. It takes a config the parameter owner has validated and puts each part in force where it
lives: the channel mapping (reverse, trim, limits, slew) and failsafe settings in the servo
backend, the speed and slew allowances in the health watch, each gimbal's limits and status
rate in its device, the telemetry rates in the MAVLink core (which re-plans its link budget).

Why a part of its own: these are the running bridge's pieces, the owner's job is the parameter
(its value, its validation, the overlay). Kept apart, the owner is tested with a recording
target and this with the real pieces, and the application layer only wires them.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

from mavservo.config import Config, gimbal_settings, telemetry_rates
from mavservo.control.health_thresholds import health_limits
from mavservo.control.health_watch import HealthWatch
from mavservo.control.servo_backend import ServoBackend
from mavservo.mavlink import GimbalDevice, TelemetryRates


class TelemetryTuning(Protocol):
    """Where new telemetry rates take effect: the MAVLink core (``MavlinkCore``)."""

    def set_telemetry_rates(self, rates: TelemetryRates, now: float) -> None: ...


class ConfigTargets:
    """The running pieces a validated config is applied to, each with its own view of it.

    ``telemetry`` is the MAVLink core, known only once the MAVLink side that serves the
    parameters is built (:meth:`attach_telemetry`); until then rates are not applied (no
    PARAM_SET can arrive before the side starts).
    """

    def __init__(
        self,
        backend: ServoBackend,
        *,
        health: HealthWatch | None,
        gimbals: Sequence[GimbalDevice],
    ) -> None:
        self._backend = backend
        self._health = health
        self._gimbals = tuple(gimbals)
        self._telemetry: TelemetryTuning | None = None

    def attach_telemetry(self, telemetry: TelemetryTuning) -> None:
        self._telemetry = telemetry

    def apply(self, config: Config, now: float) -> None:
        """``config``'s mapping, health allowances, gimbal limits and telemetry rates, in
        force at once (called by the MAVLink thread, under the MAVLink side's lock)."""
        self._backend.reconfigure(config, now)
        if self._health is not None:  # speed limits and slews are in the tracking allowance
            self._health.reconfigure(health_limits(config))
        for device, settings in zip(self._gimbals, gimbal_settings(config), strict=True):
            device.settings = settings
        if self._telemetry is not None:
            self._telemetry.set_telemetry_rates(telemetry_rates(config.mavlink.telemetry), now)
