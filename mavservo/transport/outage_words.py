"""How a bus says it was lost and came back: words of the bus's kind, not of the wrapper.

:class:`~mavservo.transport.resilient_bus.ResilientBus` reports every outage of the bus it
wraps as one event (the bridge's console line, STATUSTEXT, run log and summary). What happened
depends on what the bus is: a USB adapter is unplugged and reopened, while the autopilot's CAN
port (``mavlink-can``) stops being forwarded and is asked for again. So the kind of bus says
it: a bus that declares :class:`SaysItsOutages` gives its :class:`OutageWords`; any other bus
(python-can's, a vendor's, the ``aa55`` adapter) is a device on a port and gets
:data:`DEVICE_WORDS`.

Why a nominal base class and not a ``getattr``: as for
:class:`~mavservo.transport.counters.TransportCounters`, a foreign bus's attribute of the same
name could be anything; only buses that declare the contract are asked.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass


@dataclass(frozen=True)
class OutageWords:
    """Templates of one kind of bus's outage texts (``str.format`` fields in braces).

    ``lost``: ``{name}`` (the bus's name) and ``{reason}`` (the error that ended it);
    ``back``: ``{name}`` and ``{down_for}`` (seconds, a float); ``down``: ``{name}``, the
    refusal of a send while the bus is away (the scheduler logs it once per outage);
    ``retrying``: ``{name}``, ``{path}``, ``{failed}`` (reopens failed so far) and ``{reason}``,
    the warning of a reopen that keeps failing.
    """

    lost: str
    back: str
    down: str
    retrying: str

    def lost_text(self, name: str, reason: object) -> str:
        return self.lost.format(name=name, reason=reason)

    def back_text(self, name: str, down_for: float) -> str:
        return self.back.format(name=name, down_for=down_for)

    def down_text(self, name: str) -> str:
        return self.down.format(name=name)

    def retrying_text(self, name: str, path: str, failed: int, reason: object) -> str:
        return self.retrying.format(name=name, path=path, failed=failed, reason=reason)


#: A device on a port (a USB-CAN adapter, a serial or socketcan interface): unplugged, reopened.
DEVICE_WORDS = OutageWords(
    lost="{name}: CAN adapter lost ({reason}); reconnecting",
    back="{name}: CAN adapter back after {down_for:.1f} s",
    down="{name}: device disconnected, reconnecting",
    retrying="{name}: cannot reopen {path} ({failed} failed attempts since it was lost): "
    "{reason}; still trying (an adapter that came back under another device name needs a "
    "config change)",
)


class SaysItsOutages(abc.ABC):
    """A bus kind whose outages are not a device's: it gives its own words."""

    @abc.abstractmethod
    def outage_words(self) -> OutageWords:
        """The texts of this bus's loss and return (the same for every bus of the kind and
        channel: :class:`ResilientBus` asks the first bus it opens)."""


def outage_words(bus: object) -> OutageWords:
    """``bus.outage_words()`` for a bus that declares :class:`SaysItsOutages`, else the
    device's."""
    return bus.outage_words() if isinstance(bus, SaysItsOutages) else DEVICE_WORDS
