"""Who hears what the scheduler's threads do: its observer and its state subscribers.

Its own part because every call out of a loop follows one rule: an observer or subscriber that
raises is logged and forgotten, never allowed to stop the command loop or the receive loop; and
the optional write capability (:class:`WriteObserver`) is resolved once, when the scheduler is
built, not asked for every frame. The scheduler's two threads call :class:`ObserverFanout`; the
Protocols below are the boundary other layers implement (the run log, the bridge's fan-out).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

import can

from mavservo.servos import ServoState

from .schedule_core import FrameKind

# The scheduler's lines all go to the runner's logger: the console and the recovery filter
# (app/run.py RECOVERY_LOGGERS) know the scheduler by that name.
log = logging.getLogger("mavservo.scheduling.runner")

StateCallback = Callable[[str, ServoState], None]


class SchedulerObserver(Protocol):
    """Hooks called from the scheduler's threads (the scheduler's observer boundary).

    A Protocol: the run log implements it structurally; a class that subclasses it explicitly
    inherits a no-op for every hook it does not override. Implementations MUST be non-blocking
    (append to a queue, bump a counter): they run inside the command loop and the receive loop,
    so a slow observer would delay commands. Exceptions are logged and swallowed; they never
    stop the loop. ``bus`` is the scheduler's name.
    """

    def on_setpoint(self, servo: str, seq: int, angle_deg: float, source: str, t: float) -> None:
        """A setpoint was accepted into the scheduler."""
        return None

    def on_tx(
        self,
        bus: str,
        msg: can.Message,
        t: float,
        kind: FrameKind,
        servo: str,
        seq: int | None,
    ) -> None:
        """``bus.send`` returned for ``msg``; ``t`` is the monotonic time just after the write."""
        return None

    def on_rx(
        self, bus: str, msg: can.Message, t: float, servo: str, state: ServoState | None
    ) -> None:
        """A reply from ``servo`` was decoded into ``state``; None for a frame that starts or
        continues a multi-frame report (a DroneCAN Status), which is whole at its last frame."""
        return None

    def on_lost(self, bus: str, servo: str, t: float) -> None:
        """A reply ``servo`` owed us did not arrive within ``reply_timeout_s``."""
        return None

    def on_reject(self, bus: str, reason: str, raw_bytes: bytes, t: float) -> None:
        """The bus's frame decoder rejected bytes (forwarded through ``report_reject``)."""
        return None


@runtime_checkable
class WriteObserver(Protocol):
    """An observer that also wants to know when a servo's frames are all on the wire: a
    capability of a :class:`SchedulerObserver`, checked with isinstance once, when the
    scheduler is built (an observer without it is not called)."""

    def on_written(self, bus: str, t: float, kind: FrameKind, servo: str, seq: int | None) -> None:
        """Every frame carrying ``servo``'s ``kind`` frame (its ``seq``) is on the wire, the last
        of them written at ``t``: called once per servo per write, after the frames' ``on_tx``.
        A packed transfer (DroneCAN's ArrayCommand: 8 servos' commands in 5 frames) has fewer
        frames than commands, so ``on_tx`` cannot say which commands it wrote; this does, for
        every family alike."""
        ...


@runtime_checkable
class RejectReporting(Protocol):
    """A bus that reports the bytes its frame decoder rejected (the aa55 bus): ``on_reject``
    is called with ``(reason, raw_bytes)``; None until someone listens."""

    on_reject: Callable[[Any, bytes], None] | None


class _NoObserver(SchedulerObserver):
    """The observer of a scheduler nobody observes: every hook a no-op."""


class ObserverFanout:
    """The scheduler's observer (None: nobody) and its state subscribers, called safely.

    Every method may be called from either of the scheduler's threads; none raises what an
    observer or subscriber raised. ``writes`` tells whether the observer has the
    :class:`WriteObserver` capability, so a write with nobody to tell costs no loop.
    """

    def __init__(self, observer: SchedulerObserver | None) -> None:
        self._observer: SchedulerObserver = observer or _NoObserver()
        self._on_written = observer.on_written if isinstance(observer, WriteObserver) else None
        self.writes = self._on_written is not None
        self._subscribers: list[StateCallback] = []
        self._lock = threading.Lock()

    def setpoint(self, servo: str, seq: int, angle_deg: float, source: str, t: float) -> None:
        try:
            self._observer.on_setpoint(servo, seq, angle_deg, source, t)
        except Exception:  # an observer must never stop the loop
            log.exception("scheduler observer on_setpoint failed")

    def tx(
        self, bus: str, msg: can.Message, t: float, kind: FrameKind, servo: str, seq: int | None
    ) -> None:
        try:
            self._observer.on_tx(bus, msg, t, kind, servo, seq)
        except Exception:
            log.exception("scheduler observer on_tx failed")

    def written(self, bus: str, t: float, kind: FrameKind, servo: str, seq: int | None) -> None:
        if self._on_written is None:
            return
        try:
            self._on_written(bus, t, kind, servo, seq)
        except Exception:
            log.exception("scheduler observer on_written failed")

    def rx(
        self, bus: str, msg: can.Message, t: float, servo: str, state: ServoState | None
    ) -> None:
        try:
            self._observer.on_rx(bus, msg, t, servo, state)
        except Exception:
            log.exception("scheduler observer on_rx failed")

    def lost(self, bus: str, servo: str, t: float) -> None:
        try:
            self._observer.on_lost(bus, servo, t)
        except Exception:
            log.exception("scheduler observer on_lost failed")

    def reject(self, bus: str, reason: str, raw_bytes: bytes, t: float) -> None:
        try:
            self._observer.on_reject(bus, reason, raw_bytes, t)
        except Exception:
            log.exception("scheduler observer on_reject failed")

    def subscribe(self, callback: StateCallback) -> Callable[[], None]:
        """Call ``callback(servo, state)`` on every :meth:`state`; returns an unsubscribe."""
        with self._lock:
            self._subscribers.append(callback)

        def unsubscribe() -> None:
            with self._lock:
                if callback in self._subscribers:
                    self._subscribers.remove(callback)

        return unsubscribe

    def state(self, servo: str, state: ServoState) -> None:
        """Tell every subscriber ``servo``'s new ``state`` (a reply, or it went offline)."""
        with self._lock:
            subscribers = list(self._subscribers)
        for callback in subscribers:
            try:
                callback(servo, state)
            except Exception:
                log.exception("scheduler subscriber failed for %s", servo)
