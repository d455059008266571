"""Bounds on what a sender can make the bridge do: token buckets, per sender, and digests.

Everything a stranger can trigger (a PARAM_SET, a read, an FTP request, a refusal text) costs
the bridge CPU, disk or link bytes. These three small tools put a rate and a bound on it, with
time passed in (no clock of their own, so the core stays pure and testable):

* :class:`TokenBucket`: ``rate`` per second, at most ``capacity`` saved up; the link budget is
  one (a hard bound on every window, not only the average), each sender's set rate another;
* :class:`PerSender`: one bucket per sender, in a table of bounded size (the least recently
  used sender is forgotten first, so spoofed senders cannot grow it);
* :class:`RefusalDigest`: the first refusal from a sender is said at once, the repeats within
  ``window_s`` are counted and said in one line when the window ends ("12 more ... from 255/190").
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Hashable
from dataclasses import dataclass


class TokenBucket:
    """``rate`` tokens a second, at most ``capacity`` held; ``debt`` lets a must-send message
    take tokens below zero (repaid before anything optional goes out again)."""

    def __init__(self, rate: float, capacity: float, now: float | None = 0.0) -> None:
        self.rate = rate
        self.capacity = capacity
        self.tokens = capacity
        #: None: the clock starts at the first :meth:`level` (full until then)
        self._at = now

    @property
    def at(self) -> float | None:
        """The time the tokens were last counted at (None: not yet)."""
        return self._at

    def level(self, now: float) -> float:
        if self._at is None:
            self._at = now
        elif now > self._at:
            self.tokens = min(self.capacity, self.tokens + (now - self._at) * self.rate)
            self._at = now
        return self.tokens

    def take(self, amount: float, now: float, *, keep: float = 0.0, debt: float = 0.0) -> bool:
        """Take ``amount`` if that leaves at least ``keep`` (or, with ``debt``, no less than
        ``-debt``); False and nothing taken otherwise."""
        floor = -debt if debt else keep
        if self.level(now) - amount < floor:
            return False
        self.tokens -= amount
        return True


class PerSender:
    """A token bucket per sender, at most ``max_senders`` of them (least recently used out)."""

    def __init__(self, rate: float, burst: float, max_senders: int = 64) -> None:
        self.rate = rate
        self.burst = burst
        self.max_senders = max_senders
        self._buckets: OrderedDict[Hashable, TokenBucket] = OrderedDict()

    def allow(self, sender: Hashable, now: float, cost: float = 1.0) -> bool:
        bucket = self._buckets.get(sender)
        if bucket is None:
            bucket = TokenBucket(self.rate, self.burst, now)
            self._buckets[sender] = bucket
            while len(self._buckets) > self.max_senders:
                self._buckets.popitem(last=False)
        else:
            self._buckets.move_to_end(sender)
        return bucket.take(cost, now)


@dataclass
class _Window:
    opened: float
    repeats: int = 0
    last: str = ""


class RefusalDigest:
    """One text per sender per ``window_s`` for repeated refusals, with the count.

    Why: refused sets each queued a STATUSTEXT; a 50/s flood of NaN sets pushed the failsafe
    alert out of the queue (issue 32, finding 4). Now a flood is one text a second per sender.
    """

    def __init__(self, window_s: float = 1.0, max_senders: int = 64) -> None:
        self.window_s = window_s
        self.max_senders = max_senders
        self._open: OrderedDict[Hashable, _Window] = OrderedDict()

    def note(self, sender: Hashable, text: str, now: float) -> str | None:
        """The text to say now (the first refusal of a window), or None (counted)."""
        window = self._open.get(sender)
        if window is not None and now - window.opened < self.window_s:
            window.repeats += 1
            window.last = text
            return None
        self._open[sender] = _Window(now)
        self._open.move_to_end(sender)
        while len(self._open) > self.max_senders:
            self._open.popitem(last=False)
        return text

    def due(self, now: float, describe: str = "refused") -> list[str]:
        """Summaries of the windows that ended: "N more <describe> from S/C (last: ...)"."""
        out = []
        for sender, window in list(self._open.items()):
            if now - window.opened < self.window_s:
                continue
            del self._open[sender]
            if window.repeats:
                who = (
                    "/".join(str(part) for part in sender) if isinstance(sender, tuple) else sender
                )
                out.append(f"{window.repeats} more {describe} from {who} (last: {window.last})")
        return out
