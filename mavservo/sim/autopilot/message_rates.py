"""Which periodic messages the simulated autopilot sends, how often, and which are due now.

A part of its own because it is ArduPilot's stream-rate bookkeeping, with its own rules and
its own state: the rates given at construction are the defaults, a companion's
SET_MESSAGE_INTERVAL changes one (negative: off, 0: back to the default), a reboot forgets
them all, and each enabled message is due on absolute deadlines that skip ahead after a stall
instead of bursting. The stream only asks what is due and sends it, and hands it the
companion's SET_MESSAGE_INTERVAL and REQUEST_MESSAGE commands to answer.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

from mavservo.mavlink import mavlink2 as mav


def interval_of(rate_hz: float | None) -> float | None:
    """The period of ``rate_hz`` in seconds; None (off) for a rate that is not positive."""
    return None if not rate_hz or rate_hz <= 0 else 1.0 / rate_hz


class MessageRates:
    """Intervals in seconds (None: off) by message name, and their next deadlines."""

    def __init__(
        self, defaults: Mapping[str, float | None], unrequestable: Iterable[str] = ()
    ) -> None:
        self._defaults = dict(defaults)
        #: messages a REQUEST_MESSAGE may not ask for (sent only on their own terms)
        self._unrequestable = frozenset(unrequestable)
        self._intervals = dict(self._defaults)
        self._next_due: dict[str, float] = {}

    def __contains__(self, name: object) -> bool:
        return name in self._intervals

    def interval_s(self, name: str) -> float | None:
        return self._intervals.get(name)

    def set_interval_us(self, name: str, interval_us: float) -> None:
        """SET_MESSAGE_INTERVAL for a message this autopilot sends (``name in self``)."""
        if interval_us < 0:
            self._intervals[name] = None
        elif interval_us == 0:
            self._intervals[name] = self._defaults[name]
        else:
            self._intervals[name] = interval_us / 1e6

    def on_command(self, command: int, msg_id: float, interval_us: float) -> tuple[int, str | None]:
        """A companion's SET_MESSAGE_INTERVAL or REQUEST_MESSAGE (``param1``, ``param2``):
        the MAV_RESULT to answer, and the message to send at once (REQUEST_MESSAGE)."""
        name = _message_name(int(msg_id))
        if command == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
            if name is None or name not in self._intervals:
                return mav.MAV_RESULT_DENIED, None
            self.set_interval_us(name, interval_us)
            return mav.MAV_RESULT_ACCEPTED, None
        if command == mav.MAV_CMD_REQUEST_MESSAGE:
            if name is None or name not in self._intervals or name in self._unrequestable:
                return mav.MAV_RESULT_DENIED, None
            return mav.MAV_RESULT_ACCEPTED, name
        return mav.MAV_RESULT_UNSUPPORTED, None

    def reset(self) -> None:
        """A reboot: every rate back to its default."""
        self._intervals = dict(self._defaults)

    def start(self, now: float) -> None:
        """Every enabled message is first due at ``now``."""
        self._next_due = {name: now for name, iv in self._intervals.items() if iv}

    def due(self, now: float) -> list[str]:
        """The messages due at ``now``, in a fixed order; each one's deadline moves on."""
        names = []
        next_due = self._next_due
        for name, interval in self._intervals.items():
            if interval is None:
                next_due.pop(name, None)
                continue
            due = next_due.setdefault(name, now)
            if now >= due:
                names.append(name)
                # absolute deadlines; after a stall, skip ahead instead of bursting
                next_due[name] = due + interval if now - due < interval else now + interval
        return names

    def next_deadline(self, default: float) -> float:
        """The earliest deadline (``default`` when nothing is enabled)."""
        return min(self._next_due.values(), default=default)


def _message_name(msg_id: int) -> str | None:
    cls = mav.mavlink_map.get(msg_id)
    return None if cls is None else cls.msgname
