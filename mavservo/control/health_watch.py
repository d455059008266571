"""Every servo's health judgement (:class:`~mavservo.control.health.ServoHealth`) fed from the
backend's statuses, for the bridge: which states are new, the transitions they cause, the
episode counts and the summary the run records keep (docs/health.md).

The bridge's tick thread updates it every command period; any thread may read a servo's flags
(the telemetry and the gimbal do, through the backend's statuses) or the summary.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable, Iterable

from mavservo.control.health import (
    CHECKS,
    HealthEvent,
    HealthLimits,
    Sample,
    ServoHealth,
    TemperatureAction,
    check_name,
)
from mavservo.mavlink import NO_HEALTH_PROBLEM, Health, ServoStatus


class HealthWatch:
    """Every servo's :class:`ServoHealth`, fed from the backend's statuses (the bridge calls
    :meth:`update` every command period; a state is judged once, when it is new)."""

    def __init__(
        self, limits: dict[str, HealthLimits], clock: Callable[[], float] | None = None
    ) -> None:
        """``clock``: the clock the states are stamped with (the bridge: ``time.monotonic``);
        with it each servo's commanded trajectory is recorded every update, stamped when it
        was in force (:meth:`ServoHealth.command`), and the states are judged against it.
        None (tests with states from a made-up clock): the setpoints seen with the states."""
        self.servos = {name: ServoHealth(name, lim) for name, lim in limits.items()}
        self._clock = clock
        self.events: deque[HealthEvent] = deque(maxlen=1000)
        self.counts: dict[str, dict[str, int]] = {}
        #: the bridge's tick thread updates, any thread may ask for the summary
        self._lock = threading.Lock()

    def reconfigure(self, limits: dict[str, HealthLimits]) -> None:
        """New thresholds (a ground station changed a speed limit or a slew): in force from the
        next state; episodes and their timers carry on."""
        with self._lock:
            for name, lim in limits.items():
                if name in self.servos:
                    self.servos[name].set_limits(lim)

    def flags(self, servo: str) -> Health:
        health = self.servos.get(servo)
        return NO_HEALTH_PROBLEM if health is None else health.active

    def update(self, statuses: Iterable[ServoStatus]) -> list[HealthEvent]:
        with self._lock:
            return self._update(statuses)

    def _update(self, statuses: Iterable[ServoStatus]) -> list[HealthEvent]:
        events: list[HealthEvent] = []
        now = None if self._clock is None else self._clock()
        for status in statuses:
            health = self.servos.get(status.name)
            if health is None:
                continue
            if now is not None:
                health.command(now, status.setpoint_deg)
            state = status.state
            if not status.online or state is None:
                health.offline()
                continue
            events += health.update(
                Sample(
                    t=state.timestamp,
                    setpoint_deg=status.setpoint_deg,
                    position_deg=state.position_deg,
                    velocity_dps=state.velocity_dps,
                    current_a=state.current_a,
                    temperature_c=state.temperature_c,
                    voltage_v=state.voltage_v,
                )
            )
        for event in events:
            self.events.append(event)
            if event.active:
                per_servo = self.counts.setdefault(event.servo, {})
                per_servo[event.name] = per_servo.get(event.name, 0) + 1
        return events

    def temperature_action(self, servo: str) -> TemperatureAction | None:
        """The action in force for ``servo`` (None: none, or only ``warn``)."""
        health = self.servos.get(servo)
        if health is None or Health.OVERHEATED not in health.active:
            return None
        action = health.limits.temperature_action
        return None if action == "warn" else action

    def summary(self) -> dict[str, object]:
        """For the end-of-run summary and metrics.json: episodes per servo and check, what is
        active now, and the last events (newest last)."""
        with self._lock:
            return self._summary()

    def _summary(self) -> dict[str, object]:
        return {
            "judged": {name: h.judged for name, h in self.servos.items()},
            "episodes": {servo: dict(checks) for servo, checks in self.counts.items()},
            "active": {
                name: [check_name(c) for c in CHECKS if c in h.active]
                for name, h in self.servos.items()
                if h.active
            },
            "events": [
                {
                    "t": e.t,
                    "servo": e.servo,
                    "check": e.name,
                    "active": e.active,
                    "text": e.text,
                    "announced": e.announce,
                }
                for e in list(self.events)[-50:]
            ],
        }
