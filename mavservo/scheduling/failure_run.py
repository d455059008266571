"""Failures of one repeating operation (a bus's sends, its receives), counted and logged once
per outage.

Its own module because both sides of the scheduler keep one (the command loop its sends, the
receive thread its receives) and the rule is the same for both.
"""

from __future__ import annotations

from typing import Any


class FailureRun:
    """Counts every failure of one repeating operation and says what to log, once per outage.

    Why: when the adapter is unplugged every send fails, 20-80 times a second for as long as
    it is away. One warning per failure buried the log (``--quiet`` does not hide warnings)
    and said nothing the first one had not. So an outage is logged when it starts (the
    caller logs ``failed`` returning True, with the reason) and when the operation works
    again (``succeeded`` returns how many failed and for how long); in between failures are
    only counted. ``total`` and ``outages`` count every failure and every outage. Not
    thread-safe: the caller serialises (the scheduler calls it under its lock).
    """

    def __init__(self) -> None:
        self.total = 0
        self.outages = 0
        self.failing_since: float | None = None
        """When the current outage began (None while the operation works)."""
        self._in_outage = 0

    def failed(self, t: float) -> bool:
        """Count a failure at ``t``; True if it starts an outage (the one to log)."""
        self.total += 1
        self._in_outage += 1
        if self.failing_since is not None:
            return False
        self.failing_since = t
        self.outages += 1
        return True

    def succeeded(self, t: float) -> tuple[int, float] | None:
        """The operation worked at ``t``: ``(failures, seconds)`` of the outage it ends, if any."""
        ended = self.ongoing(t)
        self.failing_since = None
        self._in_outage = 0
        return ended

    def ongoing(self, now: float) -> tuple[int, float] | None:
        """``(failures, seconds)`` of the outage still going on at ``now``, if any.

        Reads without ending it: at ``stop()`` an outage that lasted to the end is logged, but
        it did not end in a success, so metrics written afterwards still show it failing.
        """
        if self.failing_since is None:
            return None
        return (self._in_outage, now - self.failing_since)

    def to_dict(self, now: float) -> dict[str, Any]:
        return {
            "total": self.total,
            "outages": self.outages,
            "failing_for_s": None if self.failing_since is None else now - self.failing_since,
        }
