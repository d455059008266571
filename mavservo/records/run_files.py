"""The run directory's event files, written on the run log's writer thread only.

The part of the run log that does file I/O and nothing else: it turns each queued event
(:mod:`~.run_events`) into a row of ``trace.csv``, ``latency.csv`` or ``rejections.log``, a
record of ``mavlink.tlog`` or a frame of the CAN logs (:class:`~.can_log.CanFrameLogs`),
flushes them once a second and stops writing at the run's size cap. It never sees the queue or
the callers' threads, so it can be driven event by event in a test, and a failed file is
reported through :class:`~.problems.RunLogProblems` and the others go on.
"""

from __future__ import annotations

import contextlib
import csv
import enum
import os
import struct
from collections.abc import Callable, Iterable
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import can

from mavservo.records.can_log import CAN_BASENAME, CanFrameLogs, can_log_files
from mavservo.records.latency import CSV_COLUMNS as LATENCY_COLUMNS
from mavservo.records.problems import RunLogProblems
from mavservo.records.run_events import (
    BUS_RX,
    CATEGORY,
    HEALTH,
    LATENCY,
    LOST,
    MAV_IN,
    MAV_OUT,
    REJECT,
    RX,
    SETPOINT,
    STATE,
    TX,
    Event,
)
from mavservo.records.sink import BufferedSink
from mavservo.servos import ServoState

TRACE_FILE = "trace.csv"
LATENCY_FILE = "latency.csv"
REJECTIONS_FILE = "rejections.log"
TLOG_FILE = "mavlink.tlog"

TRACE_COLUMNS: tuple[str, ...] = (
    "t",
    "servo",
    "event",
    "setpoint_deg",
    "position_deg",
    "velocity_dps",
    "current_a",
    "temperature_c",
    "faults",
)


class RunFiles:
    """The event files of one run in ``directory``, opened at construction (headers written).

    ``offset`` turns the events' monotonic times into wall-clock time; ``channel_of(bus)`` is
    the CAN channel number a bus has in the run header. Once the directory holds
    ``max_run_bytes`` (checked at each :meth:`flush`), :attr:`capped` is set and the writer
    thread writes nothing more.
    """

    def __init__(
        self,
        directory: Path,
        formats: Iterable[str],
        rotate_bytes: int,
        *,
        start_wall: float,
        offset: float,
        tlog: bool,
        channel_of: Callable[[str], int],
        problems: RunLogProblems,
        max_run_bytes: int,
    ) -> None:
        self.directory = directory
        self._offset = offset
        self._channel_of = channel_of
        self._problems = problems
        self.max_run_bytes = max_run_bytes
        self.capped = False
        self.flushes = 0
        self._last_setpoint: dict[str, float] = {}
        self._can = CanFrameLogs(directory, formats, rotate_bytes, start_wall, problems.file_failed)
        self._sinks: dict[str, BufferedSink] = {}
        self._csv: dict[str, Any] = {}
        for key, name, columns in (
            ("trace", TRACE_FILE, TRACE_COLUMNS),
            ("latency", LATENCY_FILE, LATENCY_COLUMNS),
        ):
            sink = BufferedSink(directory / name, text=True)
            self._sinks[key] = sink
            self._csv[key] = csv.writer(sink)
            self._csv[key].writerow(columns)
        self._sinks["rejections"] = BufferedSink(directory / REJECTIONS_FILE, text=True)
        if tlog:
            self._sinks["tlog"] = BufferedSink(directory / TLOG_FILE, text=False)

    def created_paths(self) -> list[Path]:
        """Every file this run's events went to (a failed start removes them)."""
        created = [sink.path for sink in self._sinks.values()]
        for fmt in self._can.formats:
            created += can_log_files(self.directory, fmt)
        return created

    def write(self, item: Event) -> None:
        """One event into its file; a file that fails is reported, then the error raised."""
        try:
            self._write(item)
        except OSError as exc:  # a full disk: the caller counts the event as dropped
            self._problems.file_failed(_failed_name(exc, item), exc)
            raise

    def flush(self) -> None:
        """Every file's buffered data onto the disk; failures are reported, never raised."""
        self._can.flush()
        for sink in self._sinks.values():
            try:
                sink.flush()
            except OSError as exc:
                self._problems.file_failed(sink.path.name, exc)
        self.flushes += 1
        self._check_size()

    def close(self) -> None:
        self._can.close()
        for sink in self._sinks.values():
            try:
                sink.close()
            except OSError as exc:
                self._problems.file_failed(sink.path.name, exc)

    def _check_size(self) -> None:
        """Stop writing events once the run's files add up to ``max_run_bytes``."""
        if self.capped:
            return
        total = 0
        with contextlib.suppress(OSError), os.scandir(self.directory) as entries:
            for entry in entries:
                with contextlib.suppress(OSError):
                    if entry.is_file(follow_symlinks=False):
                        total += entry.stat(follow_symlinks=False).st_size
        if total >= self.max_run_bytes:
            self.capped = True
            self._problems.report(
                "cap",
                f"run log reached its size cap ({total / 2**20:.0f} MiB >= logging.max_run_mb);"
                " it records nothing more this run (the bridge keeps running)",
            )

    def _write(self, item: Event) -> None:
        code = item[0]
        if code in (TX, RX, BUS_RX):
            self._write_frame(item)
        elif code == STATE:
            _, servo, state, t = item
            self._write_state(servo, state, t)
        elif code == SETPOINT:
            _, servo, angle, t = item
            self._last_setpoint[servo] = angle
            self._csv["trace"].writerow([f"{t:.6f}", servo, "setpoint", _num(angle)] + [""] * 5)
        elif code == LOST:
            _, bus, servo, t = item
            setpoint = self._last_setpoint.get(servo)
            row = [f"{t:.6f}", servo or "", "lost", _num(setpoint)] + [""] * 5
            self._csv["trace"].writerow(row)
        elif code == REJECT:
            _, bus, reason, raw, t = item
            wall = datetime.fromtimestamp(t + self._offset, tz=timezone.utc).isoformat()
            self._sinks["rejections"].write(f"{wall} {t:.6f} {bus} {reason} {raw.hex(' ')}\n")
        elif code in (MAV_IN, MAV_OUT):
            _, raw, t = item
            usec = int((t + self._offset) * 1e6)
            self._sinks["tlog"].write(struct.pack(">Q", usec) + raw)
        elif code == LATENCY:
            self._csv["latency"].writerow(item[1].csv_row())
        elif code == HEALTH:
            _, servo, check, active, figures, t = item
            event = f"health:{check}" if active else f"health-cleared:{check}"
            self._csv["trace"].writerow(
                [f"{t:.6f}", servo, event, _num(self._last_setpoint.get(servo))]
                + [
                    _num(figures.get(key))
                    for key in ("position_deg", "velocity_dps", "current_a", "temperature_c")
                ]
                + [""]
            )

    def _write_frame(self, item: Event) -> None:
        code, bus, arb_id, extended, remote, dlc, data, t = item[:8]
        msg = can.Message(
            timestamp=t + self._offset,
            arbitration_id=arb_id,
            is_extended_id=extended,
            is_remote_frame=remote,
            dlc=dlc,
            data=data,
            is_rx=code != TX,
            is_error_frame=code == BUS_RX and item[8],
            channel=self._channel_of(bus),
            check=False,
        )
        self._can.write(msg)  # one full CAN log does not stop the others
        if code == RX and item[9] is not None:
            self._write_state(item[8], item[9], t)

    def _write_state(self, servo: str | None, state: ServoState, t: float) -> None:
        """A decoded servo state as a ``trace.csv`` row."""
        setpoint = self._last_setpoint.get(servo) if servo is not None else None
        self._csv["trace"].writerow(
            [
                f"{t:.6f}",
                servo or "",
                "state",
                _num(setpoint),
                _num(state.position_deg),
                _num(state.velocity_dps),
                _num(state.current_a),
                _num(state.temperature_c),
                _faults(state.faults),
            ]
        )


def _num(value: Any) -> str:
    return "" if value is None else f"{float(value):.4f}"


def _faults(value: Any) -> str:
    """Fault flags by name ("STALL|OVER_CURRENT"), empty when none: stable across enum changes."""
    if value is None:
        return ""
    if isinstance(value, enum.Flag):
        return value.name or "" if value else ""
    return str(value) if value else ""


def _failed_name(exc: OSError, item: Event) -> str:
    """Which file an event's failed write was for (named by the errno's filename if set)."""
    if exc.filename:
        return Path(exc.filename).name
    return {
        "can": f"{CAN_BASENAME}.*",
        "trace": TRACE_FILE,
        "rejections": REJECTIONS_FILE,
        "mavlink": TLOG_FILE,
        "latency": LATENCY_FILE,
    }[CATEGORY[item[0]]]
