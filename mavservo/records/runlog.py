"""The run log directory writer: what crossed the wire, in formats other tools already read.

A :class:`RunLog` is a scheduler observer (``on_setpoint``, ``on_tx``, ``on_rx``, ``on_lost``,
``on_reject``) plus a MAVLink tap (``mavlink_in`` / ``mavlink_out``) and the latency hooks
(``mavlink_received``, ``telemetry_sent``). Those methods are called from the scheduler's and the
link's threads, so they only put a small tuple on a bounded queue; one writer thread does all the
file I/O. When the disk cannot keep up the queue fills and new events are dropped and counted:
a slow disk costs log lines, never command slots. The counts land in ``metrics.json``.

Directory layout (see ``docs/logs.md``)::

    run.json         header: versions, config path, start wall time, monotonic->wall offset, buses
    can.asc/.blf     every TX and RX CAN frame (python-can writers, rotated by size)
    rejections.log   decoder rejections with the offending bytes
    trace.csv        setpoints and decoded servo states, for the report's figures
    latency.csv      one row per command, stage by stage (mavservo.records.latency)
    mavlink.tlog     MAVLink in and out, 8-byte big-endian usec wall timestamp + raw frame
    metrics.json     written at close: scheduler metrics, latency summary, log counters

Times handed in are ``time.monotonic()`` seconds; the files carry wall-clock time, computed with
the offset captured once at start (and stored in ``run.json`` so a reader can go back).
"""

from __future__ import annotations

import contextlib
import csv
import enum
import json
import os
import platform
import re
import struct
import sys
import threading
import time
from collections import Counter, deque
from collections.abc import Iterable, Mapping
from datetime import datetime, timezone
from pathlib import Path
from typing import IO, Any

import can

from mavservo.records.latency import CSV_COLUMNS as LATENCY_COLUMNS
from mavservo.records.latency import CommandTrace, LatencyTracer

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

# Event codes on the queue (small ints keep the tuples cheap to build on the caller's thread).
_TX, _RX, _SETPOINT, _LOST, _REJECT, _MAV_IN, _MAV_OUT, _LATENCY = range(8)
_CATEGORY = {
    _TX: "can",
    _RX: "can",
    _SETPOINT: "trace",
    _LOST: "trace",
    _REJECT: "rejections",
    _MAV_IN: "mavlink",
    _MAV_OUT: "mavlink",
    _LATENCY: "latency",
}


def new_run_dir(base: str | os.PathLike[str], now: float | None = None) -> Path:
    """Create and return a fresh ``base/YYYYmmdd-HHMMSS[-n]`` directory for one run."""
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(time.time() if now is None else now))
    base_path = Path(base)
    base_path.mkdir(parents=True, exist_ok=True)
    for n in range(1000):
        candidate = base_path / (stamp if n == 0 else f"{stamp}-{n}")
        try:
            candidate.mkdir()
        except FileExistsError:
            continue
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
        with can.LogReader(path, **options) as reader:
            frames.extend(reader)
    return frames


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
    ) -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
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

        self._thread: threading.Thread | None = None
        self._closed = False
        self._last_setpoint: dict[str, float] = {}
        self._files: dict[str, IO[Any]] = {}
        self._csv: dict[str, Any] = {}
        self._can_loggers: list[can.io.BaseRotatingLogger] = []
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
        self._write_header(end_wall=time.time())
        self._write_metrics(metrics or {})

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
        self._put(
            (
                _TX,
                bus,
                msg.arbitration_id,
                msg.is_extended_id,
                msg.is_remote_frame,
                msg.dlc,
                bytes(msg.data),
                t,
            )
        )

    def on_rx(self, bus: str, msg: can.Message, t: float, servo: str | None, state: Any) -> None:
        self.latency.on_rx(bus, msg, t, servo, state)
        self._put(
            (
                _RX,
                bus,
                msg.arbitration_id,
                msg.is_extended_id,
                msg.is_remote_frame,
                msg.dlc,
                bytes(msg.data),
                t,
                servo,
                state,
            )
        )

    def on_lost(self, bus: str, servo: str | None, t: float) -> None:
        self.latency.on_lost(bus, servo, t)
        self._put((_LOST, bus, servo, t))

    def on_reject(self, bus: str, reason: Any, raw_bytes: bytes, t: float) -> None:
        self._put((_REJECT, bus, str(getattr(reason, "value", reason)), bytes(raw_bytes), t))

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
            logger = can.SizedRotatingLogger(
                base_filename=d / f"{CAN_BASENAME}.{fmt}", max_bytes=self.rotate_bytes
            )
            self._can_loggers.append(logger)
        for key, name, columns in (
            ("trace", TRACE_FILE, TRACE_COLUMNS),
            ("latency", LATENCY_FILE, LATENCY_COLUMNS),
        ):
            handle = open(d / name, "w", newline="", encoding="utf-8")  # noqa: SIM115
            self._files[key] = handle
            self._csv[key] = csv.writer(handle)
            self._csv[key].writerow(columns)
        self._files["rejections"] = open(d / REJECTIONS_FILE, "w", encoding="utf-8")  # noqa: SIM115
        if self._tlog_enabled:
            self._files["tlog"] = open(d / TLOG_FILE, "wb")  # noqa: SIM115

    def _close_files(self) -> None:
        for logger in self._can_loggers:
            with contextlib.suppress(Exception):
                logger.stop()
        for handle in self._files.values():
            with contextlib.suppress(Exception):
                handle.close()

    def _run(self) -> None:
        last_flush = time.monotonic()
        while True:
            stopping = self._stopping.is_set()  # read before draining: nothing is left behind
            while self._queue:
                item = self._queue.popleft()
                try:
                    self._write(item)
                    self.written[_CATEGORY[item[0]]] += 1
                except Exception as exc:  # a full disk must not kill the bridge
                    self.write_errors += 1
                    self.last_error = f"{type(exc).__name__}: {exc}"
            if stopping:
                return
            self._stopping.wait(_POLL_S)
            now = time.monotonic()
            if now - last_flush >= _FLUSH_EVERY_S:
                last_flush = now
                for handle in self._files.values():
                    with contextlib.suppress(Exception):
                        handle.flush()

    def _write(self, item: tuple[Any, ...]) -> None:
        code = item[0]
        if code in (_TX, _RX):
            self._write_frame(item)
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

    def _write_frame(self, item: tuple[Any, ...]) -> None:
        code, bus, arb_id, extended, remote, dlc, data, t = item[:8]
        msg = can.Message(
            timestamp=t + self._offset,
            arbitration_id=arb_id,
            is_extended_id=extended,
            is_remote_frame=remote,
            dlc=dlc,
            data=data,
            is_rx=code == _RX,
            channel=self._bus_entry(bus)["channel"],
            check=False,
        )
        for logger in self._can_loggers:
            logger.on_message_received(msg)
        if code == _RX and item[9] is not None:
            servo, state = item[8], item[9]
            self._csv["trace"].writerow(
                [
                    f"{t:.6f}",
                    servo or "",
                    "state",
                    _num(self._last_setpoint.get(servo)),
                    _num(getattr(state, "position_deg", None)),
                    _num(getattr(state, "velocity_dps", None)),
                    _num(getattr(state, "current_a", None)),
                    _num(getattr(state, "temperature_c", None)),
                    _faults(getattr(state, "faults", None)),
                ]
            )

    # -- header and metrics ----------------------------------------------------------------

    def _write_header(self, end_wall: float | None = None) -> None:
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
            "buses": self._buses,
            "servos": self._servos,
            **self._extra_header,
        }
        _write_json_atomic(self.directory / RUN_HEADER, header)

    def _write_metrics(self, metrics: Mapping[str, Any]) -> None:
        data = dict(metrics)
        data["runlog"] = self.counters()
        data["latency"] = self.latency.summary()
        _write_json_atomic(self.directory / METRICS_FILE, data)


def _num(value: Any) -> str:
    return "" if value is None else f"{float(value):.4f}"


def _faults(value: Any) -> str:
    """Fault flags by name ("STALL|OVER_CURRENT"), empty when none: stable across enum changes."""
    if value is None:
        return ""
    if isinstance(value, enum.Flag):
        return value.name or "" if value else ""
    return str(value) if value else ""


def _write_json_atomic(path: Path, data: Mapping[str, Any]) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, default=str) + "\n", encoding="utf-8")
    os.replace(tmp, path)
