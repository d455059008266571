"""Answers to requests: to the requester only, paced per requester, within the link budget.

Why: one 13-byte PARAM_REQUEST_LIST drew 88 PARAM_VALUE (3,256 B) sent to every peer, the
autopilot link included, and PARAM_REQUEST_READ at 1,000/s put 69.5 kB/s on a link budgeted at
1 kB/s (issue 32, finding 3). A service (parameters, FTP, missions) hands its answers to
:meth:`AnswerQueue.put` with the requester's (system, component); :meth:`AnswerQueue.due`
gives out what may go now: requesters in turn (one cannot starve another), each at most
``per_sender_hz`` answers a second, and each answer only if the link's budget admits it (the
caller's ``admit``). A requester's queue is bounded (the oldest answers beyond it are dropped and
counted), the table of requesters too (the least recently served is forgotten); a repeated
request with the same ``tag`` (a list asked again) replaces what is still queued for it.

Pure: time comes in; the link layer sends each :class:`Answer` to ``to`` only.
"""

from __future__ import annotations

from collections import Counter, OrderedDict, deque
from collections.abc import Callable, Hashable
from dataclasses import dataclass
from typing import Any

from mavservo.mavlink.commands import Outgoing
from mavservo.mavlink.origin import Requester
from mavservo.mavlink.pacing import TokenBucket

#: Answers one requester gets a second at most (a parameter list of 90 in about 2 s).
ANSWERS_PER_S = 50.0
ANSWER_BURST = 10.0
#: Answers queued for one requester at most (several components' lists).
MAX_QUEUED = 512
#: Requesters with answers queued at most.
MAX_REQUESTERS = 16


@dataclass(frozen=True)
class Answer:
    """A message from ``component_id`` for the requester ``to`` only (its ids and the origin
    its request came from: :mod:`.origin`)."""

    component_id: int
    msg: Any
    to: Requester


class _Requester:
    def __init__(self, now: float) -> None:
        self.queue: deque[tuple[Hashable, int, Any]] = deque()
        self.bucket = TokenBucket(ANSWERS_PER_S, ANSWER_BURST, now)


class AnswerQueue:
    """Per-requester FIFO queues of answers, served in turn within a budget."""

    def __init__(self) -> None:
        self._requesters: OrderedDict[Requester, _Requester] = OrderedDict()
        self.counters: Counter[str] = Counter()

    def __len__(self) -> int:
        return sum(len(r.queue) for r in self._requesters.values())

    def put(self, to: Requester, answers: list[Outgoing], now: float, tag: Hashable = None) -> None:
        """Queue ``answers`` for ``to``; with ``tag``, what is still queued under the same tag
        for ``to`` is dropped first (a list asked again restarts instead of doubling)."""
        requester = self._requesters.get(to)
        if requester is None:
            if not answers:
                return
            if len(self._requesters) >= MAX_REQUESTERS:
                self._forget_one()
            requester = _Requester(now)
            self._requesters[to] = requester
        if tag is not None:
            kept = deque(item for item in requester.queue if item[0] != tag)
            self.counters["answers_replaced"] += len(requester.queue) - len(kept)
            requester.queue = kept
        for component_id, msg in answers:
            if len(requester.queue) >= MAX_QUEUED:
                requester.queue.popleft()
                self.counters["answers_dropped"] += 1
            requester.queue.append((tag, component_id, msg))

    def _forget_one(self) -> None:
        """Make room for a new requester: one with nothing queued (least recently served
        first), else the one with the most queued (a flood), never a quiet one with little
        waiting, such as a ground station behind a flood of new spoofed requesters (among
        equals the most recently served or added goes: the one waiting longest stays)."""
        victim = next((to for to, r in self._requesters.items() if not r.queue), None)
        if victim is None:
            newest_first = list(reversed(self._requesters))
            victim = max(newest_first, key=lambda to: len(self._requesters[to].queue))
        dropped = self._requesters.pop(victim)
        self.counters["answers_dropped"] += len(dropped.queue)
        self.counters["requesters_forgotten"] += 1

    def due(self, now: float, admit: Callable[[int, Any], bool]) -> list[Answer]:
        """The answers that may go now: requesters in turn (the least recently served first,
        across calls too), one answer each per round, each within its own rate and ``admit``
        (the link budget; the first refusal ends the call, the answer stays queued)."""
        out: list[Answer] = []
        for _ in range(MAX_QUEUED):  # bounded rounds
            progressed = False
            for to in list(self._requesters):
                requester = self._requesters[to]
                if not requester.queue or requester.bucket.level(now) < 1.0:
                    continue
                _, component_id, msg = requester.queue[0]
                if not admit(component_id, msg):
                    self.counters["answers_waiting_for_budget"] += 1
                    return out
                requester.queue.popleft()
                requester.bucket.take(1.0, now)
                # served: to the back of the line, so the next call (the next tick, when the
                # budget admits one answer a tick) starts with the others. Before, the first
                # requester ever queued was asked first at every tick: a stranger's 200/s
                # READ flood took every admitted answer, a ground station's READ got 0 of 10.
                self._requesters.move_to_end(to)
                out.append(Answer(component_id, msg, to))
                self.counters["answers_sent"] += 1
                progressed = True
            if not progressed:
                break
        return out
