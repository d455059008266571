"""A python-can bus that survives its device going away (USB unplug) and comes back by itself.

The scheduler owns the only writer to the bus and should not have to know about cables. This
wrapper opens the real bus through a factory; when the device fails (``CanOperationError``,
``OSError``), it closes it, reports the loss once, and reopens it with exponential backoff from the
receive path, reporting the recovery. A reopen that keeps failing is a warning naming the path and
the error: at the first failure, then at most once per :data:`REOPEN_WARNING_INTERVAL_S` with the
count, so an adapter that came back under another device name (``/dev/ttyUSB1``) is noticed
without flooding the journal. While the device is gone ``send`` fails fast with
``CanOperationError`` (the scheduler counts every refused send and logs the outage once:
:class:`~mavservo.scheduling.runner.FailureRun`) and ``recv`` waits out its timeout, so no thread
ever blocks on a dead port.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import can

from mavservo.transport.counters import TransportCounters, transport_stats
from mavservo.transport.outage_words import outage_words

log = logging.getLogger(__name__)

#: At most one "reopen failed" warning per this many seconds of one outage (the first at once).
REOPEN_WARNING_INTERVAL_S = 30.0


class ResilientBus(can.BusABC, TransportCounters):
    """Wraps ``factory()`` (which opens the real bus) with reconnect-with-backoff.

    ``on_event(text)`` is called on loss and on recovery (the bridge turns it into STATUSTEXT).
    ``initial_backoff_s`` doubles per failed attempt up to ``max_backoff_s``. ``path``: what
    the factory opens, named in warnings (default: the opened bus's ``channel_info``).
    ``on_frame(msg, t)``: every frame the adapter delivers, with the monotonic time it was
    taken, before any filtering (the run log's "every frame"); called on the receiving
    thread, must not block. The inner bus is read only through python-can's documented
    ``BusABC`` attributes and the :class:`TransportCounters` and
    :class:`~mavservo.transport.outage_words.SaysItsOutages` contracts, so a foreign bus's extra
    attributes (a ``stats`` that is not a method) are never touched. The loss and return events
    are worded by the kind of the first bus opened (a USB adapter's "CAN adapter lost", the
    autopilot's CAN port's "the autopilot stopped forwarding CAN bus 1").
    """

    def __init__(
        self,
        factory: Callable[[], can.BusABC],
        *,
        name: str = "bus",
        on_event: Callable[[str], None] | None = None,
        initial_backoff_s: float = 0.1,
        max_backoff_s: float = 2.0,
        clock: Callable[[], float] = time.monotonic,
        path: str | None = None,
        on_frame: Callable[[can.Message, float], None] | None = None,
    ) -> None:
        self._factory = factory
        self.name = name
        self._on_event = on_event or (lambda text: log.warning("%s", text))
        self._initial_backoff = initial_backoff_s
        self._max_backoff = max_backoff_s
        self._clock = clock
        self._lock = threading.Lock()
        self._bus: can.BusABC | None = factory()  # the first open must work: errors surface
        #: what the factory opens (the serial device of an AA-55 adapter), named in warnings
        self.path = path or str(self._bus.channel_info or name)
        self._words = outage_words(self._bus)
        self.on_frame = on_frame
        self.failed_reopens = 0  # in the current outage
        self._reopen_warned_at: float | None = None
        self._backoff = initial_backoff_s
        self._next_attempt = 0.0
        self.disconnects = 0
        self.reconnects = 0
        self.garbled = 0
        """Frames the driver's ``recv`` raised on (not a lost device): dropped, counted."""
        self._garbled_warned_at: float | None = None
        self._retired: dict[str, Any] = {}  # counters of the buses closed so far
        self.down_since: float | None = None
        self.channel_info = f"{self._bus.channel_info or name} (auto-reconnect)"
        self._protocol = self._bus.protocol
        super().__init__(channel=self.path)

    @property
    def connected(self) -> bool:
        return self._bus is not None

    @property
    def inner(self) -> can.BusABC | None:
        """The bus currently open (None while the device is away)."""
        return self._bus

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        bus = self._bus
        if bus is None:
            raise can.CanOperationError(self._words.down_text(self.name))
        try:
            bus.send(msg, timeout)
        except (can.CanOperationError, OSError) as exc:
            if isinstance(exc, can.CanTimeoutError):
                raise
            self._lost(bus, exc)
            raise can.CanOperationError(self._words.lost_text(self.name, exc)) from exc

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        bus = self._bus
        if bus is None:
            bus = self._try_reconnect()
            if bus is None:
                wait = 0.1 if timeout is None else timeout
                time.sleep(max(0.0, min(wait, self._next_attempt - self._clock(), 0.1)))
                return None, False
        try:
            msg = bus.recv(timeout)
        except (can.CanOperationError, OSError) as exc:
            self._lost(bus, exc)
            return None, False
        except can.CanError:
            raise  # python-can's own errors keep their meaning (the scheduler counts them)
        except Exception as exc:  # noqa: BLE001 - a driver that cannot parse what it read
            self._garbled_frame(exc)
            return None, False
        tap = self.on_frame
        if msg is not None and tap is not None:
            tap(msg, self._clock())
        return msg, False

    def _garbled_frame(self, exc: Exception) -> None:
        """A frame the driver read but could not parse (python-can's slcan raises ValueError
        from ``recv`` on a line with a non-hex digit): that frame is lost, the device is not
        (the driver has consumed the line), and the receiving thread must not die of it.
        Counted; warned at the first, then at most once per interval with the count."""
        self.garbled += 1
        now = self._clock()
        warned = self._garbled_warned_at
        if warned is not None and now - warned < REOPEN_WARNING_INTERVAL_S:
            return
        self._garbled_warned_at = now
        log.warning(
            "%s: the driver could not parse a received frame (%d so far, dropped): %s: %s",
            self.name,
            self.garbled,
            type(exc).__name__,
            exc,
        )

    def _lost(self, bus: can.BusABC, exc: BaseException) -> None:
        with self._lock:
            if self._bus is not bus:
                return  # someone else already noticed
            self._bus = None
            self.disconnects += 1
            self.down_since = self._clock()
            self._backoff = self._initial_backoff
            self._next_attempt = self.down_since + self._backoff
            self.failed_reopens = 0
            self._reopen_warned_at = None
        _add_counts(self._retired, transport_stats(bus))
        try:
            bus.shutdown()
        except Exception as close_exc:  # a vanished device may fail to close
            log.debug("%s: close after loss failed: %s", self.name, close_exc)
        self._on_event(self._words.lost_text(self.name, exc))

    def _try_reconnect(self) -> can.BusABC | None:
        now = self._clock()
        with self._lock:
            if self._bus is not None:
                return self._bus
            if now < self._next_attempt:
                return None
            try:
                bus = self._factory()
            except Exception as exc:  # noqa: BLE001 - any open failure means "not back yet"
                self._backoff = min(self._backoff * 2, self._max_backoff)
                self._next_attempt = now + self._backoff
                self._reopen_failed(exc, now)
                return None
            self._bus = bus
            self.reconnects += 1
            down_for = now - (self.down_since or now)
            self.down_since = None
        self._on_event(self._words.back_text(self.name, down_for))
        return bus

    def _reopen_failed(self, exc: BaseException, now: float) -> None:
        """Count a failed reopen; warn at the first, then at most once per interval."""
        self.failed_reopens += 1
        warned = self._reopen_warned_at
        if warned is not None and now - warned < REOPEN_WARNING_INTERVAL_S:
            log.debug("%s: reopen of %s failed: %s", self.name, self.path, exc)
            return
        self._reopen_warned_at = now
        log.warning("%s", self._words.retrying_text(self.name, self.path, self.failed_reopens, exc))

    def stats(self) -> dict[str, Any]:
        """The device's counters since start-up, across reconnects (each reopened device starts
        its own from zero), plus the link's own."""
        inner = self._bus
        totals = _add_counts({}, self._retired)
        if inner is not None:
            _add_counts(totals, transport_stats(inner))
        return {
            **totals,
            "connected": inner is not None,
            "disconnects": self.disconnects,
            "reconnects": self.reconnects,
            "garbled": self.garbled,
        }

    def shutdown(self) -> None:
        super().shutdown()
        bus, self._bus = self._bus, None
        if bus is not None:
            bus.shutdown()


def _add_counts(total: dict[str, Any], more: dict[str, Any]) -> dict[str, Any]:
    """Add the integer counters of ``more`` into ``total`` (nested dicts too); keep the rest."""
    for key, value in more.items():
        if isinstance(value, dict):
            _add_counts(total.setdefault(key, {}), value)
        elif isinstance(value, int) and not isinstance(value, bool):
            total[key] = total.get(key, 0) + value
        else:
            total[key] = value
    return total
