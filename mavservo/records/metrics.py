"""Timing figures of the paper (eqs. 1-5) as bounded, pure accumulators.

Nothing here reads a clock or starts a thread: callers pass every timestamp in. Every sample
store is a ring buffer of raw doubles allocated in full when it is built (:class:`FloatRing`),
so a bridge's memory is flat from its first second, not only once every window has filled
(a deque of float objects took 32 bytes a sample and about 7 minutes at 10 Hz to fill). The
mean, sigma, min and max are kept exactly over *all* samples (Welford), the percentiles over
the most recent ``window`` samples, which is what a live monitor and an end-of-run report
want.

The scheduler owns one ``SchedulerMetrics`` and updates it under its lock; ``to_dict()`` is the
JSON-serialisable snapshot the API, the live monitor and the run log share.
"""

from __future__ import annotations

import itertools
import json
import math
from array import array
from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

DEFAULT_WINDOW = 4096


def percentile(sorted_values: list[float], q: float) -> float:
    """Linear-interpolated percentile (``q`` in 0..100) of an already sorted, non-empty list."""
    if not sorted_values:
        raise ValueError("percentile of an empty sample")
    if not 0.0 <= q <= 100.0:
        raise ValueError(f"percentile must be in 0..100, got {q}")
    position = (len(sorted_values) - 1) * q / 100.0
    low = math.floor(position)
    high = min(low + 1, len(sorted_values) - 1)
    fraction = position - low
    return sorted_values[low] + (sorted_values[high] - sorted_values[low]) * fraction


class FloatRing:
    """The last ``maxlen`` floats, oldest first, in one array of doubles allocated up front.

    Why not ``deque(maxlen=...)``: a deque holds a float object per sample (8-byte slot plus a
    24-byte object) and grows block by block until it is full, so a store's memory keeps rising
    for as long as it takes to collect ``maxlen`` samples. Here all ``8 * maxlen`` bytes exist
    from the start and ``append`` only overwrites. Reads like the deque it replaces: ``len``,
    iteration and ``reversed`` (oldest first / newest first).
    """

    __slots__ = ("maxlen", "_values", "_next", "_size")

    def __init__(self, maxlen: int) -> None:
        if maxlen < 1:
            raise ValueError("a ring holds at least one value")
        self.maxlen = maxlen
        self._values = array("d", bytes(8 * maxlen))
        self._next = 0  # slot the next value goes into
        self._size = 0

    def append(self, value: float) -> None:
        self._values[self._next] = value
        self._next = (self._next + 1) % self.maxlen
        if self._size < self.maxlen:
            self._size += 1

    def __len__(self) -> int:
        return self._size

    def __bool__(self) -> bool:
        return self._size > 0

    def _parts(self) -> tuple[array[float], array[float]]:
        """The values as (older, newer) copies: a C-level slice each, so iterating stays as
        cheap as a deque's (``Scheduler.round_trip_samples`` reads under the scheduler's lock).
        Until the ring is full nothing has wrapped and the older part is empty."""
        if self._size < self.maxlen:
            return array("d"), self._values[: self._size]
        return self._values[self._next :], self._values[: self._next]

    def __iter__(self) -> Iterator[float]:
        older, newer = self._parts()
        return itertools.chain(older, newer)

    def __reversed__(self) -> Iterator[float]:
        older, newer = self._parts()
        return itertools.chain(reversed(newer), reversed(older))

    def values(self) -> list[float]:
        """The held values in storage order, not time order (for sorting: one C-level copy).

        Until the ring is full nothing has wrapped, so the values are the first ``len`` slots.
        """
        return self._values[: self._size].tolist()


class SampleStats:
    """Running mean and population sigma (paper eq. 5) over all samples, plus a bounded window.

    Population sigma (divide by N, not N - 1) because eq. (5) is written that way.
    """

    def __init__(self, window: int = DEFAULT_WINDOW) -> None:
        if window < 1:
            raise ValueError("window must hold at least one sample")
        self.count = 0
        self._mean = 0.0
        self._m2 = 0.0
        self.minimum = math.inf
        self.maximum = -math.inf
        self.recent = FloatRing(window)

    def add(self, value: float) -> None:
        self.count += 1
        delta = value - self._mean
        self._mean += delta / self.count
        self._m2 += delta * (value - self._mean)
        self.minimum = min(self.minimum, value)
        self.maximum = max(self.maximum, value)
        self.recent.append(value)

    def extend(self, values: Iterable[float]) -> None:
        for value in values:
            self.add(value)

    @property
    def mean(self) -> float | None:
        return self._mean if self.count else None

    @property
    def sigma(self) -> float | None:
        return math.sqrt(self._m2 / self.count) if self.count else None

    def summary(self) -> dict[str, Any]:
        """Count, mean, sigma, min, max and p50/p95/p99 of the recent window (None when empty)."""
        if not self.count:
            return {
                "n": 0,
                "mean": None,
                "sigma": None,
                "min": None,
                "max": None,
                "p50": None,
                "p95": None,
                "p99": None,
            }
        ordered = sorted(self.recent.values())
        return {
            "n": self.count,
            "mean": self.mean,
            "sigma": self.sigma,
            "min": self.minimum,
            "max": self.maximum,
            "p50": percentile(ordered, 50),
            "p95": percentile(ordered, 95),
            "p99": percentile(ordered, 99),
        }


class PeriodStats:
    """Intervals between successive events against a nominal period.

    Reports the achieved period (mean, sigma) and the p99 of ``|interval - nominal|``, the two
    figures the command-loop goal is written in.
    """

    def __init__(self, nominal_s: float | None, window: int = DEFAULT_WINDOW) -> None:
        self.nominal_s = nominal_s
        self.intervals = SampleStats(window)
        self.deviations = SampleStats(window)
        self._last: float | None = None

    @property
    def last(self) -> float | None:
        """The latest event marked (None before the first)."""
        return self._last

    def mark(self, t: float) -> None:
        if self._last is not None:
            interval = t - self._last
            self.intervals.add(interval)
            if self.nominal_s is not None:
                self.deviations.add(abs(interval - self.nominal_s))
        self._last = t

    def summary(self) -> dict[str, Any]:
        out = {"nominal": self.nominal_s, "interval": self.intervals.summary()}
        out["abs_deviation"] = self.deviations.summary()
        return out


class LoadMeter:
    """Measured bus load R (paper eq. 4) over a sliding time window.

    ``add(t, bits)`` for every frame seen on the bus (sent or received); ``ratio(now)`` is the
    bits inside ``(now - window_s, now]`` divided by ``window_s * bitrate``. The event store is
    bounded by ``max_events``: at most a window's worth of frames is ever kept.
    """

    def __init__(self, bitrate: int, window_s: float = 1.0, max_events: int = 65536) -> None:
        if bitrate <= 0 or window_s <= 0:
            raise ValueError("bitrate and window must be positive")
        self.bitrate = bitrate
        self.window_s = window_s
        self._events: deque[tuple[float, int]] = deque(maxlen=max_events)
        self._bits_in_window = 0
        self.total_bits = 0
        self.peak = 0.0
        self.first_t: float | None = None

    def _expire(self, now: float) -> None:
        horizon = now - self.window_s
        while self._events and self._events[0][0] <= horizon:
            self._bits_in_window -= self._events.popleft()[1]

    def add(self, t: float, bits: int) -> None:
        if len(self._events) == self._events.maxlen:
            self._bits_in_window -= self._events[0][1]
        self._events.append((t, bits))
        self._bits_in_window += bits
        if self.first_t is None:
            self.first_t = t
        self.total_bits += bits
        self._expire(t)
        self.peak = max(self.peak, self._bits_in_window / (self.window_s * self.bitrate))

    def ratio(self, now: float) -> float:
        self._expire(now)
        return self._bits_in_window / (self.window_s * self.bitrate)

    def mean(self, now: float) -> float:
        """Every bit seen over the time from the first frame to ``now`` (at least one window),
        as a share of the bus: the run's average R, which ``peak`` (the busiest window ending
        at a frame) always reaches or exceeds."""
        if self.first_t is None:
            return 0.0
        span = max(now - self.first_t, self.window_s)
        return self.total_bits / (span * self.bitrate)


@dataclass
class ServoMetrics:
    """Per-servo counters and timing samples."""

    command_period_s: float | None = None
    telemetry_period_s: float | None = None
    window: int = DEFAULT_WINDOW
    latency: SampleStats = field(init=False)
    telemetry_intervals: PeriodStats = field(init=False)
    """Between answers to telemetry polls and pushes: the poll stream, against its period."""
    state_intervals: PeriodStats = field(init=False)
    """Between any two decoded states (command replies, poll answers, pushes): how fresh the
    servo's published state is, and what the report's Figs. 4 and 5 draw from trace.csv."""
    command_intervals: PeriodStats = field(init=False)
    commands_sent: int = 0
    """Commands sent to the servo: one per frame of its own, or one per shared transfer that
    carried its entry (a DroneCAN ArrayCommand), however many frames that transfer took; the
    same for refreshes, requests and lifecycle frames. Frames on the wire are the bus's
    ``SchedulerMetrics.frames_written``."""
    refreshes_sent: int = 0
    requests_sent: int = 0
    lifecycle_sent: int = 0
    """Start-up, release and shutdown frames of the servo's profile (``docs/profiles.md``)."""
    received: int = 0
    """Every decoded reply: answers, late answers and pushes."""
    pushed: int = 0
    """Replies that answered nothing sent: status a push-style servo sends on its own, so
    ``received`` can be far above ``sent`` for it."""
    timed_out: int = 0
    """Expected replies not there within ``reply_timeout_s``."""
    late_replies: int = 0
    """Replies that came after their timeout (counted in ``timed_out`` and ``received``)."""
    rejected: int = 0
    send_failed: int = 0
    """Frames for this servo that ``bus.send`` refused (never counted as sent)."""
    setpoints_accepted: int = 0
    setpoints_rejected: int = 0
    setpoints_dropped: int = 0
    """Accepted setpoints dropped unsent because the servo went offline (bus down, no reply)."""
    went_offline: int = 0
    """Times the servo went offline (:data:`mavservo.records.vocabulary.OFFLINE`): the count
    of the console's and the ground station's "servo NAME offline" events, said or counted."""

    def __post_init__(self) -> None:
        self.latency = SampleStats(self.window)
        self.telemetry_intervals = PeriodStats(self.telemetry_period_s, self.window)
        self.state_intervals = PeriodStats(None, self.window)
        self.command_intervals = PeriodStats(self.command_period_s, self.window)

    @property
    def lost(self) -> int:
        """Expected replies that never came: timed out and not late. A reply after its timeout
        is late, not lost (the summary once counted it as both). Not below 0: a duplicate
        reply with no timed-out expectation left to answer counts as late only."""
        return max(0, self.timed_out - self.late_replies)

    def to_dict(self) -> dict[str, Any]:
        return {
            "latency_s": self.latency.summary(),
            "telemetry_interval_s": self.telemetry_intervals.summary(),
            "state_interval_s": self.state_intervals.intervals.summary(),
            "command_interval_s": self.command_intervals.summary(),
            "frames": {
                "commands": self.commands_sent,
                "refreshes": self.refreshes_sent,
                "requests": self.requests_sent,
                "lifecycle": self.lifecycle_sent,
                "sent": self.commands_sent
                + self.refreshes_sent
                + self.requests_sent
                + self.lifecycle_sent,
                "received": self.received,
                "pushed": self.pushed,
                "timed_out": self.timed_out,
                "late": self.late_replies,
                "lost": self.lost,
                "rejected": self.rejected,
                "send_failed": self.send_failed,
                "went_offline": self.went_offline,
            },
            "setpoints": {
                "accepted": self.setpoints_accepted,
                "rejected": self.setpoints_rejected,
                "dropped": self.setpoints_dropped,
            },
        }


class SchedulerMetrics:
    """Everything one scheduler (one bus) measures; ``to_dict(now)`` is JSON-serialisable."""

    def __init__(
        self,
        servo_names: Iterable[str],
        command_period_s: float,
        telemetry_period_s: float,
        bitrate: int,
        load_window_s: float = 1.0,
        window: int = DEFAULT_WINDOW,
    ) -> None:
        self.servos = {
            name: ServoMetrics(
                command_period_s=command_period_s,
                telemetry_period_s=telemetry_period_s,
                window=window,
            )
            for name in servo_names
        }
        self.command_period_s = command_period_s
        self.command_ticks = PeriodStats(command_period_s, window)
        self.command_lateness = SampleStats(window)
        """Slot due -> its first command frame written (or, for a slot with nothing to write,
        -> the step that served it). Measured at the write, not when the loop woke: a loop that
        woke on time and then stalled before the bus took the frame left the bus silent."""
        self.late_command_slots = 0
        """Slots whose first command frame was written a whole period or more after the slot
        was due, i.e. after the next slot was already due (the core counts those it skipped
        in ``missed_command_slots``; these it served, but too late)."""
        self.longest_command_gap_s = 0.0
        """Longest time between two served command slots (first writes): the bus silence."""
        self.telemetry_ticks = PeriodStats(telemetry_period_s, window)
        self.missed_command_slots = 0
        self.frames_written = 0
        """CAN frames the bus took from the scheduler: every servo frame, every frame of a
        packed transfer (DroneCAN's ArrayCommand: 8 servos' commands, 5 frames), the bus
        nodes' own frames. The servos' ``frames.sent`` count commands instead, one per servo
        per transfer, so on a packed bus their sum is above this."""
        self.bus_rejected = 0
        self.load = LoadMeter(bitrate, load_window_s)
        self.info: dict[str, Any] = {}

    def command_slot_served(self, due: float, t: float) -> None:
        """The command slot due at ``due`` got its first frame on the bus at ``t``."""
        last = self.command_ticks.last
        if last is not None:
            self.longest_command_gap_s = max(self.longest_command_gap_s, t - last)
        self.command_ticks.mark(t)
        lateness = t - due
        self.command_lateness.add(lateness)
        if lateness >= self.command_period_s:
            self.late_command_slots += 1

    def to_dict(self, now: float) -> dict[str, Any]:
        return {
            "info": dict(self.info),
            "command_tick": self.command_ticks.summary(),
            "command_lateness_s": self.command_lateness.summary(),
            "telemetry_tick": self.telemetry_ticks.summary(),
            "missed_command_slots": self.missed_command_slots,
            "frames_written": self.frames_written,
            "late_command_slots": self.late_command_slots,
            "longest_command_gap_s": self.longest_command_gap_s,
            "bus_rejected": self.bus_rejected,
            "load": {
                "window_s": self.load.window_s,
                "current": self.load.ratio(now),
                "mean": self.load.mean(now),
                "peak": self.load.peak,
                "total_bits": self.load.total_bits,
            },
            "servos": {name: servo.to_dict() for name, servo in self.servos.items()},
        }


def round_trip_figures(samples_s: Iterable[float]) -> dict[str, float]:
    """``rtt_p50``/``rtt_p95``/``rtt_p99`` in ms of wire round trips given in seconds (none
    without samples): the live figures the bridge publishes next to its bus loads."""
    ordered = sorted(samples_s)
    if not ordered:
        return {}
    return {f"rtt_p{q}": percentile(ordered, q) * 1000.0 for q in (50, 95, 99)}


def write_json(path: str | Path, snapshot: dict[str, Any]) -> Path:
    """Write a ``to_dict`` snapshot to ``path`` (parents created), return the path."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(json.dumps(snapshot, indent=2, sort_keys=True) + "\n")
    return target


def peak_window_bytes(samples: Iterable[tuple[float, int]], window_s: float = 1.0) -> int:
    """The most bytes in any window of ``window_s`` over ``(time, bytes)`` samples (sorted by
    time): what a radio's buffer sees, where an average hides the bursts (a link averaging 894
    B/s under a 1,000 B/s budget had 25 of 60 seconds above it)."""
    ordered = sorted(samples)
    peak = total = start = 0
    for end in range(len(ordered)):
        total += ordered[end][1]
        while ordered[end][0] - ordered[start][0] >= window_s:
            total -= ordered[start][1]
            start += 1
        peak = max(peak, total)
    return peak
