"""Replaying a recorded .tlog into a live MAVLink link, so a real flight drives bench servos.

A .tlog (MAVProxy, Mission Planner, QGC, pymavlink's logfile writer) is a sequence of records:
an 8-byte big-endian microsecond Unix timestamp, then one MAVLink frame exactly as received.
:func:`iter_tlog` walks those records itself rather than through ``mavutil``: it needs the
receive timestamp of every frame and the original bytes, and must not depend on pymavlink's
process-wide MAVLink 1/2 switch. :func:`replay` re-sends the original frame bytes, so source
system/component, sequence numbers and every field stay exactly as recorded.
"""

from __future__ import annotations

import struct
import threading
import time
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mavservo.errors import MavservoError
from mavservo.mavlink import mavlink2, open_connection
from mavservo.sim.autopilot.background import Background
from mavservo.threads import BackgroundLoop

# What the bridge consumes (docs/engineering/architecture.md, mavservo/mavlink/).
BRIDGE_TYPES: frozenset[str] = frozenset(
    {
        "HEARTBEAT",
        "SERVO_OUTPUT_RAW",
        "ACTUATOR_OUTPUT_STATUS",
        "GIMBAL_DEVICE_SET_ATTITUDE",
        "AUTOPILOT_STATE_FOR_GIMBAL_DEVICE",
        "COMMAND_LONG",
        "COMMAND_INT",
        "ATTITUDE",
    }
)

_STX_V1, _STX_V2 = 0xFE, 0xFD
_SIGNED = 0x01


class TlogError(MavservoError, ValueError):
    """The file is not a well-formed tlog at ``offset``."""


def _frame_length(buf: bytes, pos: int) -> int:
    """Total length of the MAVLink frame starting at ``pos`` (header, payload, CRC, signature)."""
    stx = buf[pos]
    if stx == _STX_V2:
        if pos + 3 > len(buf):
            raise TlogError(f"truncated MAVLink 2 header at offset {pos}")
        signed = buf[pos + 2] & _SIGNED
        return 10 + buf[pos + 1] + 2 + (13 if signed else 0)
    if stx == _STX_V1:
        if pos + 2 > len(buf):
            raise TlogError(f"truncated MAVLink 1 header at offset {pos}")
        return 6 + buf[pos + 1] + 2
    raise TlogError(f"no MAVLink start byte at offset {pos} (found 0x{stx:02X})")


def iter_tlog_records(data: bytes) -> Iterator[tuple[int, bytes]]:
    """(timestamp_us, frame bytes) for every record of a tlog held in memory. Raises TlogError."""
    pos = 0
    while pos < len(data):
        if pos + 9 > len(data):
            raise TlogError(f"truncated record at offset {pos}")
        (stamp,) = struct.unpack_from(">Q", data, pos)
        length = _frame_length(data, pos + 8)
        end = pos + 8 + length
        if end > len(data):
            raise TlogError(f"truncated frame at offset {pos + 8}")
        yield stamp, data[pos + 8 : end]
        pos = end


def iter_tlog(
    path: str | Path, types: Collection[str] | None = BRIDGE_TYPES
) -> Iterator[tuple[float, Any]]:
    """Yield ``(t_rel, msg)`` for the messages of ``types`` (None = all) in file order.

    ``t_rel`` is seconds since the file's first record (whatever its type), which matches the
    timelines in tests/data/README.md. ``msg.get_msgbuf()`` returns the original frame bytes.
    Frames that fail their CRC or are unknown to the ardupilotmega dialect are skipped.
    """
    data = Path(path).read_bytes()
    wanted = None if types is None else frozenset(types)
    parser = mavlink2.MAVLink(None)
    parser.robust_parsing = True
    first: int | None = None
    for stamp, frame in iter_tlog_records(data):
        if first is None:
            first = stamp
        for msg in parser.parse_buffer(frame) or ():
            name = msg.get_type()
            if name == "BAD_DATA" or (wanted is not None and name not in wanted):
                continue
            yield (stamp - first) / 1e6, msg


@dataclass
class ReplayResult:
    """What a replay did: how many messages went out, per type, and how long it took."""

    sent: int = 0
    per_type: dict[str, int] = field(default_factory=dict)
    duration_s: float = 0.0
    stopped: bool = False  # ended by ``stop`` or ``max_duration_s`` before the end of the file


def replay(
    path: str | Path,
    url_or_conn: str | Any,
    *,
    speed: float = 1.0,
    as_fast: bool = False,
    types: Collection[str] | None = BRIDGE_TYPES,
    start_s: float = 0.0,
    end_s: float | None = None,
    max_duration_s: float | None = None,
    stop: threading.Event | None = None,
    on_message: Callable[[float, Any], None] | None = None,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> ReplayResult:
    """Send the messages of a .tlog into a MAVLink link, paced like the recording.

    ``speed`` scales time (4 = four times faster); ``as_fast`` ignores the timestamps entirely.
    ``start_s``/``end_s`` cut a window out of the file (seconds from its first record).
    ``max_duration_s`` and ``stop`` bound the run. ``url_or_conn`` is a pymavlink connection
    string (opened and closed here) or an open connection with ``write(bytes)``.
    """
    if speed <= 0:
        raise ValueError("speed must be > 0")
    own = isinstance(url_or_conn, str)
    conn: Any = (
        open_connection(url_or_conn, source_system=255, source_component=0) if own else url_or_conn
    )
    result = ReplayResult()
    began = clock()
    origin: float | None = None
    try:
        for t_rel, msg in iter_tlog(path, types):
            if t_rel < start_s:
                continue
            if end_s is not None and t_rel > end_s:
                break
            if origin is None:
                origin = t_rel
            if not as_fast:
                due = began + (t_rel - origin) / speed
                if max_duration_s is not None and due - began > max_duration_s:
                    result.stopped = True
                    break
                while not (stop is not None and stop.is_set()):
                    remaining = due - clock()
                    if remaining <= 0:
                        break
                    sleep(min(remaining, 0.05))
            elapsed = clock() - began
            if (stop is not None and stop.is_set()) or (
                max_duration_s is not None and elapsed > max_duration_s
            ):
                result.stopped = True
                break
            conn.write(msg.get_msgbuf())
            result.sent += 1
            name = msg.get_type()
            result.per_type[name] = result.per_type.get(name, 0) + 1
            if on_message is not None:
                on_message(t_rel, msg)
    finally:
        result.duration_s = clock() - began
        if own:
            conn.close()
    return result


class ReplayRunner(Background):
    """:func:`replay` on a bounded background thread, with the same start()/stop() as the stream.

    This is what a ``sim`` endpoint with ``profile: replay`` runs inside the bridge process.
    """

    def __init__(self, path: str | Path, url: str, **options: Any) -> None:
        self.path = Path(path)
        self.url = url
        self.options = options
        self.result: ReplayResult | None = None
        self.error: BaseException | None = None
        self._loop = BackgroundLoop(self._run, name="sitl-replay")

    def start(self) -> ReplayRunner:
        if self._loop.started:
            raise RuntimeError("replay already started")
        if not self.path.is_file():
            raise FileNotFoundError(self.path)
        self._loop.start()
        return self

    def _run(self) -> None:
        try:
            self.result = replay(self.path, self.url, stop=self._loop.stop_event, **self.options)
        except Exception as exc:  # surfaced through .error
            self.error = exc
            raise

    def stop(self, timeout: float = 2.0) -> None:
        self._loop.stop(timeout)
