"""What the scheduler says about its servos in the log: offline/online and late replies.

Pure (no clock, no logging calls): the scheduler feeds events with their times and logs the
``(level, text)`` lines returned, so the rules are tested without threads.

Why rate-limited: under reply loss a servo flaps, offline after three lost replies, back with
the next one. The trial's journal got ``servo aileron offline (no reply)`` 8-29 times in 6-8 s
and no recovery line at the default WARNING level, so it read as permanently offline. Now each
servo's first offline is logged (WARNING) with its recovery (INFO); further offline events
within ``interval_s`` of the last one logged are only counted, and one WARNING per interval
sums them up and says whether the servo is online *now*, so the last line about a servo is
always true.

Why late replies get one warning: a servo that answers consistently after ``reply_timeout_s``
reads as losing most replies (``lost 50 of 76``, no latency) while staying online, and nothing
said the timeout was too short. :class:`LateReplies` collects how late they come and, after
``warn_after`` of them, returns one warning naming the measured latency and the setting.
"""

from __future__ import annotations

import logging
import statistics
from dataclasses import dataclass

Line = tuple[int, str]

FLAP_INTERVAL_S = 10.0
LATE_WARN_AFTER = 5


@dataclass
class _Track:
    online: bool = True
    offline_since: float | None = None
    last_offline_logged: float | None = None
    recovery_to_log: bool = False
    repeats: int = 0
    recoveries: int = 0


class OnlineLog:
    """Offline/online transitions of each servo into log lines, repeats rate-limited."""

    def __init__(self, interval_s: float = FLAP_INTERVAL_S) -> None:
        self.interval_s = interval_s
        self._tracks: dict[str, _Track] = {}

    def offline(self, servo: str, reason: str, t: float) -> list[Line]:
        """``servo`` went offline at ``t`` because of ``reason`` ("no reply", ...)."""
        track = self._tracks.setdefault(servo, _Track())
        track.online = False
        track.offline_since = t
        last = track.last_offline_logged
        if last is not None and t - last < self.interval_s:
            track.repeats += 1
            return []
        text = f"servo {servo} offline ({reason})"
        if track.repeats:  # only after a quiet interval with no summary yet (flush not called)
            text += f"; {self._summary(track, t - last)}"  # type: ignore[operator]
        track.repeats = track.recoveries = 0
        track.last_offline_logged = t
        track.recovery_to_log = True
        return [(logging.WARNING, text)]

    def online(self, servo: str, t: float) -> list[Line]:
        """``servo`` answered again at ``t`` after being offline."""
        track = self._tracks.setdefault(servo, _Track())
        track.online = True
        since, track.offline_since = track.offline_since, None
        if not track.recovery_to_log:
            track.recoveries += 1
            return []
        track.recovery_to_log = False
        away = "" if since is None else f" after {t - since:.1f} s"
        return [(logging.INFO, f"servo {servo} back online{away}")]

    def flush(self, t: float) -> list[Line]:
        """Summaries of the repeats counted for an interval (call regularly, e.g. each step)."""
        lines: list[Line] = []
        for servo, track in self._tracks.items():
            last = track.last_offline_logged
            if not track.repeats or last is None or t - last < self.interval_s:
                continue
            now = "online now" if track.online else "offline now"
            summary = self._summary(track, t - last)
            lines.append((logging.WARNING, f"servo {servo}: {summary}; {now}"))
            track.repeats = track.recoveries = 0
            track.last_offline_logged = t
            track.recovery_to_log = not track.online
        return lines

    @staticmethod
    def _summary(track: _Track, over_s: float) -> str:
        return (
            f"went offline {track.repeats} more times in {over_s:.1f} s "
            f"(back online {track.recoveries} times; not logged one by one)"
        )


class LateReplies:
    """Counts each servo's replies that came after their timeout and warns once per servo."""

    def __init__(self, reply_timeout_s: float, warn_after: int = LATE_WARN_AFTER) -> None:
        self.reply_timeout_s = reply_timeout_s
        self.warn_after = warn_after
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
        advice = "raise scheduler.reply_timeout_s"
        if seen:
            typical = statistics.median(seen)
            text += (
                f", typically {typical * 1e3:.0f} ms after the request "
                f"({(typical - self.reply_timeout_s) * 1e3:.0f} ms late)"
            )
            advice += f" above {typical * 1e3 * 1.5:.0f} ms"
        return [
            (
                logging.WARNING,
                f"{text} (counted late, not lost); if the servo is just slow, {advice}",
            )
        ]
