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

log = logging.getLogger(__name__)

#: At most one "reopen failed" warning per this many seconds of one outage (the first at once).
REOPEN_WARNING_INTERVAL_S = 30.0


class ResilientBus(can.BusABC):
    """Wraps ``factory()`` (which opens the real bus) with reconnect-with-backoff.

    ``on_event(text)`` is called on loss and on recovery (the bridge turns it into STATUSTEXT).
    ``initial_backoff_s`` doubles per failed attempt up to ``max_backoff_s``.
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
        self.path = _device_name(self._bus, name)
        self.failed_reopens = 0  # in the current outage
        self._reopen_warned_at: float | None = None
        self._backoff = initial_backoff_s
        self._next_attempt = 0.0
        self.disconnects = 0
        self.reconnects = 0
        self._retired: dict[str, Any] = {}  # counters of the buses closed so far
        self.down_since: float | None = None
        self.channel_info = f"{getattr(self._bus, 'channel_info', name)} (auto-reconnect)"
        self._protocol = getattr(self._bus, "protocol", can.CanProtocol.CAN_20)
        super().__init__(channel=getattr(self._bus, "channel", name))

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
            raise can.CanOperationError(f"{self.name}: device disconnected, reconnecting")
        try:
            bus.send(msg, timeout)
        except (can.CanOperationError, OSError) as exc:
            if isinstance(exc, can.CanTimeoutError):
                raise
            self._lost(bus, exc)
            raise can.CanOperationError(f"{self.name}: device lost: {exc}") from exc

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        bus = self._bus
        if bus is None:
            bus = self._try_reconnect()
            if bus is None:
                wait = 0.1 if timeout is None else timeout
                time.sleep(max(0.0, min(wait, self._next_attempt - self._clock(), 0.1)))
                return None, False
        try:
            return bus.recv(timeout), False
        except (can.CanOperationError, OSError) as exc:
            self._lost(bus, exc)
            return None, False

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
        if hasattr(bus, "stats"):
            _add_counts(self._retired, bus.stats())
        try:
            bus.shutdown()
        except Exception as close_exc:  # a vanished device may fail to close
            log.debug("%s: close after loss failed: %s", self.name, close_exc)
        self._on_event(f"{self.name}: CAN adapter lost ({exc}); reconnecting")

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
        self._on_event(f"{self.name}: CAN adapter back after {down_for:.1f} s")
        return bus

    def _reopen_failed(self, exc: BaseException, now: float) -> None:
        """Count a failed reopen; warn at the first, then at most once per interval."""
        self.failed_reopens += 1
        warned = self._reopen_warned_at
        if warned is not None and now - warned < REOPEN_WARNING_INTERVAL_S:
            log.debug("%s: reopen of %s failed: %s", self.name, self.path, exc)
            return
        self._reopen_warned_at = now
        log.warning(
            "%s: cannot reopen %s (%d failed attempts since it was lost): %s; still trying "
            "(an adapter that came back under another device name needs a config change)",
            self.name,
            self.path,
            self.failed_reopens,
            exc,
        )

    def stats(self) -> dict[str, Any]:
        """The device's counters since start-up, across reconnects (each reopened device starts
        its own from zero), plus the link's own."""
        inner = self._bus
        totals = _add_counts({}, self._retired)
        if inner is not None and hasattr(inner, "stats"):
            _add_counts(totals, inner.stats())
        return {
            **totals,
            "connected": inner is not None,
            "disconnects": self.disconnects,
            "reconnects": self.reconnects,
        }

    def shutdown(self) -> None:
        super().shutdown()
        bus, self._bus = self._bus, None
        if bus is not None:
            bus.shutdown()


def _device_name(bus: can.BusABC, default: str) -> str:
    """The serial path a bus was opened on (AA-55), else its ``channel_info`` (other buses
    keep objects, not names, in ``channel``)."""
    channel = getattr(bus, "channel", None)
    if isinstance(channel, str):
        return channel
    return str(getattr(bus, "channel_info", default))


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
