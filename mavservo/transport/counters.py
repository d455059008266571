"""The typed contract for a bus that counts what its transport saw.

Why a nominal base class and not a runtime-checkable Protocol: ``isinstance(bus, Protocol)``
only asks whether an attribute of that name exists, so a python-can bus of another vendor
with a ``stats`` attribute that is a dict, a property or anything else passed the check and
crashed the bridge at stop, with no summary (issue 29). Only buses that declare this contract
(the ``aa55`` bus, the auto-reconnect wrapper) are asked for counters; every other bus reports
none, whatever attributes it carries.
"""

from __future__ import annotations

import abc
from typing import Any


class TransportCounters(abc.ABC):
    """A bus whose ``stats()`` returns its transport counters (a JSON-able dict)."""

    @abc.abstractmethod
    def stats(self) -> dict[str, Any]:
        """Transport counters since start-up, for the summary and the run log."""


def transport_stats(bus: object) -> dict[str, Any]:
    """``bus.stats()`` for a bus that declares :class:`TransportCounters`, else ``{}``."""
    return bus.stats() if isinstance(bus, TransportCounters) else {}
