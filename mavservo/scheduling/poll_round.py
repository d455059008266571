"""The telemetry loop's own state: its ticks, each polled servo's next poll, and the round of
polls waiting for bus time.

Pure (no clock, no I/O): the policy core (:mod:`.schedule_core`) opens a round at each tick and
takes from it the polls that fit before the next command slot, then builds their request frames
and expectations. Its own part because the telemetry loop is the second of the two loops, with
its own clock (ticks every ``telemetry_period_s``, phased away from command slots) and its own
fairness rules (schedule core's module docstring, "Telemetry"): due servos are served
oldest-due first, equally due ones in configuration order; a servo keeps its place in the round,
so its reply comes back at the same offset after every tick; the polls that did not fit keep the
front of the next round; a servo with a request unanswered is not polled again until the reply
or its timeout; a servo far behind is not caught up with a burst.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence


class _Poll:
    __slots__ = ("period", "cost_s", "next_due")

    def __init__(self, period: float, cost_s: float) -> None:
        self.period = period
        self.cost_s = cost_s
        """Bus time of its requests and their replies."""
        self.next_due = math.inf


class PollRound:
    """Ticks and polls of the servos ``polled`` (``(name, period, cost_s)`` in configuration
    order; a servo never polled is left out)."""

    def __init__(
        self,
        polled: Sequence[tuple[str, float, float]],
        telemetry_period_s: float,
        phase_s: float,
    ) -> None:
        self._polls = {name: _Poll(period, cost) for name, period, cost in polled}
        self._rank = {name: i for i, (name, _, _) in enumerate(polled)}
        self._period_s = telemetry_period_s
        self._phase_s = phase_s
        self.next_tick = math.inf
        self.round: list[str] = []
        """The servos due and not yet polled, in the order they will be."""

    def anchor(self, start: float) -> None:
        """The first tick is ``phase_s`` after ``start``; every servo is due at it."""
        self.next_tick = start + self._phase_s
        for poll in self._polls.values():
            poll.next_due = self.next_tick

    def tick(self, now: float) -> float | None:
        """Open a new round if a tick is due at ``now``: returns the tick served (the latest, if
        the loop was late: ticks are not replayed), None when none is due."""
        if now < self.next_tick:
            return None
        period = self._period_s
        behind = math.floor((now - self.next_tick) / period + 1e-9)
        tick = self.next_tick + behind * period
        self.next_tick = tick + period
        half_tick = period / 2
        due = [name for name, poll in self._polls.items() if poll.next_due - now <= half_tick]
        due.sort(key=lambda name: (self._polls[name].next_due, self._rank[name]))
        # a new round keeps any leftovers of the previous one in front (they are older)
        self.round = [m for m in self.round if m not in due] + due
        return tick

    def take(
        self, now: float, budget_s: float, outstanding: Callable[[str], bool], late: list[str]
    ) -> list[str]:
        """The servos to poll at ``now``, in order, within ``budget_s`` of bus time; those
        polled more than half a tick after they were due are appended to ``late``. The rest
        stay in the round."""
        remaining: list[str] = []
        taken: list[str] = []
        for name in self.round:
            poll = self._polls[name]
            if outstanding(name) or poll.cost_s > budget_s:
                remaining.append(name)
                continue
            budget_s -= poll.cost_s
            if now - poll.next_due > self._period_s / 2:
                late.append(name)
            taken.append(name)
            poll.next_due += poll.period
            if poll.next_due < now:  # far behind: do not try to catch up with a burst
                poll.next_due = now + poll.period
        self.round = remaining
        return taken

    def waiting(self, outstanding: Callable[[str], bool]) -> bool:
        """True when a servo of the round could be polled (none has its request out)."""
        return any(not outstanding(name) for name in self.round)
