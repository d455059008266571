"""What the scheduler tells the user about a servo it cannot hear, and where that goes.

Its own part, with its own state (which servos were already advised, which profiles can
advise), because it is the scheduler's one voice to the user besides the log: a WARNING plus
``on_event`` (the bridge turns it into a console line, an event and a STATUSTEXT), at most once
per servo and run. Users of other tools lose hours to a motor that answers in a protocol the
host does not speak; a flood of the same advice would bury it.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence

import can

from mavservo.servos import Advising

from .schedule_core import ServoSpec

log = logging.getLogger("mavservo.scheduling.runner")  # the scheduler's one logger


class ServoAdvice:
    """Advice about the servos of one bus (``name``), once per servo, and announcements.

    Thread-safe: the receive thread diagnoses unclaimed frames while the command loop names
    the likely causes of a servo that went offline without ever answering.
    """

    def __init__(self, name: str, servos: Sequence[ServoSpec]) -> None:
        self._name = name
        self.on_event: Callable[[str], None] | None = None
        """Where advice goes besides the log (the bridge: console, event list and
        STATUSTEXT); called from the scheduler's threads, must not block."""
        self._advising = {
            spec.name: spec.profile for spec in servos if isinstance(spec.profile, Advising)
        }
        """The servos whose profile can say whose an unclaimed frame is (resolved once: a
        foreign node's flood costs nothing for the others)."""
        self._advised: set[str] = set()
        self._lock = threading.Lock()

    def announce(self, text: str) -> None:
        """A WARNING and ``on_event`` (STATUSTEXT through the bridge): advice about a servo,
        the measured load over ``max_load`` (:mod:`.load_watch`, rate-limited there)."""
        log.warning("scheduler %s: %s", self._name, text)
        on_event = self.on_event
        if on_event is not None:
            try:
                on_event(text)
            except Exception:  # noqa: BLE001 - an observer must not stop the loop
                log.exception("scheduler %s: on_event failed", self._name)

    def advise(self, servo: str, text: str) -> None:
        """Say once per servo why it is not heard (a wrong protocol, host id, id...)."""
        with self._lock:
            if servo in self._advised:
                return
            self._advised.add(servo)
        self.announce(f"servo {servo}: {text}")

    def diagnose(self, msg: can.Message) -> None:
        """A frame no servo claims: ask each servo not yet advised whether it is its own in
        another form (:class:`~mavservo.servos.base.Advising`)."""
        for name, profile in self._advising.items():
            if name in self._advised:
                continue
            text = profile.diagnose(msg)
            if text is not None:
                self.advise(name, text)

    def silence_hint(self, servo: str) -> str | None:
        """The likely causes to name for ``servo`` gone offline without ever answering."""
        profile = self._advising.get(servo)
        return None if profile is None else profile.silence_hint()
