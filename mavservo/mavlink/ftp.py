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

Repeats and stale replies (as ArduPilot's server, ``GCS_FTP::worker``, ArduPilot master 01d2ac9:
"if it's a rerequest and we still have the last response then send it"): a request repeated with
the same sequence number is answered once: while its reply still waits it is not queued again,
once it went the same reply is re-sent (never recomputed, never a second queued copy). A client
that retries with a new sequence number (MAVSDK's FTP client does, ``mavlink_ftp_client.cpp``
``timeout()``: ``work->payload.seq_number = _last_sent_seq_number++``) makes the reply still
queued for the old one stale: the client only takes the newest sequence (MAVSDK checks
``expected_seq`` strictly, QGroundControl's FTPManager ``_expectedIncomingSeqNumber``), so the
stale copy is dropped, not sent. Ending or resetting a session drops what waits for it.

Who goes first: replies wait per requester and requesters are served in turn (round robin); a
requester whose next reply makes progress (an ACK, an end of file) goes before one whose next
reply is a refusal (NoSessionsAvailable, InvalidSession, ...), so 64 strangers' NAKs never hold a
ground station's read. Burst packets are made one at a time when the link can take them, so a
burst stays inside the budget whatever its length.

Bounds (whatever a stranger sends): at most :data:`MAX_SESSIONS` open sessions,
:data:`MAX_SESSIONS_PER_SENDER` per sender, each closed after :data:`SESSION_IDLE_S` without a
request; at most :data:`MAX_QUEUED` replies waiting (:data:`MAX_QUEUED_PER_SENDER` each) for at
most :data:`MAX_REQUESTERS` requesters; a burst is at most :data:`BURST_PACKETS` packets; every
reply passes the caller's ``admit`` (the link budget) and a sliding 1-second ``bytes_per_s``
window (frames as they go on the wire; without a link budget the only bound). Sans-I/O: requests
and the time come in, reply payloads go out.
"""

from __future__ import annotations

import struct
import zlib
from collections import Counter, OrderedDict, deque
from collections.abc import Callable, Mapping
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
#: Requesters remembered (their queue and last reply): the least recently heard one with
#: nothing queued is forgotten first, so spoofed senders cannot grow the table.
MAX_REQUESTERS = 32
BURST_PACKETS = 16
#: Senders remembered as squatters (a session of theirs closed unread) at most.
MAX_SQUATTERS = 256
#: Without a link budget the server is still paced (a USB link, a monitor output).
UNBUDGETED_BYTES_S = 20_000.0

#: Data bytes of a read reply at least, however slow the link (ArduPilot's own server sends 48
#: on a busy RP2350 USB link: GCS_FTP.cpp, ReadFile and BurstReadFile, ``MIN(..., 48)``).
MIN_CHUNK = 48
#: A read reply's frame is at most this share of the link's budget in bytes (see
#: :func:`chunk_for_budget`).
CHUNK_SHARE = 0.15

#: Who owns a session and gets its replies: the claimed (system, component) and the origin
#: (address, connection) it spoke from (issue 40: keyed by the ids alone, anyone claiming a
#: station's ids from elsewhere shared its sessions and its reply queue).
Sender = Requester
#: A request as the client repeats it: (session, opcode, offset).
_Key = tuple[int, int, int]


def crc32(data: bytes) -> int:
    """The CRC32 of MAVLink FTP's CalcFileCRC32 and COMPONENT_METADATA.file_crc: ArduPilot's
    ``crc_crc32(0, data)`` (libraries/AP_Math/crc.cpp: the reflected 0xEDB88320 table, initial
    value 0, no final XOR; ``AP_Filesystem::crc32`` starts it at 0 for CalcFileCRC32 in
    GCS_FTP.cpp), which MAVSDK computes too (cpp/src/mavsdk/core/crc32.cpp ``Crc32::add``, line
    87, ``val{0}`` in crc32.hpp; compared in mavlink_ftp_client.cpp line 440 for
    ``are_files_identical``, MAVSDK 158e339).

    Not zlib's CRC-32 (ISO-HDLC: initial 0xFFFFFFFF and a final XOR): zlib's register starts at
    the complement of its ``value`` argument and its result is complemented, so starting it at
    0xFFFFFFFF and complementing the result gives the register ArduPilot keeps."""
    return (zlib.crc32(data, 0xFFFFFFFF) ^ 0xFFFFFFFF) & 0xFFFFFFFF


def chunk_for_budget(bytes_per_s: float | None) -> int:
    """Data bytes per ReadFile / BurstReadFile reply on a link budgeted at ``bytes_per_s``.

    Why: a client waits 1,000 ms for each reply (QGroundControl's FTPManager, and for each
    packet of a burst) or 500 ms (MAVSDK). At the default 1,000 B/s, after the gimbal's
    attitude status and the heartbeats, the answers get ~370 B/s: a full 266-byte frame every
    0.72 s at best, retries and a stalled download as soon as anything else wants the link. A
    reply of fewer bytes than asked is allowed (the reply's ``size`` says how many; ArduPilot
    sends 48 on a busy link, and QGroundControl, MAVSDK and pymavlink's mavftp read on from
    ``offset + size``): 123 bytes at 1,000 B/s leave every ~0.4 s, the same bytes a second."""
    if bytes_per_s is None:
        return MAX_DATA
    fitting = int(bytes_per_s * CHUNK_SHARE) - FRAME_OVERHEAD - HEADER_BYTES
    return max(MIN_CHUNK, min(MAX_DATA, fitting))


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
    #: the request's own sequence number (a repeat of it while the burst runs is ignored)
    request_seq: int = -1


@dataclass
class _Session:
    number: int
    owner: Sender
    name: str
    last_used: float
    burst: _Burst | None = None
    #: its owner read from it (ReadFile or BurstReadFile)
    read: bool = False


@dataclass(frozen=True)
class _Reply:
    payload: bytes
    #: the request it answers: its sequence number and (session, opcode, offset)
    request_seq: int
    key: _Key
    #: an ACK or an end of file (the client moves on with it), not a refusal
    progress: bool


@dataclass
class _Requester:
    queue: deque[_Reply] = field(default_factory=deque)
    #: the last reply that went to this requester (re-sent when its request is repeated)
    last_sent: _Reply | None = None
    #: the last request heard: (sequence number, session, opcode, offset, data)
    last_request: tuple[int, int, int, int, bytes] | None = None


@dataclass
class FtpServer:
    """The FTP server of one component. ``files``: served name -> content (read-only)."""

    files: Mapping[str, bytes]
    bytes_per_s: float = UNBUDGETED_BYTES_S
    #: the link's window, when several servers share one link (else the server's own)
    window: ByteWindow | None = None
    #: data bytes of a read reply at most (:func:`chunk_for_budget`)
    chunk_bytes: int = MAX_DATA
    counters: Counter[str] = field(default_factory=Counter)
    _sessions: dict[int, _Session] = field(default_factory=dict)
    _requesters: OrderedDict[Sender, _Requester] = field(default_factory=OrderedDict)
    #: senders whose session went unread (see :meth:`_close`), least recent first
    _squatters: OrderedDict[Sender, None] = field(default_factory=OrderedDict)
    #: the time of the :meth:`due` call in progress
    _now: float = 0.0

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
        """One request; its answer is queued and goes out through :meth:`due`."""
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
        if self._repeated(request):
            return
        self._drop_superseded(request)
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

    def _requester(self, sender: Sender) -> _Requester:
        requester = self._requesters.get(sender)
        if requester is None:
            if len(self._requesters) >= MAX_REQUESTERS:
                self._forget_one()
            requester = self._requesters[sender] = _Requester()
        return requester

    def _forget_one(self) -> None:
        """Room for a new requester: the least recently served one with nothing queued and no
        session, else one with nothing queued, else the one with the most queued (a flood),
        never a quiet one with little waiting."""
        owners = {session.owner for session in self._sessions.values()}
        idle = [s for s, r in self._requesters.items() if not r.queue]
        unattached = [s for s in idle if s not in owners]
        if unattached or idle:
            victim = (unattached or idle)[0]
        else:
            victim = max(self._requesters, key=lambda s: len(self._requesters[s].queue))
        self.counters["queue_full"] += len(self._requesters.pop(victim).queue)
        self.counters["requesters_forgotten"] += 1

    def _repeated(self, request: _Request) -> bool:
        """A request repeated with the same sequence number (its reply lost or late): True when
        it is answered already: its reply still waits (nothing more), a burst it started still
        runs, or its reply went and is queued once more (ArduPilot re-sends its last reply,
        except a NoSessionsAvailable: a session may be free by now)."""
        requester = self._requester(request.sender)
        ident = (request.seq, request.session, request.opcode, request.offset, request.data)
        if requester.last_request != ident:
            requester.last_request = ident
            return False
        if any(reply.request_seq == request.seq for reply in requester.queue):
            self.counters["repeat_waiting"] += 1
            return True
        session = self._sessions.get(request.session)
        burst = None if session is None or session.owner != request.sender else session.burst
        if burst is not None and burst.request_seq == request.seq:
            self.counters["repeat_waiting"] += 1
            return True
        last = requester.last_sent
        if (
            last is not None
            and last.request_seq == request.seq
            and last.key[:2] == (request.session, request.opcode)
            and request.opcode != OP_BURST_READ_FILE  # a burst asked again starts again
            and not _is_nak(last.payload, ERR_NO_SESSIONS_AVAILABLE)
        ):
            self.counters["repeat_resent"] += 1
            self._enqueue(request.sender, last)
            return True
        return False

    def _drop_superseded(self, request: _Request) -> None:
        """A new request makes the replies still queued for the same one (a retry with a new
        sequence number) stale: the client takes only the newest sequence."""
        requester = self._requesters.get(request.sender)
        if requester is None:
            return
        key = (request.session, request.opcode, request.offset)
        kept = deque(r for r in requester.queue if r.key != key)
        self.counters["stale_dropped"] += len(requester.queue) - len(kept)
        requester.queue = kept

    def _drop_session_replies(self, sender: Sender, sessions: set[int]) -> None:
        """Replies waiting for sessions the sender ended or reset: nobody reads them."""
        requester = self._requesters.get(sender)
        if requester is None:
            return
        kept = deque(r for r in requester.queue if r.key[0] not in sessions)
        self.counters["stale_dropped"] += len(requester.queue) - len(kept)
        requester.queue = kept

    def _reset(self, request: _Request, now: float) -> None:
        """ResetSessions: the sender's own sessions only (a stranger cannot end ours)."""
        mine = {n for n, s in self._sessions.items() if s.owner == request.sender}
        for number in mine:
            del self._sessions[number]
        self._drop_session_replies(request.sender, mine)
        self._ack(request, request.session)

    def _terminate(self, request: _Request, now: float) -> None:
        if self._owned(request) is None:
            return
        del self._sessions[request.session]
        self._drop_session_replies(request.sender, {request.session})
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
            self._nak(request, ERR_EOF, progress=True)
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
        squatter = request.sender in self._squatters
        if len(self._sessions) >= MAX_SESSIONS and not squatter and not mine:
            self._evict_idle(now)  # only a sender without a session may take an idle one
        if len(self._sessions) >= MAX_SESSIONS or len(mine) >= MAX_SESSIONS_PER_SENDER:
            self.counters["no_session"] += 1
            if squatter:  # counted, not answered: its sessions went unread, so does a NAK
                self.counters["squatter_refused"] += 1
                return
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
        self._reading(session)
        content = self.files[session.name]
        if request.offset >= len(content):
            self._nak(request, ERR_EOF, progress=True)
            return
        data = content[request.offset : request.offset + min(request.size, self._chunk())]
        self.counters["read_bytes"] += len(data)
        self._ack(request, session.number, data=data, offset=request.offset)

    def _burst(self, request: _Request, now: float) -> None:
        session = self._owned(request)
        if session is None:
            return
        session.last_used = now
        self._reading(session)
        if request.offset >= len(self.files[session.name]):
            session.burst = None
            self._nak(request, ERR_EOF, progress=True)
            return
        chunk = min(request.size or MAX_DATA, self._chunk())
        # a new request (the client's retry, or its request for a gap) replaces the burst
        session.burst = _Burst(
            request.offset, chunk, (request.seq + 1) & 0xFFFF, BURST_PACKETS, request.seq
        )

    def _reading(self, session: _Session) -> None:
        """The owner reads: a client, whatever it did before."""
        session.read = True
        self._squatters.pop(session.owner, None)

    def _chunk(self) -> int:
        return max(MIN_CHUNK, min(MAX_DATA, self.chunk_bytes))

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
            self._close(oldest)
            self.counters["evicted"] += 1

    def _expire(self, now: float) -> None:
        for session in [s for s in self._sessions.values() if now - s.last_used > SESSION_IDLE_S]:
            self._close(session)
            self.counters["expired"] += 1

    def _close(self, session: _Session) -> None:
        """A session evicted or expired; one its owner never read from marks the owner as a
        squatter: its later opens take a free session but never evict another's.

        Why: 64 spoofed ids opening a session a second each took every session as soon as one
        had been idle the eviction time; a ground station's open lost that race to 64 others
        (NAK NoSessionsAvailable for most of its tries). A client opens to read, at once."""
        del self._sessions[session.number]
        if not session.read:
            self._squatters[session.owner] = None
            self._squatters.move_to_end(session.owner)
            while len(self._squatters) > MAX_SQUATTERS:
                self._squatters.popitem(last=False)

    # ------------------------------------------------------------------ replies

    def _ack(self, request: _Request, session: int, *, data: bytes = b"", offset: int = 0) -> None:
        payload = _reply((request.seq + 1) & 0xFFFF, session, OP_ACK, request.opcode, offset, data)
        self._queue_reply(request, payload, progress=True)

    def _nak(self, request: _Request, error: int, *, progress: bool = False) -> None:
        self.counters[f"nak_{error}"] += 1
        payload = _reply(
            (request.seq + 1) & 0xFFFF,
            request.session,
            OP_NAK,
            request.opcode,
            request.offset,  # a client matches a burst's EOF to its offset (mavftp)
            bytes([error]),
        )
        self._queue_reply(request, payload, progress=progress)

    def _queue_reply(self, request: _Request, payload: bytes, *, progress: bool) -> None:
        key = (request.session, request.opcode, request.offset)
        self._enqueue(request.sender, _Reply(payload, request.seq, key, progress))

    def _enqueue(self, sender: Sender, reply: _Reply) -> None:
        """Queue a reply; a sender's own oldest makes room beyond its share, and a full queue
        drops the oldest refusal waiting (a NAK nobody can make progress with), else the
        oldest of the sender with the most queued (never a quiet requester's: with 65
        requesters holding one reply each, the first in line was dropped, a ground station's
        ACK among them)."""
        requester = self._requester(sender)
        if len(requester.queue) >= MAX_QUEUED_PER_SENDER:
            requester.queue.popleft()
            self.counters["queue_full"] += 1
        elif self.queued() >= MAX_QUEUED:
            refusing = next(
                (r for r in self._requesters.values() if any(not x.progress for x in r.queue)),
                None,
            )
            if refusing is not None:
                oldest = next(x for x in refusing.queue if not x.progress)
                refusing.queue.remove(oldest)
            elif not reply.progress:
                self.counters["queue_full"] += 1
                return  # a refusal never pushes out a reply that makes progress
            else:
                fullest = max(self._requesters.values(), key=lambda r: len(r.queue))
                fullest.queue.popleft()
            self.counters["queue_full"] += 1
        requester.queue.append(reply)

    def queued(self) -> int:
        """Replies waiting, all requesters together."""
        return sum(len(r.queue) for r in self._requesters.values())

    def queued_for(self, sender: Sender) -> int:
        requester = self._requesters.get(sender)
        return 0 if requester is None else len(requester.queue)

    # ------------------------------------------------------------------ time

    def periodic(self, now: float) -> list[tuple[Sender, bytes]]:
        """:meth:`due` without a link budget (the server's own byte window only)."""
        return self.due(now, lambda _payload, _awaited: True)

    def due(self, now: float, admit: Callable[[bytes, bool], bool]) -> list[tuple[Sender, bytes]]:
        """Replies that go now, each (the requester, the 251-byte payload): requesters in turn,
        the ones whose next reply makes progress (an ACK, a burst packet, an end of file)
        before the ones whose next reply is a refusal; each reply within the byte window and
        ``admit(payload, awaited)`` (the link budget: the first refusal ends the call, the reply
        stays queued; ``awaited``: a reply that makes progress, one a client waits for, not a
        refusal)."""
        self._expire(now)
        self._now = now
        window = self.window
        assert window is not None
        out: list[tuple[Sender, bytes]] = []
        for _ in range(MAX_QUEUED + MAX_SESSIONS * BURST_PACKETS):  # bounded
            sender = self._next_requester()
            if sender is None:
                return out
            requester = self._requesters[sender]
            reply = requester.queue[0] if requester.queue else self._burst_packet(sender, True)
            assert reply is not None
            size = frame_bytes(reply.payload)
            if not window.fits(size, now) or not admit(reply.payload, reply.progress):
                self.counters["waiting_for_budget"] += 1
                return out
            if requester.queue:
                requester.queue.popleft()
            else:
                self._burst_packet(sender, False)
            requester.last_sent = reply
            window.take(size, now)
            self.counters["sent_bytes"] += size
            self._requesters.move_to_end(sender)  # served: the others go first next time
            out.append((sender, reply.payload))
        return out

    def _next_requester(self) -> Sender | None:
        """The least recently served requester of the first tier that has one: a reader (it
        reads a file it opened) with a reply that makes progress; any requester with a reply
        that makes progress (an open, a list, a CRC); one with a refusal waiting. Why tiers: a
        download in progress must not share its turns with strangers' opens (16 spoofed ids'
        open ACKs took 16 of every 17 turns, the ground station's burst packets came 1.5 s
        apart), nor with their refusals."""
        readers = {s.owner for s in self._sessions.values() if s.read}
        best: tuple[int, Sender] | None = None
        for sender, requester in self._requesters.items():
            if requester.queue:
                tier = (0 if sender in readers else 1) if requester.queue[0].progress else 2
            elif self._bursting(sender) is not None:
                tier = 0
            else:
                continue
            if tier == 0:
                return sender
            if best is None or tier < best[0]:
                best = (tier, sender)
        return None if best is None else best[1]

    def _bursting(self, sender: Sender) -> _Session | None:
        return next(
            (s for s in self._sessions.values() if s.owner == sender and s.burst is not None),
            None,
        )

    def _burst_packet(self, sender: Sender, peek: bool) -> _Reply | None:
        """The next packet of ``sender``'s burst (made when it can go: never queued)."""
        session = self._bursting(sender)
        if session is None:
            return None
        burst = session.burst
        assert burst is not None
        content = self.files[session.name]
        data = content[burst.offset : burst.offset + burst.chunk]
        last = burst.left == 1 or burst.offset + len(data) >= len(content)
        payload = _reply(
            burst.seq, session.number, OP_ACK, OP_BURST_READ_FILE, burst.offset, data, last
        )
        reply = _Reply(
            payload, burst.request_seq, (session.number, OP_BURST_READ_FILE, burst.offset), True
        )
        if not peek:
            # a burst going out is the session in use (it was evicted as idle mid-burst: no
            # request comes while its packets flow)
            session.last_used = max(session.last_used, self._now)
            self.counters["burst_bytes"] += len(data)
            burst.offset += len(data)
            burst.seq = (burst.seq + 1) & 0xFFFF
            burst.left -= 1
            if last:
                session.burst = None
        return reply

    def stats(self) -> dict[str, int]:
        return {**self.counters, "sessions": len(self._sessions), "queued": self.queued()}


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


def _is_nak(payload: bytes, error: int) -> bool:
    return payload[3] == OP_NAK and payload[HEADER_BYTES] == error


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
