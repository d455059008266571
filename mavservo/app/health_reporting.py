"""The bridge's own servo health judgement, said and acted on (docs/health.md).

:class:`HealthReporter` feeds the servo statuses to the :class:`~mavservo.control.HealthWatch`
each bridge tick and turns each transition it reports into what the bridge does with it: a
console line and event, the run log's trace, a STATUSTEXT (CRITICAL for a surface that does not
do what it is told or a servo at its temperature limit, WARNING for the other onsets, NOTICE for
every clearing; once per episode, as the check's text spacing allows), and the temperature
limit's action on the servo.

Why a part of its own: the judgement is control's (pure, tested alone); what follows from it
needs the run log and the MAVLink side, which only the application has, and has state of its
own (the watch). Apart from the bridge's life cycle it is tested with a recording event list.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from mavservo.app.bridge_events import (
    MAV_SEVERITY_CRITICAL,
    MAV_SEVERITY_NOTICE,
    MAV_SEVERITY_WARNING,
    BridgeEvents,
)
from mavservo.control import HealthEvent, HealthWatch, ServoBackend
from mavservo.mavlink import Health
from mavservo.records import RunLog

#: health checks whose onset is CRITICAL (the surface does not do what it is told, or the
#: servo is at its temperature limit); the others are WARNINGs, every clearing a NOTICE
CRITICAL_HEALTH = Health.JAMMED | Health.SLIPPING | Health.OVERHEATED


class HealthReporter:
    """Judges the backend's servo statuses with ``watch`` and reports each transition."""

    def __init__(
        self,
        watch: HealthWatch,
        backend: ServoBackend,
        events: BridgeEvents,
        *,
        runlog: RunLog | None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.watch = watch
        self._backend = backend
        self._events = events
        self._runlog = runlog
        self._clock = clock

    def update(self) -> None:
        """Judge the servos' new states and say what changed (once per bridge tick)."""
        for event in self.watch.update(self._backend.servo_statuses()):
            self.report(event)

    def report(self, event: HealthEvent) -> None:
        """One health transition: the run log's trace, the temperature limit's action, and
        when it is announced the console, the event list and STATUSTEXT. The fault bit
        (``s<n>_hlt``) and a gimbal's failure flags follow from the servo's status."""
        if event.announce:
            # the console says what the ground station is told, as often (issue 37): an
            # episode inside its check's text spacing goes to the run log only, and the next
            # text counts it ("(2 more since the last report)")
            self._events.note(event.text)
        if self._runlog is not None:
            self._runlog.health_event(event.servo, event.name, event.active, event.figures, event.t)
        if event.check is Health.OVERHEATED:
            limits = self.watch.servos[event.servo].limits
            action = self.watch.temperature_action(event.servo)
            self._backend.set_health_action(
                event.servo, action, self._clock(), slow_factor=limits.slow_factor
            )
        if not event.announce:
            return
        severity = MAV_SEVERITY_NOTICE
        if event.active:
            critical = event.check & CRITICAL_HEALTH
            severity = MAV_SEVERITY_CRITICAL if critical else MAV_SEVERITY_WARNING
        self._events.announce(event.text, severity)

    def summary(self) -> dict[str, object]:
        return self.watch.summary()
