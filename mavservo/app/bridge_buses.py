"""The bridge's CAN buses: each configured bus opened by the transport layer, closed at the end.

:class:`BridgeBuses` opens every bus of ``can.buses`` through
:func:`~mavservo.transport.open_bus` (a device, or the built-in simulation for ``channel: sim``,
whose adapter emulators it keeps by bus name for the tests and the doctor), taps every frame
into the run log with ``logging.can_frames: all``, routes the adapter's rejected bytes to whoever
owns the bus (the scheduler) and closes each one it opened.

Why a part of its own: the buses are opened before anything that uses them and closed after
everything, with their own state (the opened handles, the emulators); the bridge asks only for
a bus by name.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import can

from mavservo.app.startup_errors import bus_open_error
from mavservo.config import BusConfig, Config, tunnel_filter_ids, tunnel_keeps_extended
from mavservo.records import RunLog
from mavservo.sim import PtyAdapter, simulator_factory
from mavservo.transport import (
    MAVLINK_CAN,
    BusRequest,
    FrameCarrier,
    OpenedBus,
    open_bus,
    transport_stats,
)

log = logging.getLogger(__name__)


class BridgeBuses:
    """The opened buses (``buses``) and simulated adapters (``emulators``) by bus name."""

    def __init__(
        self,
        config: Config,
        *,
        on_event: Callable[[str], None],
        on_reject: Callable[[str, object, bytes], None],
        carrier: FrameCarrier | None = None,
    ) -> None:
        self._config = config
        #: the MAVLink link the ``mavlink-can`` buses speak through (the bridge's CanTunnel)
        self._carrier = carrier
        self._on_event = on_event
        self._on_reject = on_reject
        self.emulators: dict[str, PtyAdapter] = {}
        self.buses: dict[str, can.BusABC] = {}
        self._opened: list[OpenedBus] = []

    def open_all(self, runlog: RunLog | None) -> None:
        """Open every bus; one that does not open is a :class:`DeviceOpenError` naming it, its
        config key and the usual causes for its kind of device (issue 37)."""
        for index, bus_cfg in enumerate(self._config.can.buses):
            try:
                self.buses[bus_cfg.name] = self._open(bus_cfg, runlog)
            except (OSError, ValueError, can.CanError) as exc:
                raise bus_open_error(index, bus_cfg, exc) from exc

    def _open(self, bus_cfg: BusConfig, runlog: RunLog | None) -> can.BusABC:
        """The transport layer's factory opens it (a device, or its simulation for ``sim``);
        with ``logging.can_frames: all`` the run log gets every frame the adapter delivers."""
        name = bus_cfg.name
        options: dict[str, Any] = dict(bus_cfg.options)
        if bus_cfg.interface == "aa55":
            options = {
                "serial_baud": bus_cfg.serial_baud,
                "protocol": bus_cfg.protocol,
                "read_interval_s": bus_cfg.read_interval_s,
                **options,
            }
        if bus_cfg.interface == MAVLINK_CAN:  # the autopilot's own DroneCAN: dropped if unused
            options.setdefault("keep_extended", tunnel_keeps_extended(self._config, bus_cfg))
            options["forward_filter_ids"] = tunnel_filter_ids(self._config, bus_cfg)
        request = BusRequest(name, bus_cfg.interface, bus_cfg.channel, bus_cfg.bitrate, options)
        tap = None
        if runlog is not None and self._config.logging.can_frames == "all":

            def tap(msg: can.Message, t: float) -> None:
                runlog.on_bus_frame(name, msg, t)

        opened = open_bus(
            request,
            simulate=simulator_factory(self._config, self.emulators),
            on_event=self._on_event,
            on_reject=lambda reason, raw: self._on_reject(name, reason, raw),
            on_frame=tap,
            carrier=self._carrier,
        )
        self._opened.append(opened)
        return opened.bus

    def transport_stats(self, name: str) -> dict[str, Any]:
        """The transport counters of bus ``name`` for the summary (empty for a foreign bus)."""
        return transport_stats(self.buses.get(name))

    def close(self) -> None:
        """Close every bus opened (and its simulation); a failing close does not stop the
        others."""
        for opened in self._opened:
            try:
                opened.close()
            except Exception as exc:  # noqa: BLE001 - shutdown must go on
                log.warning("shutdown step failed: %s", exc)
