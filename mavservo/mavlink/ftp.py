"""A read-only MAVLink FTP server for the few files a component serves (its metadata).

Why: QGroundControl learns a component's parameter names, units, ranges and descriptions from
the files COMPONENT_METADATA (397) points at, and reads them over MAVLink FTP. The bridge has
such files in memory (built from the config at start); this module serves exactly those, and
nothing else: there is no file system behind it, so no path, however crafted, reaches a file the
bridge did not hand it.

Protocol (https://mavlink.io/en/services/ftp.html, "Payload", "Opcodes", "NAK error codes"):
the FILE_TRANSFER_PROTOCOL payload is a 12-byte header (``seq`` u16, ``session`` u8, ``opcode``
u8, ``size`` u8, ``req_opcode`` u8, ``burst_complete`` u8, padding u8, ``offset`` u32, all
little-endian) and up to 239 data bytes. A reply carries the request's sequence number + 1,
``req_opcode`` = the request's opcode, and ACK (128) or NAK (129, data[0] = the error code).
Served: ResetSessions, TerminateSession, ListDirectory (the root only), OpenFileRO, ReadFile,
BurstReadFile, CalcFileCRC32. Every opcode that writes answers NAK FileProtected; any other
opcode NAK UnknownCommand; an ACK or NAK sent to us is not answered (two servers never ping-pong).

Bounds (whatever a stranger sends): at most :data:`MAX_SESSIONS` open sessions,
:data:`MAX_SESSIONS_PER_SENDER` per sender, each closed after :data:`SESSION_IDLE_S` without a
request; at most :data:`MAX_QUEUED` replies waiting; a burst is at most
:data:`BURST_PACKETS` packets; and every byte this server sends is paced: at most
``bytes_per_s`` over every 1-second window (frames as they go on the wire; a sliding window, not
an average: a radio's buffer is small), so a transfer takes a share of the link, never the
link. Sans-I/O: requests and the time come in, reply payloads go out.
"""

from __future__ import annotations

import struct
import zlib
from collections import Counter, deque
from collections.abc import Mapping
from dataclasses import dataclass, field

from mavservo.mavlink.origin import Requester

#: The header, as the MAVLink FTP page lays it out.
HEADER = struct.Struct("<HBBBBBBI")
HEADER_BYTES = HEADER.size  # 12
#: FILE_TRANSFER_PROTOCOL.payload is 251 bytes: header + data.
PAYLOAD_BYTES = 251
MAX_DATA = PAYLOAD_BYTES - HEADER_BYTES  # 239
#: MAVLink 2 framing around a payload (header 10 + checksum 2) and FILE_TRANSFER_PROTOCOL's
#: fixed fields before the payload (target_network, target_system, target_component).
FRAME_OVERHEAD = 12 + 3

# opcodes (MAVLink FTP, "Opcodes")
OP_NONE = 0
OP_TERMINATE_SESSION = 1
OP_RESET_SESSIONS = 2
OP_LIST_DIRECTORY = 3
OP_OPEN_FILE_RO = 4
OP_READ_FILE = 5
OP_CREATE_FILE = 6
OP_WRITE_FILE = 7
OP_REMOVE_FILE = 8
OP_CREATE_DIRECTORY = 9
OP_REMOVE_DIRECTORY = 10
OP_OPEN_FILE_WO = 11
OP_TRUNCATE_FILE = 12
OP_RENAME = 13
OP_CALC_FILE_CRC32 = 14
OP_BURST_READ_FILE = 15
OP_ACK = 128
OP_NAK = 129
WRITE_OPS = frozenset(
    {
        OP_CREATE_FILE,
        OP_WRITE_FILE,
        OP_REMOVE_FILE,
        OP_CREATE_DIRECTORY,
        OP_REMOVE_DIRECTORY,
        OP_OPEN_FILE_WO,
        OP_TRUNCATE_FILE,
        OP_RENAME,
    }
)

# NAK error codes (MAVLink FTP, "NAK error codes")
ERR_FAIL = 1
ERR_INVALID_DATA_SIZE = 3
ERR_INVALID_SESSION = 4
ERR_NO_SESSIONS_AVAILABLE = 5
ERR_EOF = 6
ERR_UNKNOWN_COMMAND = 7
ERR_FILE_PROTECTED = 9
ERR_FILE_NOT_FOUND = 10

#: Sessions cost a name and an offset (the files are in memory): enough of them that squatting
#: takes many spoofed senders (review3: with 4, two senders' four OpenFileRO every 10 s kept
#: every ground station out: NAK NoSessionsAvailable for good).
MAX_SESSIONS = 16
MAX_SESSIONS_PER_SENDER = 2
SESSION_IDLE_S = 10.0
#: When every session is taken, the least recently used one idle this long makes room for a
#: newcomer (a transfer in progress asks far more often; a squatter must keep asking).
SESSION_EVICT_IDLE_S = 1.0
MAX_QUEUED = 16
#: Replies queued for one sender at most: its oldest makes room for its newest. When the queue
#: is full, the sender with the most queued gives up its oldest (review3: one sender's 10
#: requests a second kept the 16-entry queue full at a 1 kB/s budget, every other requester's
#: replies dropped as ``queue_full``).
MAX_QUEUED_PER_SENDER = 4
BURST_PACKETS = 16
#: Without a link budget the server is still paced (a USB link, a monitor output).
UNBUDGETED_BYTES_S = 20_000.0

#: Who owns a session and gets its replies: the claimed (system, component) and the origin
#: (address, connection) it spoke from (issue 40: keyed by the ids alone, anyone claiming a
#: station's ids from elsewhere shared its sessions and its reply queue).
Sender = Requester


def crc32(data: bytes) -> int:
    """The CRC32 MAVLink FTP's CalcFileCRC32 and COMPONENT_METADATA.file_crc use (the one of
    zlib, ISO-HDLC; ArduPilot's ``crc_crc32`` and PX4's ``crc32_part`` compute the same)."""
    return zlib.crc32(data) & 0xFFFFFFFF


def normalize_path(raw: bytes) -> str | None:
    """A request's path as a served name (``/general.json`` -> ``general.json``), or None.

    Only printable ASCII; the first NUL ends it; leading slashes go. No ``..``, no directory:
    names are looked up in a table, never on a disk, so this only makes equal names equal."""
    text = raw.split(b"\x00", 1)[0]
    if not text or any(b < 0x20 or b > 0x7E for b in text):
        return None
    return text.decode("ascii").lstrip("/")


class ByteWindow:
    """At most ``bytes_per_s`` in every 1-second window (sliding, not an average): one per
    link, shared by every component's server, so two components' transfers take the share
    once. The allowance is at least one full frame, or nothing could ever go."""

    def __init__(self, bytes_per_s: float) -> None:
        full_frame = float(frame_bytes(bytes([1]) * PAYLOAD_BYTES))
        self.allowance = max(1.0, float(bytes_per_s), full_frame)
        self._sent: deque[tuple[float, int]] = deque()
        self._total = 0

    def fits(self, size: int, now: float) -> bool:
        while self._sent and now - self._sent[0][0] >= 1.0:
            self._total -= self._sent.popleft()[1]
        return self._total + size <= self.allowance

    def take(self, size: int, now: float) -> None:
        self._sent.append((now, size))
        self._total += size


@dataclass
class _Burst:
    offset: int
    chunk: int
    seq: int
    left: int


@dataclass
class _Session:
    number: int
    owner: Sender
    name: str
    last_used: float
    burst: _Burst | None = None


@dataclass
class FtpServer:
    """The FTP server of one component. ``files``: served name -> content (read-only)."""

    files: Mapping[str, bytes]
    bytes_per_s: float = UNBUDGETED_BYTES_S
    #: the link's window, when several servers share one link (else the server's own)
    window: ByteWindow | None = None
    counters: Counter[str] = field(default_factory=Counter)
    _sessions: dict[int, _Session] = field(default_factory=dict)
    _queue: deque[tuple[Sender, bytes]] = field(default_factory=deque)
    _next_burst: int = 0

    def __post_init__(self) -> None:
        for name in self.files:
            if normalize_path(name.encode("ascii")) != name:
                raise ValueError(f"served name {name!r} is not a plain ASCII name")
        self.files = dict(self.files)
        self.bytes_per_s = max(1.0, float(self.bytes_per_s))
        if self.window is None:
            self.window = ByteWindow(self.bytes_per_s)

    # ------------------------------------------------------------------ input

    def handle(self, payload: bytes, sender: Sender, now: float) -> None:
        """One request; its answer is queued and goes out through :meth:`periodic`."""
        self._expire(now)
        self.counters["requests"] += 1
        if len(payload) < HEADER_BYTES:
            self.counters["too_short"] += 1
            return
        seq, session, opcode, size, _req, _burst, _pad, offset = HEADER.unpack_from(payload)
        data = bytes(payload[HEADER_BYTES : HEADER_BYTES + min(size, MAX_DATA)])
        if opcode in (OP_ACK, OP_NAK):
            self.counters["ack_ignored"] += 1
            return
        request = _Request(seq, session, opcode, size, offset, data, sender)
        if size > MAX_DATA:
            self._nak(request, ERR_INVALID_DATA_SIZE)
            return
        handler = _HANDLERS.get(opcode)
        if handler is not None:
            handler(self, request, now)
        elif opcode in WRITE_OPS:
            self._nak(request, ERR_FILE_PROTECTED)
        else:
            self._nak(request, ERR_UNKNOWN_COMMAND)

    def _reset(self, request: _Request, now: float) -> None:
        """ResetSessions: the sender's own sessions only (a stranger cannot end ours)."""
        for number in [n for n, s in self._sessions.items() if s.owner == request.sender]:
            del self._sessions[number]
        self._ack(request, request.session)

    def _terminate(self, request: _Request, now: float) -> None:
        if self._owned(request) is None:
            return
        del self._sessions[request.session]
        self._ack(request, request.session)

    def _list(self, request: _Request, now: float) -> None:
        path = normalize_path(request.data)
        if path not in ("", "."):
            self._nak(request, ERR_FILE_NOT_FOUND)
            return
        entries = [
            f"F{name}\t{len(content)}".encode("ascii") for name, content in self.files.items()
        ]
        if request.offset >= len(entries):
            self._nak(request, ERR_EOF)
            return
        data = b""
        for entry in entries[request.offset :]:
            if len(data) + len(entry) + 1 > MAX_DATA:
                break
            data += entry + b"\x00"
        self._ack(request, request.session, data=data, offset=request.offset)

    def _open(self, request: _Request, now: float) -> None:
        name = normalize_path(request.data)
        if name is None or name not in self.files:
            self.counters["not_found"] += 1
            self._nak(request, ERR_FILE_NOT_FOUND)
            return
        mine = [s for s in self._sessions.values() if s.owner == request.sender]
        if len(self._sessions) >= MAX_SESSIONS and len(mine) < MAX_SESSIONS_PER_SENDER:
            self._evict_idle(now)
        if len(self._sessions) >= MAX_SESSIONS or len(mine) >= MAX_SESSIONS_PER_SENDER:
            self.counters["no_session"] += 1
            self._nak(request, ERR_NO_SESSIONS_AVAILABLE)
            return
        number = next(n for n in range(MAX_SESSIONS) if n not in self._sessions)
        self._sessions[number] = _Session(number, request.sender, name, now)
        self.counters["opened"] += 1
        size = len(self.files[name]).to_bytes(4, "little")
        self._ack(request, number, data=size)

    def _read(self, request: _Request, now: float) -> None:
        session = self._owned(request)
        if session is None:
            return
        session.last_used = now
        content = self.files[session.name]
        if request.offset >= len(content):
            self._nak(request, ERR_EOF)
            return
        data = content[request.offset : request.offset + min(request.size, MAX_DATA)]
        self.counters["read_bytes"] += len(data)
        self._ack(request, session.number, data=data, offset=request.offset)

    def _burst(self, request: _Request, now: float) -> None:
        session = self._owned(request)
        if session is None:
            return
        session.last_used = now
        if request.offset >= len(self.files[session.name]):
            session.burst = None
            self._nak(request, ERR_EOF)
            return
        chunk = min(request.size, MAX_DATA) or MAX_DATA
        # a repeated request (the client's retry) replaces the burst in progress
        session.burst = _Burst(request.offset, chunk, (request.seq + 1) & 0xFFFF, BURST_PACKETS)

    def _crc(self, request: _Request, now: float) -> None:
        name = normalize_path(request.data)
        if name is None or name not in self.files:
            self._nak(request, ERR_FILE_NOT_FOUND)
            return
        self._ack(request, request.session, data=crc32(self.files[name]).to_bytes(4, "little"))

    def _none(self, request: _Request, now: float) -> None:
        self._ack(request, request.session)

    def _owned(self, request: _Request) -> _Session | None:
        """The request's session when the sender opened it; else NAK InvalidSession."""
        session = self._sessions.get(request.session)
        if session is None or session.owner != request.sender:
            self.counters["invalid_session"] += 1
            self._nak(request, ERR_INVALID_SESSION)
            return None
        return session

    def _evict_idle(self, now: float) -> None:
        """The least recently used session, if idle :data:`SESSION_EVICT_IDLE_S`, goes."""
        oldest = min(self._sessions.values(), key=lambda s: s.last_used)
        if now - oldest.last_used >= SESSION_EVICT_IDLE_S:
            del self._sessions[oldest.number]
            self.counters["evicted"] += 1

    def _expire(self, now: float) -> None:
        for number in [n for n, s in self._sessions.items() if now - s.last_used > SESSION_IDLE_S]:
            del self._sessions[number]
            self.counters["expired"] += 1

    # ------------------------------------------------------------------ replies

    def _ack(self, request: _Request, session: int, *, data: bytes = b"", offset: int = 0) -> None:
        self._queue_reply(
            request.sender,
            _reply((request.seq + 1) & 0xFFFF, session, OP_ACK, request.opcode, offset, data),
        )

    def _nak(self, request: _Request, error: int) -> None:
        self.counters[f"nak_{error}"] += 1
        self._queue_reply(
            request.sender,
            _reply(
                (request.seq + 1) & 0xFFFF,
                request.session,
                OP_NAK,
                request.opcode,
                request.offset,  # a client matches a burst's EOF to its offset (mavftp)
                bytes([error]),
            ),
        )

    def _queue_reply(self, sender: Sender, payload: bytes) -> None:
        """Queue a reply; a sender's own oldest makes room beyond its share, and a full queue
        takes room from the sender with the most queued (never from a quiet requester)."""
        per_sender = Counter(owner for owner, _ in self._queue)
        if per_sender[sender] >= MAX_QUEUED_PER_SENDER:
            self._drop_oldest_of(sender)
        elif len(self._queue) >= MAX_QUEUED:
            self._drop_oldest_of(max(per_sender, key=lambda owner: per_sender[owner]))
        self._queue.append((sender, payload))

    def _drop_oldest_of(self, sender: Sender) -> None:
        for index, (owner, _) in enumerate(self._queue):
            if owner == sender:
                del self._queue[index]
                self.counters["queue_full"] += 1
                return

    # ------------------------------------------------------------------ time

    def periodic(self, now: float) -> list[tuple[Sender, bytes]]:
        """Replies due at ``now`` within the byte rate: queued answers first, then burst data
        of the open sessions in turn. Each is (the requester, the 251-byte payload)."""
        self._expire(now)
        window = self.window
        assert window is not None
        out: list[tuple[Sender, bytes]] = []
        while True:
            item = self._queue[0] if self._queue else self._next_burst_packet(peek=True)
            if item is None or not window.fits(frame_bytes(item[1]), now):
                return out
            if self._queue:
                self._queue.popleft()
            else:
                self._next_burst_packet(peek=False)
            window.take(frame_bytes(item[1]), now)
            self.counters["sent_bytes"] += frame_bytes(item[1])
            out.append(item)

    def _next_burst_packet(self, *, peek: bool) -> tuple[Sender, bytes] | None:
        bursting = [s for s in self._sessions.values() if s.burst is not None]
        if not bursting:
            return None
        session = bursting[self._next_burst % len(bursting)]
        burst = session.burst
        assert burst is not None
        content = self.files[session.name]
        data = content[burst.offset : burst.offset + burst.chunk]
        last = burst.left == 1 or burst.offset + len(data) >= len(content)
        payload = _reply(
            burst.seq, session.number, OP_ACK, OP_BURST_READ_FILE, burst.offset, data, last
        )
        if not peek:
            self.counters["burst_bytes"] += len(data)
            burst.offset += len(data)
            burst.seq = (burst.seq + 1) & 0xFFFF
            burst.left -= 1
            if last:
                session.burst = None
            self._next_burst += 1
        return session.owner, payload

    def stats(self) -> dict[str, int]:
        return {**self.counters, "sessions": len(self._sessions), "queued": len(self._queue)}


@dataclass(frozen=True)
class _Request:
    seq: int
    session: int
    opcode: int
    size: int
    offset: int
    data: bytes
    sender: Sender


def _reply(
    seq: int,
    session: int,
    opcode: int,
    req_opcode: int,
    offset: int,
    data: bytes,
    burst_complete: bool = False,
) -> bytes:
    header = HEADER.pack(
        seq, session, opcode, len(data), req_opcode, int(burst_complete), 0, offset
    )
    return (header + data).ljust(PAYLOAD_BYTES, b"\x00")


def frame_bytes(payload: bytes) -> int:
    """Bytes of the frame carrying ``payload`` (MAVLink 2 trims trailing zeros)."""
    return FRAME_OVERHEAD + len(payload.rstrip(b"\x00"))


_HANDLERS = {
    OP_NONE: FtpServer._none,
    OP_TERMINATE_SESSION: FtpServer._terminate,
    OP_RESET_SESSIONS: FtpServer._reset,
    OP_LIST_DIRECTORY: FtpServer._list,
    OP_OPEN_FILE_RO: FtpServer._open,
    OP_READ_FILE: FtpServer._read,
    OP_BURST_READ_FILE: FtpServer._burst,
    OP_CALC_FILE_CRC32: FtpServer._crc,
}
