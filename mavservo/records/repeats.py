"""Repeated problems said once per interval, with a count: the rule every output shares.

Why: a servo that flaps (offline after a few lost replies, back with the next one) on a busy
host sent 57 STATUSTEXTs in 22 s for two servos to the ground station, while the console, which
had its own rate limit in other words, said "offline (no reply)" three times (issue 37). Both
outputs now run their problem texts through this one rule, so they say the same thing as often:

* per ``(subject, kind)`` (e.g. ``("servo aileron", "offline")``), the first onset is said at
  once, and so is its clearing;
* a further onset within ``interval_s`` of the last one said is counted, not said, and so is its
  clearing;
* :meth:`Repeats.flush` (called regularly) sums up each key's counted onsets once the interval
  is over, in one text whose words say what is true *now*: ``servo aileron offline (x5 in 10 s)``
  while it still is, ``servo aileron back online (offline x5 in 10 s)`` once it is not.

So a key says at most three texts per interval (onset, clearing, summary), whatever the rate of
the flapping: with the default 10 s, at most 18 a minute, 6 once it flaps steadily (one summary
and the clearing it owes). Pure: no clock, no I/O; the caller gives times and sends the texts.
"""

from __future__ import annotations

from dataclasses import dataclass

#: a problem's repeats within this long of its last text are counted, then summed up
REPEAT_INTERVAL_S = 10.0
#: a counted onset whose problem lasts this long is summed up at once (once per interval)
LASTING_S = 2.0

Key = tuple[str, str]
"""(subject, kind): ``("servo aileron", "offline")``, ``("servo aileron", "fault OVERHEAT")``."""


@dataclass
class _Episodes:
    active: bool = False
    clear_text: str = ""
    said_at: float | None = None
    """When an onset or a summary of this key was last said (None: never)."""
    clear_owed: bool = False
    """An onset was said: its clearing is said too."""
    repeats: int = 0
    """Onsets counted, not said, since ``said_at``."""
    counted_at: float | None = None
    """When the last counted onset came (the problem has lasted since, while active)."""
    lasting_said: bool = False
    """A lasting problem was summed up in this interval already."""


@dataclass(frozen=True)
class Summary:
    """One key's counted repeats summed up: ``text`` and whether the problem is still on."""

    key: Key
    text: str
    active: bool


def repeated(text: str, count: int, span_s: float, kind: str = "") -> str:
    """``text (x5 in 10 s)``, or ``text (offline x5 in 10 s)`` with ``kind``: the one format of
    a count of repeats, on the console and on the ground station alike."""
    what = f"{kind} x{count}" if kind else f"x{count}"
    return f"{text} ({what} in {span_s:.0f} s)"


class Repeats:
    """Onsets and clearings per :data:`Key` in, the texts to say out (module docstring)."""

    def __init__(self, interval_s: float = REPEAT_INTERVAL_S) -> None:
        self.interval_s = interval_s
        self._episodes: dict[Key, _Episodes] = {}
        #: onsets counted instead of said (all keys), for the run's counters
        self.counted = 0

    def onset(self, key: Key, text: str, t: float) -> str | None:
        """``key``'s problem began at ``t``: ``text`` to say now, or None (counted)."""
        episodes = self._episodes.setdefault(key, _Episodes())
        episodes.active = True
        if episodes.said_at is not None and t - episodes.said_at < self.interval_s:
            episodes.repeats += 1
            episodes.counted_at = t
            self.counted += 1
            return None
        if episodes.repeats and episodes.said_at is not None:  # not flushed in time
            text = repeated(text, episodes.repeats + 1, t - episodes.said_at)
        episodes.repeats = 0
        episodes.said_at = t
        episodes.clear_owed = True
        return text

    def clear(self, key: Key, text: str) -> str | None:
        """``key``'s problem is over: ``text`` to say now, or None (its onset was not said)."""
        episodes = self._episodes.setdefault(key, _Episodes())
        episodes.active = False
        episodes.clear_text = text
        if not episodes.clear_owed:
            return None
        episodes.clear_owed = False
        return text

    def flush(self, t: float) -> list[Summary]:
        """The keys whose interval with counted repeats is over at ``t``, summed up."""
        out = []
        for key, episodes in self._episodes.items():
            said_at = episodes.said_at
            if not episodes.repeats or said_at is None:
                continue
            subject, kind = key
            count, span = episodes.repeats + 1, t - said_at
            if t - said_at < self.interval_s:
                counted_at = episodes.counted_at
                lasting = (
                    episodes.active
                    and not episodes.lasting_said
                    and counted_at is not None
                    and t - counted_at >= LASTING_S
                )
                if lasting:  # it flapped, then stayed: said now, counted on
                    episodes.lasting_said = episodes.clear_owed = True
                    out.append(Summary(key, repeated(f"{subject} {kind}", count, span), True))
                continue
            if episodes.active:
                text = repeated(f"{subject} {kind}", count, span)
            else:
                text = repeated(episodes.clear_text, count, span, kind)
            out.append(Summary(key, text, episodes.active))
            episodes.repeats = 0
            episodes.said_at = t
            episodes.clear_owed = episodes.active
            episodes.lasting_said = False
        return out
