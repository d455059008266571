"""Per-command latency split into the stages the host can see (paper eq. 1, stage by stage).

The paper models a round trip as ``T_tx + T_usb + T_can + T_servo + T_rx`` but measured only the
sum. From the host we can timestamp five points of one command's life::

    MAVLink receipt --accept--> setpoint scheduled --tx--> bytes written
                    --round_trip--> reply decoded --publish--> MAVLink telemetry sent

``accept`` and ``tx`` together are the host's T_tx, ``round_trip`` is T_usb + T_can + T_servo
(the part on the far side of the serial port), ``publish`` is T_rx up to the moment the state
leaves as MAVLink. ``LatencyTracer`` follows those points with O(1) work per event and bounded
memory (one open record per servo, ``metrics.SampleStats`` rings per stage), so it can stay on in
flight. It reads no clock: every time comes in as an argument (``time.monotonic()`` seconds).

The tracer has the scheduler's observer method names, so it can be registered as an observer
directly, or be fed by :class:`mavservo.records.runlog.RunLog`, which forwards to it.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from mavservo.records.metrics import SampleStats

STAGES: tuple[str, ...] = ("accept", "tx", "round_trip", "publish")
"""Stage names in the order a command passes through them."""

STAGE_DESCRIPTIONS: dict[str, str] = {
    "accept": "MAVLink receipt -> setpoint scheduled",
    "tx": "setpoint scheduled -> bytes written (T_tx)",
    "round_trip": "bytes written -> reply decoded (T_usb + T_can + T_servo)",
    "publish": "reply decoded -> MAVLink telemetry sent (T_rx)",
}

CSV_COLUMNS: tuple[str, ...] = (
    "servo",
    "seq",
    "t_received",
    "t_accepted",
    "t_written",
    "t_decoded",
    "t_published",
    *(f"{stage}_s" for stage in STAGES),
    "outcome",
)


@dataclass
class CommandTrace:
    """The timestamps one command collected; None where a point was not (yet) seen."""

    servo: str
    seq: int
    received: float | None
    accepted: float
    written: float | None = None
    decoded: float | None = None
    published: float | None = None
    outcome: str = "open"

    def stage_seconds(self) -> dict[str, float | None]:
        """Duration of each stage, None when either end is missing."""
        points = (self.received, self.accepted, self.written, self.decoded, self.published)
        out: dict[str, float | None] = {}
        for stage, start, end in zip(STAGES, points, points[1:], strict=False):
            out[stage] = None if start is None or end is None else end - start
        return out

    def csv_row(self) -> list[str]:
        """One ``latency.csv`` row in :data:`CSV_COLUMNS` order."""

        def fmt(value: float | None) -> str:
            return "" if value is None else f"{value:.6f}"

        stages = self.stage_seconds()
        return [
            self.servo,
            str(self.seq),
            fmt(self.received),
            fmt(self.accepted),
            fmt(self.written),
            fmt(self.decoded),
            fmt(self.published),
            *(fmt(stages[s]) for s in STAGES),
            self.outcome,
        ]


def summarize(samples: Iterable[float]) -> dict[str, Any]:
    """n, mean, sigma (paper eq. 5), min, max, p50/p95/p99 of a sample, via ``metrics``."""
    values = list(samples)
    stats = SampleStats(window=max(1, len(values)))
    stats.extend(values)
    return stats.summary()


class LatencyTracer:
    """Follows each command through the stages; thread-safe, O(1) per event, bounded memory.

    ``on_record`` (optional) receives every finished :class:`CommandTrace`: complete ones, and
    partial ones that were superseded by a newer setpoint or whose reply timed out, so a log shows
    where a command stopped. It is called under the tracer's lock and must not block.
    """

    def __init__(
        self,
        window: int = 4096,
        on_record: Callable[[CommandTrace], None] | None = None,
    ) -> None:
        self._lock = threading.Lock()
        self._pending_receipt: dict[str, float] = {}
        self._open: dict[str, CommandTrace] = {}
        self._stages = {stage: SampleStats(window) for stage in STAGES}
        self._total = SampleStats(window)
        self._on_record = on_record
        self.counts: dict[str, int] = {
            "commands": 0,
            "complete": 0,
            "superseded": 0,
            "timed_out": 0,
            "open": 0,
        }

    # -- points in a command's life -------------------------------------------------------

    def mavlink_received(self, servo: str, t: float) -> None:
        """A MAVLink message asking ``servo`` to move arrived at ``t`` (before the scheduler)."""
        with self._lock:
            self._pending_receipt[servo] = t

    def on_setpoint(self, servo: str, seq: int, angle_deg: float, source: str, t: float) -> None:
        """The scheduler accepted setpoint ``seq``; any older open command for the servo ends."""
        with self._lock:
            previous = self._open.pop(servo, None)
            if previous is not None:
                self._finish(previous, "superseded")
            received = self._pending_receipt.pop(servo, None)
            self._open[servo] = CommandTrace(servo, seq, received, t)
            self.counts["commands"] += 1

    def on_tx(
        self, bus: str, msg: Any, t: float, kind: str, servo: str | None, seq: int | None
    ) -> None:
        """First ``command`` frame for the open seq marks the write; refreshes do not count."""
        if kind != "command" or servo is None:
            return
        with self._lock:
            trace = self._open.get(servo)
            if trace is not None and trace.seq == seq and trace.written is None:
                trace.written = t

    def on_written(self, bus: str, t: float, kind: str, servo: str | None, seq: int | None) -> None:
        """Every frame carrying the open seq's command is written: marks the write like
        :meth:`on_tx`, for each command of a packed transfer too (DroneCAN's ArrayCommand carries
        8 servos' commands in 5 frames; the scheduler ties each frame to one servo for the CAN
        log, so ``on_tx`` alone left 3 commands without a write). The first mark stands."""
        self.on_tx(bus, None, t, kind, servo, seq)

    def on_rx(self, bus: str, msg: Any, t: float, servo: str | None, state: Any) -> None:
        """First decoded reply after the write closes the round trip."""
        if servo is None or state is None:
            return
        with self._lock:
            trace = self._open.get(servo)
            if trace is not None and trace.written is not None and trace.decoded is None:
                trace.decoded = t

    def on_lost(self, bus: str, servo: str | None, t: float) -> None:
        """A reply timed out (outcome ``timed_out``, as the scheduler's counter: a reply after
        its timeout is late, not lost, but this command's round trip ends here)."""
        if servo is None:
            return
        with self._lock:
            trace = self._open.get(servo)
            if trace is not None and trace.written is not None and trace.decoded is None:
                del self._open[servo]
                self._finish(trace, "timed_out")

    def on_reject(self, bus: str, reason: str, raw_bytes: bytes, t: float) -> None:
        """Decoder rejections do not belong to a command; accepted for observer symmetry."""

    def telemetry_sent(self, servo: str, t: float) -> None:
        """The servo's state left as MAVLink at ``t``; completes a decoded command."""
        with self._lock:
            trace = self._open.get(servo)
            if trace is not None and trace.decoded is not None:
                trace.published = t
                del self._open[servo]
                self._finish(trace, "complete")

    # -- results ---------------------------------------------------------------------------

    def _finish(self, trace: CommandTrace, outcome: str) -> None:
        trace.outcome = outcome
        self.counts[outcome] += 1
        stages = trace.stage_seconds()
        for stage, value in stages.items():
            if value is not None:
                self._stages[stage].add(value)
        if outcome == "complete":
            self._total.add(sum(v for v in stages.values() if v is not None))
        if self._on_record is not None:
            self._on_record(trace)

    def close_open(self) -> None:
        """Finish every still-open command as ``open`` (end of run), so it reaches the log."""
        with self._lock:
            for servo in list(self._open):
                self._finish(self._open.pop(servo), "open")

    def summary(self) -> dict[str, Any]:
        """Counts and per-stage statistics (seconds): mean and sigma over every sample, the
        percentiles over the most recent ``window`` (``metrics.SampleStats``)."""
        with self._lock:
            return {
                "counts": dict(self.counts),
                "stages": {stage: stats.summary() for stage, stats in self._stages.items()},
                "total": self._total.summary(),
            }
