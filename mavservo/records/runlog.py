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

Failure rules (docs/engineering/reliability.md, "Disk full"): the directory is 0700 and every file
0600, whatever the umask (CAN frames and MAVLink traffic are nobody else's business). Every file is
flushed once a second, the BLF one too (a container per second, its header rewritten with the
wall-clock start, so a killed run keeps all but the last second with wall-clock times). A file
that cannot be written (disk full) is cut back to its last complete flush and closed, the
problem is reported once per kind through ``on_problem`` (the bridge's event path: console and
STATUSTEXT) and the log, and the bridge goes on. The whole run is capped at ``max_run_bytes``;
``metrics.json`` is kept in memory and written at close to the run directory or, when that
fails, to ``fallback_dir``; :meth:`RunLog.outcome` says what happened; no ``.tmp`` file is
left behind.

The parts, each with its own job (``RunLog`` owns them and is what callers see): the bounded
queue and writer thread (:mod:`~.event_pump`), the event files (:mod:`~.run_files`, with the
CAN logs in :mod:`~.can_log` and the other files in :mod:`~.sink`), the problem report
(:mod:`~.problems`); ``RunLog`` itself keeps the observer interface, ``run.json`` and
``metrics.json``.
"""

from __future__ import annotations

import contextlib
import enum
import logging
import os
import platform
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import can

# The run directory's names stay importable from here (and the package face) where they were.
from mavservo.records.can_log import CAN_BASENAME, can_log_files, read_can_log
from mavservo.records.event_pump import EventPump
from mavservo.records.latency import CommandTrace, LatencyTracer
from mavservo.records.private_files import DIR_MODE, FILE_MODE, create_private, write_json_atomic
from mavservo.records.problems import RunLogProblems
from mavservo.records.run_events import (
    BUS_RX,
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
    frame_fields,
)
from mavservo.records.run_files import (
    LATENCY_FILE,
    REJECTIONS_FILE,
    TLOG_FILE,
    TRACE_COLUMNS,
    TRACE_FILE,
    RunFiles,
)
from mavservo.servos import ServoState

__all__ = [
    "CAN_BASENAME",
    "DEFAULT_MAX_RUN_BYTES",
    "DIR_MODE",
    "FILE_MODE",
    "LATENCY_FILE",
    "LOG_FORMAT_VERSION",
    "METRICS_FILE",
    "REJECTIONS_FILE",
    "RUN_HEADER",
    "RunLog",
    "TLOG_FILE",
    "TRACE_COLUMNS",
    "TRACE_FILE",
    "can_log_files",
    "create_private",
    "new_run_dir",
    "read_can_log",
]

RUN_HEADER = "run.json"
METRICS_FILE = "metrics.json"
LOG_FORMAT_VERSION = 1
DEFAULT_MAX_RUN_BYTES = 1024 * 1024 * 1024
_ABANDON_JOIN_S = 2.0  # the writer polls every POLL_S; nothing is queued before a start

log = logging.getLogger(__name__)


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
        self._fallback_dir = Path(fallback_dir) if fallback_dir else Path(tempfile.gettempdir())
        self._outcome: dict[str, Any] = {}
        self._closed = False

        self._problems = RunLogProblems(on_problem)
        self.latency = LatencyTracer(window=latency_window, on_record=self._latency_record)
        self._files = RunFiles(
            self.directory,
            self.formats,
            self.rotate_bytes,
            start_wall=self._start_wall,
            offset=self._offset,
            tlog=tlog,
            channel_of=self._bus_channel,
            problems=self._problems,
            max_run_bytes=int(max_run_bytes),
        )
        self._pump = EventPump(self._files, self._problems, queue_size)
        self._put = self._pump.put  # bound once: the callers' hot path is one call deep
        #: events written and dropped per category (the writer thread's counters)
        self.written: Counter[str] = self._pump.written
        self.dropped: Counter[str] = self._pump.dropped
        self._write_header()
        if autostart:
            self.start()

    # -- lifecycle ---------------------------------------------------------------------------

    @property
    def wall_offset(self) -> float:
        """``time.time() - time.monotonic()`` captured at start: monotonic t + offset = wall."""
        return self._offset

    @property
    def problems(self) -> list[str]:
        return self._problems.problems

    @property
    def failed_files(self) -> dict[str, str]:
        return self._problems.failed_files

    @property
    def write_errors(self) -> int:
        return self._problems.write_errors

    @property
    def last_error(self) -> str | None:
        return self._problems.last_error

    @property
    def max_run_bytes(self) -> int:
        """The size the run's files are capped at: the files' own, so a cap set on the run log
        is the one applied at the next size check (not a copy taken at construction)."""
        return self._files.max_run_bytes

    @max_run_bytes.setter
    def max_run_bytes(self, value: int) -> None:
        self._files.max_run_bytes = int(value)

    @property
    def capped(self) -> bool:
        """The run's files reached ``max_run_bytes``: nothing more is recorded."""
        return self._files.capped

    @property
    def flushes(self) -> int:
        return self._files.flushes

    def start(self) -> None:
        """Start the writer thread (idempotent)."""
        self._pump.start()

    def close(self, metrics: Mapping[str, Any] | None = None, timeout: float = 10.0) -> None:
        """Drain the queue, close every file and write ``metrics.json`` (with ``metrics`` in it)."""
        if self._closed:
            return
        self._closed = True
        self.latency.close_open()
        self._pump.start()
        self._pump.stop(timeout)  # the writer drains what is queued, then returns
        self._files.close()
        header_error = self._write_header(end_wall=time.time())
        if header_error is not None:
            self._problems.report("header", f"cannot update {RUN_HEADER} at close: {header_error}")
        self._write_metrics(metrics or {})

    def abandon(self, reason: str) -> None:
        """The run never started: keep only ``run.json``, saying why (``start_failed``).

        A failed start (a missing port, ``/dev/null`` as the adapter) left the full set of
        empty files, and ``mavservo report`` drew five empty figures from them without
        saying the run never began. Nothing was recorded, so nothing else is kept."""
        if self._closed:
            return
        self._closed = True
        self._pump.stop(_ABANDON_JOIN_S)
        self._files.close()
        for path in self._files.created_paths():
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
            "queue_size": self._pump.queue_size,
            "write_errors": self.write_errors,
            "last_error": self.last_error,
            "failed_files": dict(self.failed_files),
            "capped": self.capped,
            "max_run_bytes": self.max_run_bytes,
        }

    # -- observer interface (called from scheduler / link threads; never blocks) -------------

    def on_setpoint(self, servo: str, seq: int, angle_deg: float, source: str, t: float) -> None:
        self.latency.on_setpoint(servo, seq, angle_deg, source, t)
        self._put((SETPOINT, servo, angle_deg, t))

    def on_tx(
        self, bus: str, msg: can.Message, t: float, kind: str, servo: str | None, seq: int | None
    ) -> None:
        self.latency.on_tx(bus, msg, t, kind, servo, seq)
        self._put((TX, bus, *frame_fields(msg), t))

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
                self._put((STATE, servo, state, t))
            return
        self._put((RX, bus, *frame_fields(msg), t, servo, state))

    def on_bus_frame(self, bus: str, msg: can.Message, t: float) -> None:
        """Any frame the adapter delivered at ``t`` (a servo's, a foreign node's, one no
        profile accepts, an error frame): into the CAN logs when ``can_frames`` is ``all``."""
        self._put((BUS_RX, bus, *frame_fields(msg), t, msg.is_error_frame))

    def on_lost(self, bus: str, servo: str | None, t: float) -> None:
        self.latency.on_lost(bus, servo, t)
        self._put((LOST, bus, servo, t))

    def on_reject(self, bus: str, reason: Any, raw_bytes: bytes, t: float) -> None:
        self._put(
            (
                REJECT,
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
        self._put((HEALTH, servo, check, active, dict(figures), t))

    def mavlink_received(self, servo: str, t: float) -> None:
        """The link received a command for ``servo`` at ``t`` (starts its latency trace)."""
        self.latency.mavlink_received(servo, t)

    def telemetry_sent(self, servo: str, t: float) -> None:
        """The link published ``servo``'s state at ``t`` (ends its latency trace)."""
        self.latency.telemetry_sent(servo, t)

    def mavlink_in(self, raw: bytes, t: float) -> None:
        """A raw MAVLink frame received at ``t`` goes to ``mavlink.tlog``."""
        if self._tlog_enabled:
            self._put((MAV_IN, bytes(raw), t))

    def mavlink_out(self, raw: bytes, t: float) -> None:
        """A raw MAVLink frame sent at ``t`` goes to ``mavlink.tlog``."""
        if self._tlog_enabled:
            self._put((MAV_OUT, bytes(raw), t))

    def _latency_record(self, trace: CommandTrace) -> None:
        self._put((LATENCY, trace))  # formatted by the writer, not on the caller's thread

    # -- the writer thread's side ------------------------------------------------------------

    def _bus_entry(self, name: str) -> dict[str, Any]:
        entry = self._buses.get(name)
        if entry is None:
            entry = {"channel": len(self._buses)}
            self._buses[name] = entry
        return entry

    def _bus_channel(self, name: str) -> int:
        """The CAN channel number of bus ``name`` in the logs (a new bus gets the next one)."""
        channel: int = self._bus_entry(name)["channel"]
        return channel

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
            write_json_atomic(self.directory / RUN_HEADER, header)
            return None
        try:
            write_json_atomic(self.directory / RUN_HEADER, header)
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
                write_json_atomic(target, data)
            except OSError as exc:
                errors.append(f"{target}: {exc.strerror or exc}")
                continue
            self._outcome["metrics_path"] = str(target)
            if errors:
                self._problems.report(
                    "metrics", f"{METRICS_FILE} written to {target} ({errors[0]})"
                )
            return
        self._outcome["metrics_path"] = None
        self._problems.report(
            "metrics", f"{METRICS_FILE} could not be written: {'; '.join(errors)}"
        )
