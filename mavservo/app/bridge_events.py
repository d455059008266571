"""What the bridge says: one line for the console, the kept event list, and STATUSTEXT.

Why a part of its own: every piece the bridge wires (buses, schedulers, the servo backend, the
health watch, the overlay saver, the run log) reports through the same three outlets, and the
list must stay bounded however long a run lasts. Kept apart from the bridge, the outlets are one
small object every piece is handed, instead of callbacks into the whole bridge.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Protocol

log = logging.getLogger(__name__)

EVENTS_KEPT = 1000
"""Events kept in :attr:`BridgeEvents.events` (the newest): every health transition and servo
event is one, and a servo whose readings flicker across a threshold (or lie) makes them for as
long as the run lasts."""
MAV_SEVERITY_CRITICAL = 2
MAV_SEVERITY_ERROR = 3
MAV_SEVERITY_WARNING = 4
MAV_SEVERITY_NOTICE = 5
SAID_BY_THE_MAVLINK_SIDE = ("failsafe: ", "failsafe cleared: ")
"""Events of the servo side whose STATUSTEXT the MAVLink side sends itself: the link's
failsafe, entered and left there (``mavservo.mavlink.failsafe``, one text per transition).
They go to the console and the event list only, so a ground station gets one text per
event, not two (issue 37)."""


class Announcer(Protocol):
    """Where a STATUSTEXT goes: the MAVLink side (``MavlinkSide.announce``)."""

    def announce(self, text: str, severity: int) -> None: ...


class BridgeEvents:
    """The console (``status``), the event list (``events``: (monotonic s, text)) and, once the
    MAVLink side is built (:attr:`announcer`), STATUSTEXT to the autopilot and ground station."""

    def __init__(
        self,
        status: Callable[[str], None],
        *,
        clock: Callable[[], float] = time.monotonic,
        kept: int = EVENTS_KEPT,
    ) -> None:
        self._status = status
        self._clock = clock
        self._kept = kept
        self.events: list[tuple[float, str]] = []
        self.announcer: Announcer | None = None

    def note(self, text: str) -> None:
        """Console and event list only (the MAVLink side announces its own link events)."""
        self.events.append((self._clock(), text))
        if len(self.events) > 2 * self._kept:  # trimmed in place: readers may be iterating
            del self.events[: -self._kept]
        self._status(text)

    def event(self, text: str) -> None:
        """An event of the servo side: console, event list, and a WARNING STATUSTEXT (but
        for :data:`SAID_BY_THE_MAVLINK_SIDE`)."""
        self.note(text)
        if not text.startswith(SAID_BY_THE_MAVLINK_SIDE):
            self.announce(text, MAV_SEVERITY_WARNING)

    def announce(self, text: str, severity: int) -> None:
        """STATUSTEXT only; a MAVLink side that fails to take it is logged, never raised into
        the piece that reported (a scheduler thread, the tick, shutdown)."""
        announcer = self.announcer
        if announcer is None:
            return
        try:
            announcer.announce(text, severity)
        except Exception as exc:  # noqa: BLE001 - the reporter must go on
            log.warning("STATUSTEXT not queued: %s", exc)

    def recent(self, count: int) -> list[str]:
        """The newest ``count`` event texts (the summary's)."""
        return [text for _, text in self.events[-count:]]
