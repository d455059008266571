"""What the scheduler says about its servos in the log: offline/online and late replies.

Pure (no clock, no logging calls): the scheduler feeds events with their times and logs the
``(level, text)`` lines returned, so the rules are tested without threads.

Why rate-limited: under reply loss a servo flaps, offline after three lost replies, back with
the next one. The trial's journal got ``servo aileron offline (no reply)`` 8-29 times in 6-8 s
and no recovery line at the default WARNING level, so it read as permanently offline. Now each
servo's first offline is logged (WARNING) with its recovery (INFO); further offline events
within ``interval_s`` of the last one logged are only counted, and one line per interval sums
them up and says whether the servo is online *now* (WARNING while it is still offline, INFO
once it is back), so the last line about a servo is always true. The rule and the words are
the ground station's too (:class:`mavservo.records.Repeats`).

Why late replies get one warning: a servo that answers consistently after ``reply_timeout_s``
reads as losing most replies (``lost 50 of 76``, no latency) while staying online, and nothing
said the timeout was too short. :class:`LateReplies` collects how late they come and, after
``warn_after`` of them, returns one warning naming the measured latency and the setting.

Why the advice has a ceiling: a loaded host delayed every reply by ~270 ms and the warning
advised a flight surface's bus to wait 401 ms for its replies, so a dead surface would have
been noticed only after ``offline_after_missed`` such waits. A reply timeout is only ever
advised up to :data:`MAX_ADVISED_TIMEOUT_S`; replies later than that have a cause to fix instead
(a busy host or a congested bus), and the warning names it.
"""

from __future__ import annotations

import logging
import statistics

from mavservo.records import BACK_ONLINE, OFFLINE, REPEAT_INTERVAL_S, Repeats

Line = tuple[int, str]

FLAP_INTERVAL_S = REPEAT_INTERVAL_S
LATE_WARN_AFTER = 5
#: the highest reply timeout the late-reply warning ever advises (the servos here answer in
#: 1-30 ms; a timeout above this makes a dead servo known too late to be safe for a surface)
MAX_ADVISED_TIMEOUT_S = 0.1


class OnlineLog:
    """Offline/online transitions of each servo into log lines, repeats rate-limited by the
    rule the ground station's texts follow too (:class:`~mavservo.records.Repeats`): the same
    words ("offline", "back online") and the same count ("x5 in 10 s") on every output."""

    def __init__(self, interval_s: float = FLAP_INTERVAL_S) -> None:
        self.interval_s = interval_s
        self._repeats = Repeats(interval_s)
        self._offline_since: dict[str, float] = {}

    def offline(self, servo: str, reason: str, t: float) -> list[Line]:
        """``servo`` went offline at ``t`` because of ``reason`` ("no reply", ...)."""
        self._offline_since[servo] = t
        key = (f"servo {servo}", OFFLINE)
        text = self._repeats.onset(key, f"servo {servo} {OFFLINE} ({reason})", t)
        return [] if text is None else [(logging.WARNING, text)]

    def online(self, servo: str, t: float) -> list[Line]:
        """``servo`` answered again at ``t`` after being offline."""
        since = self._offline_since.pop(servo, None)
        away = "" if since is None else f" after {t - since:.1f} s"
        key = (f"servo {servo}", OFFLINE)
        text = self._repeats.clear(key, f"servo {servo} {BACK_ONLINE}{away}")
        return [] if text is None else [(logging.INFO, text)]

    def flush(self, t: float) -> list[Line]:
        """Summaries of the repeats counted for an interval (call regularly, e.g. each step):
        WARNING while the servo is still offline, INFO once it is back."""
        return [
            (logging.WARNING if summary.active else logging.INFO, summary.text)
            for summary in self._repeats.flush(t)
        ]


class LateReplies:
    """Counts each servo's replies that came after their timeout and warns once per servo."""

    def __init__(
        self,
        reply_timeout_s: float,
        warn_after: int = LATE_WARN_AFTER,
        ceiling_s: float = MAX_ADVISED_TIMEOUT_S,
    ) -> None:
        self.reply_timeout_s = reply_timeout_s
        self.warn_after = warn_after
        #: the highest reply timeout this warning may advise (module docstring)
        self.ceiling_s = ceiling_s
        self._counts: dict[str, int] = {}
        self._latencies: dict[str, list[float]] = {}
        self._warned: set[str] = set()

    def late(self, servo: str, latency_s: float | None) -> list[Line]:
        """A reply from ``servo`` came after its timeout, ``latency_s`` after its request
        (None: not known which request it answered; counted, not measured)."""
        if servo in self._warned:
            return []
        count = self._counts[servo] = self._counts.get(servo, 0) + 1
        seen = self._latencies.setdefault(servo, [])
        if latency_s is not None:
            seen.append(latency_s)
        if count < self.warn_after:
            return []
        self._warned.add(servo)
        del self._latencies[servo], self._counts[servo]
        timeout_ms = self.reply_timeout_s * 1e3
        text = f"servo {servo}: {count} replies came after reply_timeout_s ({timeout_ms:g} ms)"
        if not seen:
            return [(logging.WARNING, f"{text} (counted late, not lost); {self._cause()}")]
        typical = statistics.median(seen)
        text += (
            f", typically {typical * 1e3:.0f} ms after the request "
            f"({(typical - self.reply_timeout_s) * 1e3:.0f} ms late)"
        )
        advised = typical * 1.5
        if advised <= self.ceiling_s:
            advice = (
                "if the servo is just slow, raise scheduler.reply_timeout_s "
                f"to {advised * 1e3:.0f} ms"
            )
        else:
            advice = self._cause()
        return [(logging.WARNING, f"{text} (counted late, not lost); {advice}")]

    def _cause(self) -> str:
        """What to look at when replies are later than any safe timeout."""
        return (
            f"a servo answers within a few ms: replies this late mean a busy host or a "
            f"congested bus (check the CPU load and the bus load; scheduler.realtime: true), "
            f"not scheduler.reply_timeout_s to raise (never above {self.ceiling_s * 1e3:.0f} ms: "
            "a dead servo would be noticed late)"
        )
