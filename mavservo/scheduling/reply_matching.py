"""Which outstanding request a servo's reply answers, when replies carry no sequence number.

RMD-X and LK replies say only *what kind* of request they answer (they echo its command byte),
not *which* one. Matching every reply to the servo's oldest outstanding expectation, as the
scheduler first did, goes wrong after a single lost reply: the next reply is then credited to
the lost one's expectation, the one after to the next, and so on, so the loss is carried along
and only declared when the servo next falls quiet for a whole timeout, often seconds and
several fault-free windows later (the soak's "clean-window losses").

Two facts settle it without sequence numbers:

* **kind**: a reply can only answer an expectation of the same exchange (``exchange_key`` of
  the profile: the command byte for RMD-X/LK; None for profiles that cannot tell, which match
  anything);
* **latency**: a servo answers with a typical latency (learned per servo from replies that can
  only answer one request: ~1-3 ms here, 30 ms for a slow one). Of the candidates, the reply
  answers the one whose latency is most like the servo's; older ones were lost, and are left
  to time out where they happened, within
  ``reply_timeout_s``. Requests of one kind go out at least a command period or an immediate
  spacing apart, so as long as a servo's latency wanders by less than half that, the pick is
  right.

A servo that suddenly slows down (no candidate within a plausible latency) keeps the strict
first-in first-out order of a CAN node's replies: the oldest candidate wins, and its latency
becomes the new typical one at once. Until a servo's latency is learned, the oldest candidate
wins too (the old behaviour). Pure: no clock, no I/O.
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence
from dataclasses import dataclass
from typing import Protocol

LATENCY_SMOOTHING = 1 / 8
"""Weight of a new sample in the per-servo typical latency (TCP's SRTT gain: slow to follow
one outlier, a few dozen replies to follow a real change)."""
PLAUSIBLE_FACTOR = 4.0
PLAUSIBLE_MARGIN_S = 0.005
"""A reply latency up to ``max(4 x typical, typical + 5 ms)`` is plausible; the margin keeps
a servo answering in 0.3 ms from calling a 2 ms scheduling hiccup implausible."""
CLOCK_SKEW_S = 0.001
"""A request written after the reply arrived cannot be what it answers; the sending and the
receiving thread read the clock at slightly different moments, so allow this much."""


class Outstanding(Protocol):
    """What matching needs of an expectation: when its request went out, and its kind."""

    t_tx: float
    key: Hashable | None


def plausible_latency_s(typical_s: float) -> float:
    """Longest latency still credible for a servo whose replies typically take ``typical_s``."""
    return max(PLAUSIBLE_FACTOR * typical_s, typical_s + PLAUSIBLE_MARGIN_S)


@dataclass
class ReplyMatcher:
    """One servo's reply matching: picks the expectation a reply answers and learns the
    servo's typical latency from the replies it matched."""

    typical_latency_s: float | None = None

    def pick(self, expected: Sequence[Outstanding], t: float, key: Hashable | None) -> int | None:
        """Index in ``expected`` (oldest first) of the expectation a reply at ``t`` answers.

        None when no outstanding expectation is of the reply's kind: the reply came after its
        own expectation timed out (late). Without a learned latency the oldest candidate wins.
        """
        candidates = [
            i for i, e in enumerate(expected) if key is None or e.key is None or e.key == key
        ]
        if not candidates:
            return None
        chosen = candidates[0]
        if len(candidates) == 1:
            self._learn(t - expected[chosen].t_tx)
        elif self.typical_latency_s is not None:
            typical = self.typical_latency_s
            bound = plausible_latency_s(typical)
            plausible = [i for i in candidates if -CLOCK_SKEW_S <= t - expected[i].t_tx <= bound]
            if plausible:  # the one whose latency is most like the servo's (ties: oldest)
                chosen = min(plausible, key=lambda i: abs(t - expected[i].t_tx - typical))
            else:  # slowed down: first in, first out, and its latency is the new typical
                self.typical_latency_s = max(0.0, t - expected[chosen].t_tx)
        return chosen

    def _learn(self, sample_s: float) -> None:
        """Fold in the latency of a reply that could only answer one expectation.

        Only such certain matches teach: learning from a pick among several would let a wrong
        pick (one request off, a lost reply carried along) confirm itself forever. Negative
        samples are skew between the sending and receiving threads' clocks: ignored.
        """
        if sample_s < 0:
            return
        if self.typical_latency_s is None:
            self.typical_latency_s = sample_s
        else:
            self.typical_latency_s += LATENCY_SMOOTHING * (sample_s - self.typical_latency_s)
