"""The replies one servo owes the scheduler, and what a reply from it answered.

Pure (no clock, no I/O): the policy core (:mod:`.schedule_core`) registers what each frame it
sends provokes, expires what timed out at each step and asks, for each decoded reply, what it
answered. Its own part because it has its own state per servo (the expectations outstanding,
the latest ones that timed out, the learned latency of :mod:`.reply_matching`, a pushing
servo's first command waiting for its first report) and its own rules, which say nothing about
when frames go out:

* a reply answers an outstanding expectation of its kind, of plausible latency
  (:class:`~mavservo.scheduling.reply_matching.ReplyMatcher`);
* a reply that answers none came after its timeout ("late"), unless the servo also speaks
  unasked (a push-style servo pushes between commands: not late), and a late reply's latency
  is measured against the oldest remembered timed-out expectation of its kind;
* the first report of a servo whose commands provoke no reply is that command's round trip.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Hashable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

from .reply_matching import ReplyMatcher

if TYPE_CHECKING:
    from .schedule_core import FrameKind

TIMED_OUT_KEPT = 8
"""How many timed-out expectations a servo remembers, to time a late reply."""


@dataclass
class Expectation:
    """A reply the bus owes us: ``kind`` of frame that provoked it, when, and until when.

    ``key`` is the profile's ``exchange_key`` of the request (None: the profile cannot tell
    its replies apart), which the reply must carry to answer it.
    """

    kind: FrameKind
    t_tx: float
    deadline: float
    key: Hashable | None = None


@dataclass(frozen=True)
class ReplyMatch:
    """What a decoded reply answered: ``kind`` None means unsolicited (push-style servo),
    ``"late"`` a reply whose expectation had already timed out (counted timed out and late,
    not lost)."""

    kind: FrameKind | Literal["late"] | None
    t_tx: float | None
    latency_s: float | None
    back_online: bool
    late_latency_s: float | None = None
    """For a ``"late"`` reply: how long after its request it came, when the timed-out
    expectation it answers is still remembered (None otherwise)."""


class OwedReplies:
    """One servo's outstanding expectations, oldest (and earliest deadline) first.

    ``only_when_asked``: the servo speaks only when asked (it is polled, or answers its
    polls), so a reply that answers nothing is late. ``keyed_pushes``: it pushes reports its
    profile tells apart from answers (Robstride's active reports).
    """

    __slots__ = (
        "expected",
        "timed_out",
        "awaiting_first_since",
        "_matcher",
        "_only_when_asked",
        "_keyed_pushes",
    )

    def __init__(self, *, only_when_asked: bool, keyed_pushes: bool) -> None:
        self.expected: deque[Expectation] = deque()
        self.timed_out: deque[Expectation] = deque(maxlen=TIMED_OUT_KEPT)
        """The latest expectations that timed out, so a late reply can tell how late it was."""
        self.awaiting_first_since: float | None = None
        """When the latest command that provokes no reply went out, until the next report."""
        self._matcher = ReplyMatcher()
        self._only_when_asked = only_when_asked
        self._keyed_pushes = keyed_pushes

    @property
    def request_outstanding(self) -> bool:
        return any(e.kind == "request" for e in self.expected)

    def expect(
        self, kind: FrameKind, now: float, timeout_s: float, key: Hashable | None, count: int
    ) -> tuple[Expectation, ...]:
        """``count`` replies owed for a ``kind`` frame sent at ``now`` (re-timed at its write)."""
        expectations = tuple(Expectation(kind, now, now + timeout_s, key) for _ in range(count))
        self.expected.extend(expectations)
        return expectations

    def expire(self, now: float) -> int:
        """Move the expectations past their deadline at ``now`` to the timed out; how many.

        Deadlines grow with position (send order, one timeout), so expired ones lead the
        deque even after replies have taken expectations out of its middle.
        """
        expired = 0
        expected = self.expected
        while expected and expected[0].deadline <= now:
            self.timed_out.append(expected.popleft())
            expired += 1
        return expired

    def forget(self, expectations: tuple[Expectation, ...]) -> None:
        """The frame that provoked ``expectations`` was refused: nothing is owed for it."""
        for expectation in expectations:
            if expectation in self.expected:
                self.expected.remove(expectation)

    def match(self, t: float, key: Hashable | None, back_online: bool) -> ReplyMatch:
        """What a reply at ``t`` with exchange key ``key`` answered (module docstring)."""
        index = self._matcher.pick(self.expected, t, key)
        if index is not None:
            expectation = self.expected[index]
            del self.expected[index]
            timed = expectation.kind in ("command", "refresh")
            latency = t - expectation.t_tx if timed else None
            return ReplyMatch(expectation.kind, expectation.t_tx, latency, back_online)
        outstanding = bool(self.expected)
        if outstanding and key is not None and self._keyed_pushes:
            # a push the profile tells apart (Robstride's active reports) while only answers
            # of another kind are due: a push, not a late answer
            outstanding = any(e.key is None or e.key == key for e in self.expected)
        if outstanding or self._only_when_asked:
            # none of its kind outstanding, or this servo only speaks when asked: an unmatched
            # reply came after its timeout. (A push-style servo, no requests, also pushes
            # between commands: not late.)
            return ReplyMatch("late", None, None, back_online, self._late_latency(t, key))
        if self.awaiting_first_since is not None:
            since = self.awaiting_first_since
            self.awaiting_first_since = None
            return ReplyMatch(None, since, t - since, back_online)
        return ReplyMatch(None, None, None, back_online)

    def _late_latency(self, t: float, key: Hashable | None) -> float | None:
        """Latency of a late reply: it answers the oldest remembered timed-out expectation of
        its kind (a CAN node answers in order), which is then forgotten."""
        for i, expectation in enumerate(self.timed_out):
            if key is None or expectation.key is None or expectation.key == key:
                del self.timed_out[i]
                return t - expectation.t_tx
        return None
