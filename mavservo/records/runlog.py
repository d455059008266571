"""The run log directory writer: what crossed the wire, in formats other tools already read.

A :class:`RunLog` is a scheduler observer (``on_setpoint``, ``on_tx``, ``on_rx``, ``on_lost``,
``on_reject``) plus a MAVLink tap (``mavlink_in`` / ``mavlink_out``) and the latency hooks
(``mavlink_received``, ``telemetry_sent``). Those methods are called from the scheduler's and the
link's threads, so they only put a small tuple on a bounded queue; one writer thread does all the
file I/O. When the disk cannot keep up the queue fills and new events are dropped and counted:
a slow disk costs log lines, never command slots. The counts land in ``metrics.json``.

Directory layout (see ``docs/logs.md``)::

    run.json         header: versions, config path, start wall time, monotonic->wall offset, buses
    can.asc/.blf     every CAN frame sent and every one the adapter delivered (``can_frames:
                     all``; ``servos``: only the servos'), python-can writers, rotated
    rejections.log   decoder rejections with the offending bytes
    trace.csv        setpoints and decoded servo states, for the report's figures
    latency.csv      one row per command, stage by stage (mavservo.records.latency)
    mavlink.tlog     MAVLink in and out, 8-byte big-endian usec wall timestamp + raw frame
    metrics.json     written at close: scheduler metrics, latency summary, log counters

A run that fails to start keeps ``run.json`` alone, with ``start_failed``: why (:meth:`abandon`).

Times handed in are ``time.monotonic()`` seconds; the files carry wall-clock time, computed with
the offset captured once at start (and stored in ``run.json`` so a reader can go back).

Failure rules (docs/reliability.md, "Disk full"): the directory is 0700 and every file 0600,
whatever the umask (CAN frames and MAVLink traffic are nobody else's business). Every file is
flushed once a second, the BLF one too (a container per second, its header rewritten with the
wall-clock start, so a killed run keeps all but the last second with wall-clock times). A file
that cannot be written (disk full) is cut back to its last complete flush and closed, the
problem is reported once per kind through ``on_problem`` (the bridge's event path: console and
STATUSTEXT) and the log, and the bridge goes on. The whole run is capped at ``max_run_bytes``;
``metrics.json`` is kept in memory and written at close to the run directory or, when that
fails, to ``fallback_dir``; :meth:`RunLog.outcome` says what happened; no ``.tmp`` file is
left behind.
"""

from __future__ import annotations

import contextlib
import csv
import enum
import errno
import json
import logging
import os
import platform
import re
import stat
import struct
import sys
import tempfile
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable, Mapping
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import can
from can.io.generic import FileIOMessageWriter

from mavservo.records.latency import CSV_COLUMNS as LATENCY_COLUMNS
from mavservo.records.latency import CommandTrace, LatencyTracer
from mavservo.servos import ServoState

RUN_HEADER = "run.json"
TRACE_FILE = "trace.csv"
LATENCY_FILE = "latency.csv"
REJECTIONS_FILE = "rejections.log"
TLOG_FILE = "mavlink.tlog"
METRICS_FILE = "metrics.json"
CAN_BASENAME = "can"
LOG_FORMAT_VERSION = 1

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

_POLL_S = 0.05  # the writer wakes on its own; callers never signal it
_FLUSH_EVERY_S = 1.0
_BUFFER_LIMIT = 256 * 1024  # a text file's buffer is written out early past this
DIR_MODE = 0o700
FILE_MODE = 0o600
DEFAULT_MAX_RUN_BYTES = 1024 * 1024 * 1024
_ABANDON_JOIN_S = 2.0  # the writer polls every _POLL_S; nothing is queued before a start

log = logging.getLogger(__name__)

# Event codes on the queue (small ints keep the tuples cheap to build on the caller's thread).
#: Events the writer handles between two hand-overs of the interpreter lock (~1.5 ms of
#: ASC + BLF work at ~24 us a frame).
_YIELD_EVERY = 64

(_TX, _RX, _SETPOINT, _LOST, _REJECT, _MAV_IN, _MAV_OUT, _LATENCY, _HEALTH, _BUS_RX, _STATE) = (
    range(11)
)
_CATEGORY = {
    _TX: "can",
    _RX: "can",
    _BUS_RX: "can",
    _STATE: "trace",
    _SETPOINT: "trace",
    _LOST: "trace",
    _REJECT: "rejections",
    _MAV_IN: "mavlink",
    _MAV_OUT: "mavlink",
    _LATENCY: "latency",
    _HEALTH: "trace",
}


def new_run_dir(base: str | os.PathLike[str], now: float | None = None) -> Path:
    """Create and return a fresh ``base/YYYYmmdd-HHMMSS[-n]`` directory for one run."""
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(time.time() if now is None else now))
    base_path = Path(base)
    base_path.mkdir(parents=True, exist_ok=True)
    for n in range(1000):
        candidate = base_path / (stamp if n == 0 else f"{stamp}-{n}")
        try:
            candidate.mkdir(mode=DIR_MODE)
        except FileExistsError:
            continue
        os.chmod(candidate, DIR_MODE)  # mkdir's mode is masked by the umask; this is not
        return candidate
    raise FileExistsError(f"no free run directory name under {base_path}")


def can_log_files(directory: str | os.PathLike[str], fmt: str) -> list[Path]:
    """The CAN log files of one format in write order: rotated parts by count, then the live one.

    python-can's ``SizedRotatingLogger`` renames full files to ``can_<date>_#NNN.<fmt>``.
    """
    directory = Path(directory)
    pattern = re.compile(rf"^{CAN_BASENAME}_.*_#(\d+)\.{re.escape(fmt)}$")
    rotated = []
    for path in directory.iterdir():
        match = pattern.match(path.name)
        if match:
            rotated.append((int(match.group(1)), path.name, path))
    files = [path for _, _, path in sorted(rotated)]
    live = directory / f"{CAN_BASENAME}.{fmt}"
    if live.exists():
        files.append(live)
    return files


def read_can_log(directory: str | os.PathLike[str], fmt: str = "blf") -> list[can.Message]:
    """Every frame of a run's CAN log in one format, across rotated files, via ``can.LogReader``."""
    frames: list[can.Message] = []
    # ASC stores times relative to its header date unless asked for absolute ones.
    options = {"relative_timestamp": False} if fmt == "asc" else {}
    for path in can_log_files(directory, fmt):
        # A killed run can end mid-container: keep every frame before the torn end.
        with (
            contextlib.suppress(struct.error, can.io.blf.BLFParseError, ValueError),
            can.LogReader(path, **options) as reader,
        ):
            for message in reader:
                frames.append(message)
    return frames


def create_private(path: str | os.PathLike[str]) -> None:
    """Create (or truncate) ``path`` as an empty file only its owner can read (0600).

    python-can's writers open their files by name; creating them first fixes the mode
    (``open`` keeps an existing file's mode). Only a regular file is chmod-ed: a test's
    symlink to ``/dev/full`` must not change the device.
    """
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, FILE_MODE)
    try:
        if stat.S_ISREG(os.fstat(fd).st_mode):
            os.fchmod(fd, FILE_MODE)
    finally:
        os.close(fd)


class _Sink:
    """One run-log file written through an in-memory buffer, cut back to whole rows on failure.

    The writer thread appends each row (csv) or frame (tlog) to a list, one ``write`` call
    each, the cheapest thing it can do per event (it shares the interpreter lock with the
    scheduler); :meth:`flush` joins and writes them with ``os.write``. When a write fails
    (ENOSPC, EFBIG, EIO) the file is truncated after the last whole record that reached the
    disk, closed, and refuses further data (:attr:`error`).
    """

    def __init__(self, path: Path, text: bool) -> None:
        create_private(path)
        self.path = path
        self._fd: int | None = os.open(path, os.O_WRONLY | os.O_APPEND)
        self._text = text
        self._parts: list[Any] = []
        self._pending = 0  # characters or bytes in _parts
        self.good_size = 0
        self.error: OSError | None = None

    def write(self, data: str | bytes) -> None:
        if self.error is not None:
            raise self.error
        self._parts.append(data)
        self._pending += len(data)
        if self._pending >= _BUFFER_LIMIT:
            self.flush()

    def flush(self) -> None:
        if self._fd is None or not self._parts:
            return
        data = "".join(self._parts).encode("utf-8") if self._text else b"".join(self._parts)
        view = memoryview(data)
        written = 0
        try:
            while written < len(view):
                written += os.write(self._fd, view[written:])
        except OSError as exc:
            self.good_size += self._whole_records(data, written)
            self._fail(exc)
            raise
        self.good_size += len(data)
        self._parts.clear()
        self._pending = 0

    def _whole_records(self, data: bytes, written: int) -> int:
        """Bytes of ``data`` up to the end of the last record within its first ``written``."""
        if self._text:
            return data.rfind(b"\n", 0, written) + 1
        end = 0
        for part in self._parts:
            if end + len(part) > written:
                break
            end += len(part)
        return end

    def _fail(self, exc: OSError) -> None:
        self.error = exc
        self._parts.clear()
        self._pending = 0
        fd, self._fd = self._fd, None
        if fd is not None:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, self.good_size)
            with contextlib.suppress(OSError):
                os.close(fd)

    def close(self) -> None:
        try:
            self.flush()
        finally:
            fd, self._fd = self._fd, None
            if fd is not None:
                os.close(fd)


def _cut_after_last_newline(path: Path, floor: int, chunk: int = 64 * 1024) -> None:
    """Truncate a regular text file after its last newline at or beyond ``floor`` bytes."""
    if not stat.S_ISREG(os.stat(path).st_mode):
        return
    with open(path, "rb+") as handle:
        end = handle.seek(0, os.SEEK_END)
        while end > floor:
            start = max(floor, end - chunk)
            handle.seek(start)
            newline = handle.read(end - start).rfind(b"\n")
            if newline >= 0:
                handle.truncate(start + newline + 1)
                return
            end = start
        handle.truncate(floor)


def _file_writer(writer: can.io.generic.MessageWriter) -> FileIOMessageWriter[Any]:
    """The rotating logger's writer as the file writer it is: every format it rotates (asc,
    blf, csv, log, txt) writes a file, whose ``file`` is flushed and measured here."""
    if not isinstance(writer, FileIOMessageWriter):
        raise TypeError(f"can log: {type(writer).__name__} does not write a file")
    return writer


def _blf_pending(writer: object) -> int | None:
    """Bytes a BLF writer holds for its next container; None for other writers.

    ``_buffer_size`` is python-can's private attribute (4.3-4.6), read by name because a
    version without it must not break logging: its containers then reach the disk at stop.
    """
    value = getattr(writer, "_buffer_size", None)
    return value if isinstance(value, int) else None


class _CanLog(can.SizedRotatingLogger):
    """python-can's size-rotating logger with private files and a flush that reaches the disk.

    BLF (python-can's :class:`can.BLFWriter`) buffers frames into 128 KiB containers and writes
    its header, which holds the start time every frame is relative to, only at ``stop``: a
    killed run lost the last ~5 s and read back with times from 1970. :meth:`flush` writes the
    pending container and rewrites the header (wall-clock start, size, object count) each
    second, using the writer's ``_flush``/``_write_header`` (python-can 4.3-4.6; a writer
    without them is flushed at stop only, as before). On a failed write the file is cut back
    to its last whole line (text formats) or container (BLF) on disk, and the logger stops.
    """

    def __init__(self, base_filename: Path, max_bytes: int, start_wall: float) -> None:
        self._start_wall = start_wall
        self.good_size = 0
        self.error: OSError | None = None
        super().__init__(base_filename=base_filename, max_bytes=max_bytes)

    def _get_new_writer(self, filename: Any) -> Any:
        create_private(filename)
        writer = _file_writer(super()._get_new_writer(filename))
        if isinstance(writer, can.BLFWriter) and hasattr(writer, "_write_header"):
            # relative times count from the run's start, to the millisecond BLF stores
            writer.start_timestamp = int(self._start_wall * 1000) / 1000
            self._rewrite_blf_header(writer)
        writer.file.flush()  # the header on disk: a file cut back on failure keeps it
        self.good_size = writer.file.tell()
        return writer

    @staticmethod
    def _rewrite_blf_header(writer: Any) -> None:
        end = writer.file.tell()
        writer.file.seek(0)
        writer._write_header(max(end, 144))  # 144: BLF's file header size
        writer.file.seek(end)

    def on_message_received(self, msg: can.Message) -> None:
        writer = _file_writer(self.writer)
        pending = _blf_pending(writer)  # BLF: bytes waiting for a container
        try:
            super().on_message_received(msg)
            after = _blf_pending(writer)
            wrote_container = pending is not None and after is not None and after < pending
            if self.writer is writer and wrote_container:
                # BLF just wrote a container: put it on disk, so a failure keeps it
                writer.file.flush()
                self.good_size = writer.file.tell()
        except OSError as exc:
            self._fail(exc)
            raise

    def flush(self) -> None:
        """Everything handed in so far onto the disk (the BLF header made current)."""
        if self.error is not None:
            return
        writer = _file_writer(self.writer)
        try:
            if isinstance(writer, can.BLFWriter) and hasattr(writer, "_flush"):
                writer._flush()
                self._rewrite_blf_header(writer)
            writer.file.flush()
            self.good_size = writer.file.tell()
        except OSError as exc:
            self._fail(exc)
            raise

    def _fail(self, exc: OSError) -> None:
        """Close the file (not ``stop()``: no end block) and cut it back to the last flush.

        By name, after closing: the file object still holds the tail that failed, and closing
        tries to write it once more (it may partly succeed under a size limit).
        """
        self.error = exc
        blf = isinstance(self.writer, can.BLFWriter)
        with contextlib.suppress(Exception):
            _file_writer(self.writer).file.close()
        with contextlib.suppress(OSError):
            if blf:  # cut after the last container known to be on disk
                os.truncate(self.base_filename, self.good_size)
            else:  # text formats: keep every whole line that reached the disk
                _cut_after_last_newline(Path(self.base_filename), self.good_size)

    def stop(self) -> None:
        if self.error is None:
            super().stop()


def _versions() -> dict[str, str]:
    versions = {"python": platform.python_version(), "python-can": can.__version__}
    with contextlib.suppress(Exception):
        import mavservo

        versions["mavservo"] = mavservo.__version__
    with contextlib.suppress(Exception):
        from importlib.metadata import version

        versions["pymavlink"] = version("pymavlink")
    return versions


class RunLog:
    """Observer that records one run into ``directory`` without ever blocking its callers.

    ``buses`` maps each bus name to facts the report needs (``bitrate``, ``max_load``,
    ``interface``...); each bus also gets a CAN channel number for the log formats (ASC and BLF
    store channels as numbers), recorded in ``run.json``. Unknown buses get the next number.
    ``autostart=False`` leaves the writer thread stopped until :meth:`start` (useful to test
    what happens when the writer falls behind).
    """

    def __init__(
        self,
        directory: str | os.PathLike[str],
        formats: Iterable[str] = ("asc", "blf"),
        rotate_bytes: int = 50 * 1024 * 1024,
        *,
        buses: Mapping[str, Mapping[str, Any]] | None = None,
        servos: Mapping[str, Mapping[str, Any]] | None = None,
        config_path: str | os.PathLike[str] | None = None,
        tlog: bool = True,
        queue_size: int = 50_000,
        latency_window: int = 4096,
        header: Mapping[str, Any] | None = None,
        autostart: bool = True,
        max_run_bytes: int = DEFAULT_MAX_RUN_BYTES,
        on_problem: Callable[[str], None] | None = None,
        fallback_dir: str | os.PathLike[str] | None = None,
        can_frames: str = "servos",
    ) -> None:
        if can_frames not in ("all", "servos"):
            raise ValueError(f"can_frames must be 'all' or 'servos', not {can_frames!r}")
        #: ``all``: the CAN logs take every received frame from :meth:`on_bus_frame` (the
        #: bus's tap) and the scheduler's ``on_rx`` adds only the decoded state to the trace;
        #: ``servos``: only the frames the scheduler matched to a servo (``on_rx``).
        self.can_frames = can_frames
        self.directory = Path(directory)
        self.directory.mkdir(mode=DIR_MODE, parents=True, exist_ok=True)
        self.formats = tuple(f.lower().lstrip(".") for f in formats)
        self.rotate_bytes = int(rotate_bytes)
        self._start_wall = time.time()
        self._start_mono = time.monotonic()
        self._offset = self._start_wall - self._start_mono
        self._buses: dict[str, dict[str, Any]] = {}
        for name, info in (buses or {}).items():
            self._bus_entry(name).update(dict(info))
        self._servos = {name: dict(info) for name, info in (servos or {}).items()}
        self._config_path = None if config_path is None else str(config_path)
        self._tlog_enabled = tlog
        self._extra_header = dict(header or {})

        # A deque, not a queue.Queue: append is atomic and wakes nobody, so a caller never
        # waits on a lock or hands the GIL to the writer; the writer polls every _POLL_S.
        self._queue: deque[tuple[Any, ...]] = deque()
        self._queue_size = int(queue_size)
        self._stopping = threading.Event()
        self._drop_lock = threading.Lock()
        self.dropped: Counter[str] = Counter()
        self.written: Counter[str] = Counter()
        self.write_errors = 0
        self.last_error: str | None = None
        self.latency = LatencyTracer(window=latency_window, on_record=self._latency_record)
        self.max_run_bytes = int(max_run_bytes)
        self._on_problem = on_problem
        self._fallback_dir = Path(fallback_dir) if fallback_dir else Path(tempfile.gettempdir())
        self._problems_reported: set[str] = set()
        self.problems: list[str] = []
        self.failed_files: dict[str, str] = {}
        self.capped = False
        self.flushes = 0
        self._outcome: dict[str, Any] = {}

        self._thread: threading.Thread | None = None
        self._closed = False
        self._last_setpoint: dict[str, float] = {}
        self._files: dict[str, _Sink] = {}
        self._csv: dict[str, Any] = {}
        self._can_loggers: list[_CanLog] = []
        self._open_files()
        self._write_header()
        if autostart:
            self.start()

    # -- lifecycle ---------------------------------------------------------------------------

    @property
    def wall_offset(self) -> float:
        """``time.time() - time.monotonic()`` captured at start: monotonic t + offset = wall."""
        return self._offset

    def start(self) -> None:
        """Start the writer thread (idempotent)."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="mavservo-runlog", daemon=True)
            self._thread.start()

    def close(self, metrics: Mapping[str, Any] | None = None, timeout: float = 10.0) -> None:
        """Drain the queue, close every file and write ``metrics.json`` (with ``metrics`` in it)."""
        if self._closed:
            return
        self._closed = True
        self.latency.close_open()
        self.start()
        assert self._thread is not None
        self._stopping.set()  # the writer drains what is queued, then returns
        self._thread.join(timeout)
        self._close_files()
        header_error = self._write_header(end_wall=time.time())
        if header_error is not None:
            self._report("header", f"cannot update {RUN_HEADER} at close: {header_error}")
        self._write_metrics(metrics or {})

    def abandon(self, reason: str) -> None:
        """The run never started: keep only ``run.json``, saying why (``start_failed``).

        A failed start (a missing port, ``/dev/null`` as the adapter) left the full set of
        empty files, and ``mavservo report`` drew five empty figures from them without
        saying the run never began. Nothing was recorded, so nothing else is kept."""
        if self._closed:
            return
        self._closed = True
        self._stopping.set()
        if self._thread is not None:
            self._thread.join(_ABANDON_JOIN_S)
        self._close_files()
        created = [sink.path for sink in self._files.values()]
        for fmt in self.formats:
            created += can_log_files(self.directory, fmt)
        for path in created:
            with contextlib.suppress(OSError):
                path.unlink()
        self._extra_header["start_failed"] = reason
        header_error = self._write_header(end_wall=time.time())
        if header_error is not None:
            log.warning("cannot record the failed start in %s: %s", RUN_HEADER, header_error)

    def outcome(self) -> dict[str, Any]:
        """What became of the run log: complete or not, why, and where ``metrics.json`` is."""
        return {
            "complete": not self.problems,
            "problems": list(self.problems),
            "failed_files": dict(self.failed_files),
            "capped": self.capped,
            **self._outcome,
        }

    def __enter__(self) -> RunLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def counters(self) -> dict[str, Any]:
        """Events written and dropped per category, plus writer errors."""
        return {
            "written": dict(self.written),
            "dropped": dict(self.dropped),
            "dropped_total": sum(self.dropped.values()),
            "queue_size": self._queue_size,
            "write_errors": self.write_errors,
            "last_error": self.last_error,
            "failed_files": dict(self.failed_files),
            "capped": self.capped,
            "max_run_bytes": self.max_run_bytes,
        }

    # -- observer interface (called from scheduler / link threads; never blocks) -------------

    def _put(self, item: tuple[Any, ...]) -> None:
        if len(self._queue) < self._queue_size:
            self._queue.append(item)
        else:
            with self._drop_lock:
                self.dropped[_CATEGORY[item[0]]] += 1

    def on_setpoint(self, servo: str, seq: int, angle_deg: float, source: str, t: float) -> None:
        self.latency.on_setpoint(servo, seq, angle_deg, source, t)
        self._put((_SETPOINT, servo, angle_deg, t))

    def on_tx(
        self, bus: str, msg: can.Message, t: float, kind: str, servo: str | None, seq: int | None
    ) -> None:
        self.latency.on_tx(bus, msg, t, kind, servo, seq)
        self._put((_TX, bus, *_frame_fields(msg), t))

    def on_written(self, bus: str, t: float, kind: str, servo: str | None, seq: int | None) -> None:
        """Every command of a write, packed transfers included: the latency's write mark (the
        CAN log has the frames from ``on_tx``)."""
        self.latency.on_written(bus, t, kind, servo, seq)

    def on_rx(
        self, bus: str, msg: can.Message, t: float, servo: str | None, state: ServoState | None
    ) -> None:
        self.latency.on_rx(bus, msg, t, servo, state)
        if self.can_frames == "all":  # the frame itself came through on_bus_frame
            if state is not None:
                self._put((_STATE, servo, state, t))
            return
        self._put((_RX, bus, *_frame_fields(msg), t, servo, state))

    def on_bus_frame(self, bus: str, msg: can.Message, t: float) -> None:
        """Any frame the adapter delivered at ``t`` (a servo's, a foreign node's, one no
        profile accepts, an error frame): into the CAN logs when ``can_frames`` is ``all``."""
        self._put((_BUS_RX, bus, *_frame_fields(msg), t, msg.is_error_frame))

    def on_lost(self, bus: str, servo: str | None, t: float) -> None:
        self.latency.on_lost(bus, servo, t)
        self._put((_LOST, bus, servo, t))

    def on_reject(self, bus: str, reason: Any, raw_bytes: bytes, t: float) -> None:
        self._put(
            (
                _REJECT,
                bus,
                str(reason.value if isinstance(reason, enum.Enum) else reason),
                bytes(raw_bytes),
                t,
            )
        )

    def health_event(
        self, servo: str, check: str, active: bool, figures: Mapping[str, float], t: float
    ) -> None:
        """A health check of ``servo`` started (``active``) or cleared at ``t``: a
        ``trace.csv`` row, event ``health:<check>`` or ``health-cleared:<check>``, with the
        figures it was judged on (mavservo/control/health.py)."""
        self._put((_HEALTH, servo, check, active, dict(figures), t))

    def mavlink_received(self, servo: str, t: float) -> None:
        """The link received a command for ``servo`` at ``t`` (starts its latency trace)."""
        self.latency.mavlink_received(servo, t)

    def telemetry_sent(self, servo: str, t: float) -> None:
        """The link published ``servo``'s state at ``t`` (ends its latency trace)."""
        self.latency.telemetry_sent(servo, t)

    def mavlink_in(self, raw: bytes, t: float) -> None:
        """A raw MAVLink frame received at ``t`` goes to ``mavlink.tlog``."""
        if self._tlog_enabled:
            self._put((_MAV_IN, bytes(raw), t))

    def mavlink_out(self, raw: bytes, t: float) -> None:
        """A raw MAVLink frame sent at ``t`` goes to ``mavlink.tlog``."""
        if self._tlog_enabled:
            self._put((_MAV_OUT, bytes(raw), t))

    def _latency_record(self, trace: CommandTrace) -> None:
        self._put((_LATENCY, trace))  # formatted by the writer, not on the caller's thread

    # -- writer thread -------------------------------------------------------------------------

    def _bus_entry(self, name: str) -> dict[str, Any]:
        entry = self._buses.get(name)
        if entry is None:
            entry = {"channel": len(self._buses)}
            self._buses[name] = entry
        return entry

    def _open_files(self) -> None:
        d = self.directory
        for fmt in self.formats:
            path = d / f"{CAN_BASENAME}.{fmt}"
            self._can_loggers.append(_CanLog(path, self.rotate_bytes, self._start_wall))
        for key, name, columns in (
            ("trace", TRACE_FILE, TRACE_COLUMNS),
            ("latency", LATENCY_FILE, LATENCY_COLUMNS),
        ):
            sink = _Sink(d / name, text=True)
            self._files[key] = sink
            self._csv[key] = csv.writer(sink)
            self._csv[key].writerow(columns)
        self._files["rejections"] = _Sink(d / REJECTIONS_FILE, text=True)
        if self._tlog_enabled:
            self._files["tlog"] = _Sink(d / TLOG_FILE, text=False)

    def _close_files(self) -> None:
        for logger in self._can_loggers:
            try:
                logger.stop()
            except OSError as exc:
                self._file_failed(Path(logger.base_filename).name, exc)
            except Exception:  # noqa: BLE001 - closing goes on with the other files
                log.debug("closing a CAN log failed", exc_info=True)
        for sink in self._files.values():
            try:
                sink.close()
            except OSError as exc:
                self._file_failed(sink.path.name, exc)

    def _flush_all(self) -> None:
        """Every file's buffered data onto the disk; failures are reported, never raised."""
        for logger in self._can_loggers:
            try:
                logger.flush()
            except OSError as exc:
                self._file_failed(Path(logger.base_filename).name, exc)
        for sink in self._files.values():
            try:
                sink.flush()
            except OSError as exc:
                self._file_failed(sink.path.name, exc)
        self.flushes += 1
        self._check_size()

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
            self._report(
                "cap",
                f"run log reached its size cap ({total / 2**20:.0f} MiB >= logging.max_run_mb);"
                " it records nothing more this run (the bridge keeps running)",
            )

    def _file_failed(self, name: str, exc: OSError) -> None:
        """A file stopped working: count it, and say it once per kind of error."""
        if name in self.failed_files:
            return
        self.failed_files[name] = f"{exc.strerror or exc}"
        self.write_errors += 1
        self.last_error = f"{name}: {exc.strerror or exc}"
        kind = errno.errorcode.get(exc.errno or 0, "error")
        self._report(
            kind,
            f"run log: cannot write {name} ({exc.strerror or exc}); that file stops here,"
            " complete up to the last second (the bridge keeps running)",
        )

    def _report(self, kind: str, text: str) -> None:
        """One log line and one ``on_problem`` call per kind of problem; all kept in problems."""
        self.problems.append(text)
        if kind in self._problems_reported:
            log.debug("%s", text)
            return
        self._problems_reported.add(kind)
        log.error("%s", text)
        if self._on_problem is not None:
            try:
                self._on_problem(text)
            except Exception:  # noqa: BLE001 - a broken listener must not stop the writer
                log.debug("on_problem failed", exc_info=True)

    def _run(self) -> None:
        last_flush = time.monotonic()
        while True:
            stopping = self._stopping.is_set()  # read before draining: nothing is left behind
            burst = 0
            while self._queue:
                burst += 1
                if burst % _YIELD_EVERY == 0:
                    # hand the interpreter lock over: a drain of thousands of frames (every
                    # frame of a busy bus) would otherwise hold it a whole switch interval
                    # (5 ms) while the scheduler waits to write its command slot
                    time.sleep(0)
                item = self._queue.popleft()
                if self.capped:
                    self.dropped["cap"] += 1
                    continue
                try:
                    self._write(item)
                    self.written[_CATEGORY[item[0]]] += 1
                except OSError as exc:  # a full disk must not kill the bridge
                    self.dropped["write_failed"] += 1
                    self._file_failed(_failed_name(exc, item), exc)
                except Exception as exc:  # noqa: BLE001 - nor must one odd event
                    self.write_errors += 1
                    self.last_error = f"{type(exc).__name__}: {exc}"
            if stopping:
                return
            self._stopping.wait(_POLL_S)
            now = time.monotonic()
            if now - last_flush >= _FLUSH_EVERY_S:
                last_flush = now
                try:
                    self._flush_all()
                except Exception:  # noqa: BLE001 - the writer thread must outlive any file
                    log.exception("run log flush failed")

    def _write(self, item: tuple[Any, ...]) -> None:
        code = item[0]
        if code in (_TX, _RX, _BUS_RX):
            self._write_frame(item)
        elif code == _STATE:
            _, servo, state, t = item
            self._write_state(servo, state, t)
        elif code == _SETPOINT:
            _, servo, angle, t = item
            self._last_setpoint[servo] = angle
            self._csv["trace"].writerow([f"{t:.6f}", servo, "setpoint", _num(angle)] + [""] * 5)
        elif code == _LOST:
            _, bus, servo, t = item
            setpoint = self._last_setpoint.get(servo)
            row = [f"{t:.6f}", servo or "", "lost", _num(setpoint)] + [""] * 5
            self._csv["trace"].writerow(row)
        elif code == _REJECT:
            _, bus, reason, raw, t = item
            wall = datetime.fromtimestamp(t + self._offset, tz=timezone.utc).isoformat()
            self._files["rejections"].write(f"{wall} {t:.6f} {bus} {reason} {raw.hex(' ')}\n")
        elif code in (_MAV_IN, _MAV_OUT):
            _, raw, t = item
            usec = int((t + self._offset) * 1e6)
            self._files["tlog"].write(struct.pack(">Q", usec) + raw)
        elif code == _LATENCY:
            self._csv["latency"].writerow(item[1].csv_row())
        elif code == _HEALTH:
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

    def _write_frame(self, item: tuple[Any, ...]) -> None:
        code, bus, arb_id, extended, remote, dlc, data, t = item[:8]
        msg = can.Message(
            timestamp=t + self._offset,
            arbitration_id=arb_id,
            is_extended_id=extended,
            is_remote_frame=remote,
            dlc=dlc,
            data=data,
            is_rx=code != _TX,
            is_error_frame=code == _BUS_RX and item[8],
            channel=self._bus_entry(bus)["channel"],
            check=False,
        )
        for logger in self._can_loggers:  # one full CAN log does not stop the others
            if logger.error is not None:
                continue
            try:
                logger.on_message_received(msg)
            except OSError as exc:
                self._file_failed(Path(logger.base_filename).name, exc)
        if code == _RX and item[9] is not None:
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

    # -- header and metrics ----------------------------------------------------------------

    def _write_header(self, end_wall: float | None = None) -> OSError | None:
        header: dict[str, Any] = {
            "format": "mavservo-run",
            "format_version": LOG_FORMAT_VERSION,
            "versions": _versions(),
            "argv": list(sys.argv),
            "config_path": self._config_path,
            "start_wall": self._start_wall,
            "start_wall_iso": datetime.fromtimestamp(self._start_wall, tz=timezone.utc).isoformat(),
            "start_monotonic": self._start_mono,
            "wall_minus_monotonic": self._offset,
            "end_wall": end_wall,
            "can_formats": list(self.formats),
            "rotate_bytes": self.rotate_bytes,
            "max_run_bytes": self.max_run_bytes,
            "buses": self._buses,
            "servos": self._servos,
            **self._extra_header,
        }
        if end_wall is None:  # at start: a failure is start-up's (the caller's) to report
            _write_json_atomic(self.directory / RUN_HEADER, header)
            return None
        try:
            _write_json_atomic(self.directory / RUN_HEADER, header)
        except OSError as exc:
            return exc
        return None

    def _write_metrics(self, metrics: Mapping[str, Any]) -> None:
        """``metrics.json`` in the run directory, else in the fallback directory, else only in
        memory; :meth:`outcome` and the log say which."""
        data = dict(metrics)
        data["runlog"] = self.counters()
        data["latency"] = self.latency.summary()
        data["runlog_problems"] = list(self.problems)
        self._outcome["metrics"] = data
        targets = [
            self.directory / METRICS_FILE,
            self._fallback_dir / f"mavservo-{self.directory.name}-{METRICS_FILE}",
        ]
        errors = []
        for target in targets:
            try:
                _write_json_atomic(target, data)
            except OSError as exc:
                errors.append(f"{target}: {exc.strerror or exc}")
                continue
            self._outcome["metrics_path"] = str(target)
            if errors:
                self._report("metrics", f"{METRICS_FILE} written to {target} ({errors[0]})")
            return
        self._outcome["metrics_path"] = None
        self._report("metrics", f"{METRICS_FILE} could not be written: {'; '.join(errors)}")


def _frame_fields(msg: can.Message) -> tuple[int, bool, bool, int, bytes]:
    """What the CAN logs keep of a frame, copied (the caller may reuse its message)."""
    return (msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame, msg.dlc, bytes(msg.data))


def _num(value: Any) -> str:
    return "" if value is None else f"{float(value):.4f}"


def _faults(value: Any) -> str:
    """Fault flags by name ("STALL|OVER_CURRENT"), empty when none: stable across enum changes."""
    if value is None:
        return ""
    if isinstance(value, enum.Flag):
        return value.name or "" if value else ""
    return str(value) if value else ""


def _failed_name(exc: OSError, item: tuple[Any, ...]) -> str:
    """Which file an event's failed write was for (named by the errno's filename if set)."""
    if exc.filename:
        return Path(exc.filename).name
    return {
        "can": f"{CAN_BASENAME}.*",
        "trace": TRACE_FILE,
        "rejections": REJECTIONS_FILE,
        "mavlink": TLOG_FILE,
        "latency": LATENCY_FILE,
    }[_CATEGORY[item[0]]]


def _write_json_atomic(path: Path, data: Mapping[str, Any]) -> None:
    """Write ``path`` (0600) through a temporary file that never outlives a failure."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    text = json.dumps(data, indent=2, default=str) + "\n"
    try:
        create_private(tmp)
        with open(tmp, "w", encoding="utf-8") as handle:
            handle.write(text)
            handle.flush()
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
