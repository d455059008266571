"""AA-55 framing of the Waveshare USB-CAN-A / Seeed USB-CAN Analyzer family, without any I/O.

Two protocols share the serial line:

* ``variable``: ``AA | type | ID (2 B LE std / 4 B LE ext) | data (DLC B) | 55`` with
  ``type = 0xC0 | ext << 5 | rtr << 4 | DLC``. Remote frames carry no data bytes; the DLC nibble
  is the requested length. There is no checksum, so validation is structural (type bits, DLC <= 8,
  ID range, end marker) and a rejected candidate is rescanned from the byte after its 0xAA: a
  0xAA inside a payload is legal and a real frame can overlap a false start.
* ``fixed``: 20-byte frames ``AA 55 | command | ... | checksum`` where the checksum is the low byte
  of the sum of bytes 2..18. The adapter's settings frame is one of these (in both protocols);
  data travels this way when the adapter is set to the fixed protocol.

The module is sans-I/O (like h11): bytes in, frames out, nothing else. That is what lets the
decoder be fuzzed and property-tested, and lets the same code serve the host interface
(:mod:`mavservo.transport.aa55.bus`) and the adapter emulator (:mod:`mavservo.sim.adapter`).
"""

from __future__ import annotations

import enum
import re
import struct
from collections import Counter, deque
from collections.abc import Iterator
from dataclasses import dataclass
from itertools import repeat
from typing import Any, Literal, NamedTuple, Protocol

import can
from can.typechecking import Channel

from .candidates import CandidateJudge, Verdict
from .layout import CMD_FIXED_DATA as CMD_FIXED_DATA
from .layout import CMD_SETTINGS_FIXED as CMD_SETTINGS_FIXED
from .layout import CMD_SETTINGS_VARIABLE as CMD_SETTINGS_VARIABLE
from .layout import CMD_STATUS as CMD_STATUS
from .layout import DATA_ALTERNATIVES, LAYOUTS, checksum_ok, layout_pattern
from .layout import END as END
from .layout import FIXED_LENGTH as FIXED_LENGTH
from .layout import MAX_EXT_ID as MAX_EXT_ID
from .layout import MAX_STD_ID as MAX_STD_ID
from .layout import START as START

__all__ = [
    "BITRATE_CODES",
    "MODES",
    "AdapterSettings",
    "ControlFrame",
    "Decoded",
    "Decoder",
    "Frame",
    "Rejection",
    "encode",
    "settings_frame",
]

ProtocolName = Literal["variable", "fixed"]
PROTOCOLS: tuple[str, ...] = ("variable", "fixed")

#: The decoder never holds this many bytes between calls. The most it holds: a 15-byte frame
#: with a frame starting at its 13th byte and running 14 bytes past it, waiting for the frame
#: after that to be whole (14 of its 15 bytes): 41. (Two 20-byte frames in the fixed protocol
#: and the next byte: 40; an incomplete candidate: < 20.)
MAX_PENDING = 42

#: CAN bitrate -> the adapter's bitrate code in the settings frame.
BITRATE_CODES: dict[int, int] = {
    1_000_000: 0x01,
    800_000: 0x02,
    500_000: 0x03,
    400_000: 0x04,
    250_000: 0x05,
    200_000: 0x06,
    125_000: 0x07,
    100_000: 0x08,
    50_000: 0x09,
    20_000: 0x0A,
    10_000: 0x0B,
    5_000: 0x0C,
}
_BITRATES_BY_CODE = {code: rate for rate, code in BITRATE_CODES.items()}

#: Operating mode name -> code in the settings frame.
MODES: dict[str, int] = {"normal": 0, "loopback": 1, "silent": 2, "loopback_silent": 3}
_MODES_BY_CODE = {code: name for name, code in MODES.items()}


class Rejection(str, enum.Enum):
    """Why a candidate frame starting at a 0xAA byte was not accepted."""

    BAD_TYPE = "bad_type"
    BAD_DLC = "bad_dlc"
    BAD_ID = "bad_id"
    BAD_END = "bad_end"
    BAD_CHECKSUM = "bad_checksum"
    BAD_FIXED = "bad_fixed"  # checksum fine, but a field is impossible (type, format, DLC, ID)
    TRUNCATED = "truncated"  # the line went idle in the middle of a candidate
    OVERLAP = "overlap"  # valid in itself, but a false start over a better-placed real frame


class FrameLike(Protocol):
    arbitration_id: int
    is_extended_id: bool
    is_remote_frame: bool
    data: Any


class _FrameFields(NamedTuple):
    arbitration_id: int
    is_extended_id: bool
    is_remote_frame: bool
    dlc: int
    data: bytes
    timestamp: float = 0.0


class Frame(_FrameFields):
    """A decoded CAN frame: the light type the decoder emits (a ``can.Message`` costs 4x more).

    It has the attributes of ``can.Message`` that matter on this link, and :meth:`to_message`.
    It is a tuple underneath so that a run of same-layout frames can be built in C
    (``struct.iter_unpack`` + ``zip``, see :meth:`Decoder.feed`), with no Python call per frame.
    Equality and hashing ignore the timestamp: two frames are equal when the wire carried the same
    frame.
    """

    __slots__ = ()

    def to_message(self, channel: Channel | None = None, is_rx: bool = True) -> can.Message:
        """The ``can.Message`` python-can users expect, built without ``Message.__init__``.

        ``Message.__init__`` costs ~0.9 us (argument handling, data copy, checks we already did);
        filling its slots directly costs a quarter of that, and the receiving thread pays it for
        every frame. The result is the same: ``data`` a ``bytearray``, ``dlc`` as on the wire.
        """
        msg = _new_message(can.Message)
        msg.timestamp = self[5]
        msg.arbitration_id = self[0]
        msg.is_extended_id = self[1]
        msg.is_remote_frame = self[2]
        msg.is_error_frame = False
        msg.channel = channel
        msg.dlc = self[3]
        msg.data = bytearray(self[4])
        msg.is_fd = False
        msg.is_rx = is_rx
        msg.bitrate_switch = False
        msg.error_state_indicator = False
        return msg

    def key(self) -> tuple[int, bool, bool, int, bytes]:
        """Identity of the frame on the wire, for comparisons in tests and tools."""
        return (self[0], self[1], self[2], self[3], self[4])

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Frame):
            return NotImplemented
        return self.key() == other.key()

    def __ne__(self, other: object) -> bool:
        equal = self.__eq__(other)
        return equal if equal is NotImplemented else not equal

    def __hash__(self) -> int:
        return hash(self.key())

    def __repr__(self) -> str:
        kind = "ext" if self.is_extended_id else "std"
        rtr = " rtr" if self.is_remote_frame else ""
        return f"Frame(0x{self.arbitration_id:X} {kind}{rtr} dlc={self.dlc} data={self.data.hex()})"


_new_message = can.Message.__new__
_new_tuple = tuple.__new__


@dataclass(frozen=True)
class AdapterSettings:
    """The adapter set-up carried by a settings frame (decoded by the adapter emulator)."""

    bitrate: int | None  # None: a code this module does not know
    extended: bool
    filter_id: int
    mask: int
    mode: str
    protocol: ProtocolName
    raw: bytes = b""


@dataclass(frozen=True)
class ControlFrame:
    """A checksummed 20-byte frame that is neither data nor settings (status request/reply...)."""

    command: int
    raw: bytes


Decoded = Frame | AdapterSettings | ControlFrame | can.Message
"""What :meth:`Decoder.feed` returns per item: ``can.Message`` for data frames with
``messages=True``, :class:`Frame` without; settings and control frames as themselves."""


def _frame_dlc(frame: FrameLike) -> int:
    dlc = getattr(frame, "dlc", None)
    data_len = len(frame.data) if frame.data is not None else 0
    if frame.is_remote_frame:
        return data_len if dlc is None else int(dlc)
    return data_len


def _validate(frame: FrameLike) -> tuple[int, bool, bool, int, bytes]:
    arb_id = int(frame.arbitration_id)
    ext = bool(frame.is_extended_id)
    rtr = bool(frame.is_remote_frame)
    data = bytes(frame.data or b"")
    limit = MAX_EXT_ID if ext else MAX_STD_ID
    if not 0 <= arb_id <= limit:
        kind = "extended" if ext else "standard"
        raise ValueError(
            f"arbitration ID 0x{arb_id:X} is out of range for a {kind} frame (0..0x{limit:X})"
        )
    if len(data) > 8:
        raise ValueError(f"data is {len(data)} bytes long; classic CAN carries at most 8")
    dlc = _frame_dlc(frame)
    if not 0 <= dlc <= 8:
        raise ValueError(f"DLC {dlc} is out of range 0..8")
    if rtr:
        data = b""  # remote frames carry no data on the wire
    return arb_id, ext, rtr, dlc, data


def encode(frame: FrameLike, protocol: ProtocolName = "variable") -> bytes:
    """Bytes that put ``frame`` on the serial line in ``protocol``.

    Raises ``ValueError`` for an impossible frame (ID out of range, more than 8 data bytes) or an
    unknown protocol, so a bad frame never reaches the wire.
    """
    arb_id, ext, rtr, dlc, data = _validate(frame)
    if protocol == "variable":
        type_byte = 0xC0 | (0x20 if ext else 0) | (0x10 if rtr else 0) | dlc
        ident = arb_id.to_bytes(4 if ext else 2, "little")
        return bytes((START, type_byte)) + ident + data + b"\x55"
    if protocol == "fixed":
        body = bytearray((START, END, CMD_FIXED_DATA, 2 if ext else 1, 2 if rtr else 1))
        body += arb_id.to_bytes(4, "little")
        body.append(dlc)
        body += data.ljust(8, b"\x00")
        body.append(0)  # reserved
        body.append(sum(body[2:]) & 0xFF)
        return bytes(body)
    raise ValueError(f"unknown protocol {protocol!r}; expected one of {PROTOCOLS}")


def settings_frame(
    bitrate: int = 1_000_000,
    *,
    extended: bool = False,
    filter_id: int = 0,
    mask: int = 0,
    mode: str = "normal",
    protocol: ProtocolName = "variable",
) -> bytes:
    """The 20-byte frame that configures the adapter (bitrate, filter, mode, protocol)."""
    if bitrate not in BITRATE_CODES:
        known = ", ".join(str(b) for b in BITRATE_CODES)
        raise ValueError(f"bitrate {bitrate} is not supported by the adapter; use one of {known}")
    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}; expected one of {', '.join(MODES)}")
    if protocol not in PROTOCOLS:
        raise ValueError(f"unknown protocol {protocol!r}; expected one of {PROTOCOLS}")
    for name, value in (("filter_id", filter_id), ("mask", mask)):
        if not 0 <= value <= 0xFFFFFFFF:
            raise ValueError(f"{name} 0x{value:X} does not fit in 32 bits")
    command = CMD_SETTINGS_VARIABLE if protocol == "variable" else CMD_SETTINGS_FIXED
    body = bytearray((START, END, command, BITRATE_CODES[bitrate], 2 if extended else 1))
    body += filter_id.to_bytes(4, "little") + mask.to_bytes(4, "little")
    body += bytes((MODES[mode], 0x01, 0, 0, 0, 0))
    body.append(sum(body[2:]) & 0xFF)
    return bytes(body)


# Searching for the leftmost match of any layout from a position is the same as the byte-by-byte
# state machine that rescans after every rejected 0xAA, but runs in C.
_FIXED_ALTERNATIVE = rb"\xaa\x55.{18}"
_VARIABLE_RE = re.compile(_FIXED_ALTERNATIVE + b"|" + DATA_ALTERNATIVES, re.DOTALL)
_FIXED_RE = re.compile(_FIXED_ALTERNATIVE, re.DOTALL)


@dataclass(frozen=True)
class _Run:
    """How to decode a run of back-to-back frames of one layout in one pass of C code."""

    pattern: re.Pattern[bytes]  # one or more consecutive frames of this layout
    rows: struct.Struct  # one frame -> (id,) or (id, data)
    ext: bool
    rtr: bool
    dlc: int


def _run_table() -> dict[int, _Run]:
    table = {}
    for ext, rtr, dlc in LAYOUTS:
        type_byte = 0xC0 | (0x20 if ext else 0) | (0x10 if rtr else 0) | dlc
        payload = 0 if rtr else dlc
        fmt = "<2x" + ("I" if ext else "H") + (f"{payload}s" if payload else "") + "x"
        pattern = re.compile(b"(?:" + layout_pattern(ext, rtr, dlc) + b")+", re.DOTALL)
        table[type_byte] = _Run(pattern, struct.Struct(fmt), ext, rtr, dlc)
    return table


def _run_messages(
    rows: Iterator[tuple[Any, ...]],
    run: _Run,
    timestamp: float,
    channel: Channel | None,
    out: list[Decoded],
) -> int:
    """Append a ``can.Message`` per unpacked row of ``run``'s layout to ``out``; how many.

    The same objects as :meth:`Frame.to_message` makes, without the :class:`Frame` in between
    nor a function call per frame: on the bus's receiving thread this loop is most of the
    Python work per frame (0.27 us against 0.6 us for Frame + ``to_message``).
    """
    new, message = _new_message, can.Message
    ext, rtr, dlc = run.ext, run.rtr, run.dlc
    if run.rtr or not run.dlc:  # rows are (id,): no payload on the wire
        rows = ((row[0], b"") for row in rows)
    before = len(out)
    append = out.append
    for ident, data in rows:
        msg = new(message)
        msg.timestamp = timestamp
        msg.arbitration_id = ident
        msg.is_extended_id = ext
        msg.is_remote_frame = rtr
        msg.is_error_frame = False
        msg.channel = channel
        msg.dlc = dlc
        msg.data = bytearray(data)
        msg.is_fd = False
        msg.is_rx = True
        msg.bitrate_switch = False
        msg.error_state_indicator = False
        append(msg)
    return len(out) - before


#: Type byte -> run decoder. Servo traffic is almost all one layout (standard ID, DLC 8), so a
#: chunk of replies is one run: decoding it costs ~0.2 us a frame instead of ~1.8 us.
_RUNS = _run_table()


class Decoder:
    """Rebuilds frames from a serial byte stream, whatever its chunking or corruption.

    ``feed(data)`` returns, in stream order, :class:`Frame` for data frames and
    :class:`AdapterSettings` / :class:`ControlFrame` for 20-byte control frames. It never raises,
    and between calls it keeps fewer than :data:`MAX_PENDING` bytes, so memory is bounded.
    Call :meth:`flush` when the line has gone idle: a candidate still incomplete then was a false
    start (or a truncated frame) and is rescanned, so a real frame behind it is not held back.

    Counters: ``frames``, ``settings``, ``control``, ``bytes_discarded``, ``rejected`` (per
    :class:`Rejection`), and ``rejections``, the last ``keep_rejections`` rejected candidates with
    their bytes, for logs.

    With ``messages=True`` data frames come out as ``can.Message`` (``channel`` set, as
    :meth:`Frame.to_message` makes them) instead of :class:`Frame`: what a python-can bus hands
    its users, built in the same pass over a run as the fields are split, at less than half the
    cost of a :class:`Frame` converted afterwards.
    """

    def __init__(
        self,
        protocol: ProtocolName = "variable",
        keep_rejections: int = 256,
        resolve_overlaps: bool = True,
        messages: bool = False,
        channel: Channel | None = None,
    ) -> None:
        if protocol not in PROTOCOLS:
            raise ValueError(f"unknown protocol {protocol!r}; expected one of {PROTOCOLS}")
        #: Judge a frame that overlaps a better-placed one (:meth:`.CandidateJudge.judge`). Off:
        #: the first structurally valid candidate always wins and nothing waits for a following
        #: byte (what a simple adapter firmware does; the adapter emulator may want that).
        self.resolve_overlaps = resolve_overlaps
        self.messages = messages
        self.channel = channel
        self.protocol: ProtocolName = protocol
        self._pattern = _VARIABLE_RE if protocol == "variable" else _FIXED_RE
        # the structural rules (:mod:`.candidates`), bound once: the scan calls them by name
        candidates = CandidateJudge(protocol)
        self._judge = candidates.judge
        self._held_back = candidates.held_back
        self._incomplete_start = candidates.incomplete_start
        self._buf = bytearray()
        self.frames = 0
        self.settings = 0
        self.control = 0
        self.bytes_discarded = 0
        self._gap = False
        self.rejected: Counter[Rejection] = Counter()
        self.rejections: deque[tuple[Rejection, bytes]] = deque(maxlen=keep_rejections)

    @property
    def pending(self) -> int:
        """Bytes held back as the start of an incomplete candidate."""
        return len(self._buf)

    def feed(self, data: bytes, timestamp: float = 0.0) -> list[Decoded]:
        if not self._buf and type(data) is bytes:
            # Nothing held back: scan the caller's bytes where they are and keep only the tail.
            # Copying a whole read into the buffer first costs little on a warm CPU but ~15 us
            # on one that has just woken up, when the bus calls this
            # (docs/benchmarks.md).
            return self._scan(data, timestamp, idle=False)
        self._buf += data
        return self._scan(self._buf, timestamp, idle=False)

    def flush(self, timestamp: float = 0.0) -> list[Decoded]:
        """The line went idle: settle what was held back, give up on an incomplete candidate.

        A frame held back for want of the byte after it is judged with the end of data as its
        follower; a candidate still incomplete was a false start or a truncated frame and is
        rescanned from the byte after its 0xAA, so a real frame behind it is not lost.
        """
        out = self._scan(self._buf, timestamp, idle=True)
        for _ in range(len(self._buf)):  # bounded: every turn drops at least one byte
            if not self._buf:
                break
            self._record(Rejection.TRUNCATED, bytes(self._buf))
            del self._buf[0]
            self._gap = True
            out += self._scan(self._buf, timestamp, idle=True)
        self._gap = False  # after an idle line the next byte starts afresh
        return out

    def _scan(self, buf: bytes | bytearray, timestamp: float, idle: bool) -> list[Decoded]:
        """Decode ``buf`` (the held-back bytes, or a fresh chunk when nothing was held back);
        what may still begin a frame ends up in ``self._buf``."""
        out: list[Decoded] = []
        append = out.append
        from_bytes = int.from_bytes
        variable = self.protocol == "variable"
        gap = self._gap  # were the bytes just before ``pos`` garbage?
        held: int | None = None
        pos = 0
        end = len(buf)
        frames = 0
        restart = True
        while restart:  # the inner loop is left only to restart the search at ``pos``
            restart = False
            if (
                variable
                and not gap
                and pos + 1 < end
                and buf[pos] == START
                and buf[pos + 1] in _RUNS
            ):
                # Usually the chunk starts with a frame (or the rest of one held back) and a run
                # of its layout follows: take it before any search.
                pos, count = self._take_run(buf, pos, _RUNS[buf[pos + 1]], timestamp, out)
                frames += count
                if pos == end:  # the usual end of a read: one run, nothing left to search
                    break
            for m in self._pattern.finditer(buf, pos):
                start = m.start()
                if start != pos:
                    if start > end - FIXED_LENGTH and self._held_back(buf, pos, start, end):
                        break  # an earlier candidate may still complete and swallow this match
                    self._reject_gap(buf, pos, start)
                    gap = True
                raw = m.group()
                type_byte = raw[1]
                stop = m.end()
                fixed = type_byte == END
                if fixed and not checksum_ok(raw, 0):
                    self._record(Rejection.BAD_CHECKSUM, raw)
                    pos = start + 1  # rescan after the 0xAA
                    gap = restart = True
                    break
                # Only a frame with a 0xAA inside can be a false start over another: the rest
                # (most frames) skip the judging.
                if self.resolve_overlaps and raw.find(START, 1) >= 0:
                    verdict = self._judge(buf, start, stop, end, gap, idle, fixed)
                    if verdict is not Verdict.ACCEPT:
                        if verdict is Verdict.WAIT:
                            held = pos = start
                            break
                        self._record(Rejection.OVERLAP, raw)
                        pos = start + 1
                        gap = restart = True
                        break
                if fixed:
                    item = self._fixed(raw, timestamp)
                    if item is None:  # impossible field: rescan after the 0xAA
                        pos = start + 1
                        gap = restart = True
                        break
                    if type(item) is Frame:
                        frames += 1
                        append(item.to_message(self.channel) if self.messages else item)
                    else:
                        append(item)
                    pos, gap = stop, False
                    continue
                frames += 1
                id_end = 6 if type_byte & 0x20 else 4  # extended IDs take 4 bytes
                frame = Frame(
                    from_bytes(raw[2:id_end], "little"),
                    id_end == 6,
                    bool(type_byte & 0x10),
                    type_byte & 0x0F,
                    raw[id_end:-1],
                    timestamp,
                )
                append(frame.to_message(self.channel) if self.messages else frame)
                pos, gap = stop, False
                if variable and pos + 1 < end and buf[pos] == START and buf[pos + 1] == type_byte:
                    # The same layout follows at once: take the whole run in one pass.
                    pos, count = self._take_run(buf, pos, _RUNS[type_byte], timestamp, out)
                    if count:
                        frames += count
                        restart = True
                        break
        self.frames += frames
        if held is not None:
            keep = held
        elif pos == end:
            keep = end
        else:  # keep the earliest 0xAA that could still begin a valid frame
            keep = self._incomplete_start(buf, pos, end)
            if keep > pos:
                self._reject_gap(buf, pos, keep)
                gap = True
        self._gap = gap
        if buf is self._buf:
            del buf[:keep]
        elif keep < end:  # scanned in place: hold back the tail (fewer than MAX_PENDING bytes)
            self._buf += buf[keep:]
        return out

    def _take_run(
        self, buf: bytes | bytearray, pos: int, run: _Run, timestamp: float, out: list[Decoded]
    ) -> tuple[int, int]:
        """Decode the frames of ``run``'s layout back to back from ``pos``; (new pos, count).

        Same result as one regex match and one judgement (:mod:`.candidates`) per frame: a run
        that starts at ``pos`` is exactly the sequence of leftmost matches from ``pos`` (each
        layout's frames have one length and no other layout matches the same type byte), it is
        only taken right after a frame (no garbage before it), and its last frame is left out
        unless it has no 0xAA inside, so every frame taken is followed by a whole frame (the
        next of the run) or has nothing inside to judge: the cases the judge accepts without
        looking further.
        Everything per frame happens in C: ``iter_unpack`` splits the fields, ``zip`` assembles
        them, ``tuple.__new__`` makes the :class:`Frame`. In ``messages`` mode one Python loop
        over ``iter_unpack`` fills each ``can.Message`` (:func:`_run_messages`).
        """
        m = run.pattern.match(buf, pos)
        if m is None:
            return pos, 0
        stop = m.end()
        last = stop - run.rows.size
        if buf.find(START, last + 1, stop) >= 0:  # the last frame may need judging: leave it
            stop = last
            if stop <= pos:
                return pos, 0
        rows = run.rows.iter_unpack(buf[pos:stop])
        if self.messages:
            return stop, _run_messages(rows, run, timestamp, self.channel, out)
        columns = list(zip(*rows, strict=True))
        ids = columns[0]
        datas = columns[1] if len(columns) > 1 else repeat(b"", len(ids))
        fields = zip(
            ids, repeat(run.ext), repeat(run.rtr), repeat(run.dlc), datas, repeat(timestamp)
        )
        out.extend(map(_new_tuple, repeat(Frame), fields))
        return stop, len(ids)

    # -- internals ----------------------------------------------------------------------------

    def _fixed(self, raw: bytes, timestamp: float) -> Frame | AdapterSettings | ControlFrame | None:
        """The item a 20-byte frame whose checksum passed carries; None (counted) when one of
        its fields is impossible."""
        command = raw[2]
        if command in (CMD_SETTINGS_VARIABLE, CMD_SETTINGS_FIXED):
            self.settings += 1
            return AdapterSettings(
                bitrate=_BITRATES_BY_CODE.get(raw[3]),
                extended=raw[4] == 2,
                filter_id=int.from_bytes(raw[5:9], "little"),
                mask=int.from_bytes(raw[9:13], "little"),
                mode=_MODES_BY_CODE.get(raw[13], f"unknown({raw[13]})"),
                protocol="variable" if command == CMD_SETTINGS_VARIABLE else "fixed",
                raw=raw,
            )
        if command == CMD_FIXED_DATA:
            kind, fmt, dlc = raw[3], raw[4], raw[9]
            arb_id = int.from_bytes(raw[5:9], "little")
            ext = kind == 2
            if kind not in (1, 2) or fmt not in (1, 2) or dlc > 8:
                self._record(Rejection.BAD_FIXED, raw)
                return None
            if arb_id > (MAX_EXT_ID if ext else MAX_STD_ID):
                self._record(Rejection.BAD_FIXED, raw)
                return None
            rtr = fmt == 2
            return Frame(arb_id, ext, rtr, dlc, b"" if rtr else raw[10 : 10 + dlc], timestamp)
        self.control += 1
        return ControlFrame(command, raw)

    def _record(self, reason: Rejection, raw: bytes) -> None:
        self.rejected[reason] += 1
        self.rejections.append((reason, raw))
        self.bytes_discarded += 1

    def _reject_gap(self, buf: bytes | bytearray, pos: int, stop: int) -> None:
        """Account for the bytes in ``buf[pos:stop]``, none of which starts a valid frame."""
        start = buf.find(START, pos, stop)
        if start < 0:
            self.bytes_discarded += stop - pos
            return
        self.bytes_discarded += start - pos
        while start >= 0:
            reason = self._why_not(buf, start)
            self._record(reason, bytes(buf[start : min(start + FIXED_LENGTH, len(buf))]))
            nxt = buf.find(START, start + 1, stop)
            self.bytes_discarded += (nxt if nxt >= 0 else stop) - start - 1
            start = nxt

    def _why_not(self, buf: bytes | bytearray, start: int) -> Rejection:
        """The reason the candidate at ``start`` (known not to be a valid frame) fails."""
        n = len(buf)
        if start + 1 >= n:
            return Rejection.TRUNCATED
        type_byte = buf[start + 1]
        if type_byte == END:
            if start + FIXED_LENGTH > n:
                return Rejection.TRUNCATED
            return Rejection.BAD_CHECKSUM
        if self.protocol == "fixed" or type_byte & 0xC0 != 0xC0:
            return Rejection.BAD_TYPE
        dlc = type_byte & 0x0F
        if dlc > 8:
            return Rejection.BAD_DLC
        ext = bool(type_byte & 0x20)
        id_len = 4 if ext else 2
        length = 3 + id_len + (0 if type_byte & 0x10 else dlc)
        if start + 2 + id_len > n:
            return Rejection.TRUNCATED
        arb_id = int.from_bytes(buf[start + 2 : start + 2 + id_len], "little")
        if arb_id > (MAX_EXT_ID if ext else MAX_STD_ID):
            return Rejection.BAD_ID
        if start + length > n:
            return Rejection.TRUNCATED
        return Rejection.BAD_END
