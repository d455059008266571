"""Judging candidates in an AA-55 byte stream: is a match a false start over a real frame, may
a cut candidate still grow into one (sans-I/O, imports nothing of the project).

The variable-length protocol has no checksum, so where a frame starts is a structural guess: a
garbage 0xAA or a frame cut short can take the next frame's bytes as its own and end on a 0x55.
Deciding that is its own job, with no state but the protocol: it reads the bytes it is shown
and says accept, reject or wait. It lives apart from the :class:`~.codec.Decoder` (which owns
one) because the decoder's job is the scan itself, its hot path, and its counters; the rules
here are the subtle part, and alone they can be tested case by case on a few bytes.
"""

from __future__ import annotations

import enum
from typing import Literal

from .layout import (
    ADAPTER_COMMANDS,
    DATA_RE,
    END,
    FIXED_LENGTH,
    FIXED_START,
    MAX_EXT_ID,
    MAX_STD_ID,
    START,
    checksum_ok,
)


class Verdict(enum.Enum):
    """What to do with a matched candidate."""

    ACCEPT = "accept"
    REJECT = "reject"  # a false start: rescan from the byte after its 0xAA
    WAIT = "wait"  # not known until more bytes come (or the line goes idle)


class CandidateJudge:
    """The structural rules of one protocol (``variable`` or ``fixed``) for candidates."""

    __slots__ = ("protocol",)

    def __init__(self, protocol: Literal["variable", "fixed"]) -> None:
        self.protocol = protocol

    def judge(
        self,
        buf: bytes | bytearray,
        start: int,
        stop: int,
        end: int,
        gap: bool,
        idle: bool,
        fixed: bool = False,
    ) -> Verdict:
        """Keep the frame matched at ``buf[start:stop]``, or is it a false start over a real one?

        Without a checksum, a truncated frame or a garbage 0xAA can take the following frame's
        bytes as its own and happen to end on a 0x55: the match is structurally valid and the
        real frame inside it would be lost. Real frames follow each other back to back (or the
        line goes idle), garbage and truncation sit *before* a frame, so a match is given up for
        a valid frame starting inside it when

        * the match came after garbage and the inner frame ends where the match ends or is
          itself followed by a frame, or
        * the match is followed by something that is not a frame start while the inner frame is,
          or ends there too (then the line is damaged right after both, and a real frame whose
          last bytes read as a frame, ~3 in 100,000, is rarer than a cut one or a garbage 0xAA
          that runs exactly to the end of the next frame).

        A frame followed at once by another frame, with no garbage before it, is always kept:
        that is every frame of a clean stream, decided without looking further. Undecided cases
        wait for more bytes (at most two frames' worth), or for the line to go idle.

        ``fixed``: the match is a checksummed 20-byte frame. Its checksum passes by chance for
        one false start in 256 (a frame cut short takes the next frame's first bytes as its
        last; in the variable protocol, a payload ending in 0xAA before its 0x55 end marker
        starts one), so the same rule runs with the frames inside it (20-byte frames, up to one
        starting on its last byte, and variable ones in the variable protocol), and one more:
        when neither is followed by a frame start (garbage after the inner one), the inner
        frame wins. A real 20-byte frame loses that way only if garbage follows it and it holds
        a valid frame: in the fixed protocol one with ``AA 55`` (~1 in 4,000 random frames)
        whose 20 bytes pass the checksum by chance (1 in 256); in the variable one, where
        20-byte frames are the adapter's rare replies, a structurally valid variable frame.
        """
        marker: bytes | int  # what starts an inner candidate: ``AA 55``, or a lone 0xAA
        if fixed and self.protocol == "fixed":
            if stop == end and buf[stop - 1] == START and not idle:
                return Verdict.WAIT  # is that last 0xAA the start of an ``AA 55`` frame?
            marker, limit = FIXED_START, min(stop + 1, end)
        else:
            marker, limit = START, stop
        inner = buf.find(marker, start + 1, limit)
        if inner < 0:
            return Verdict.ACCEPT
        # A 20-byte frame on a variable-protocol line is one of the adapter's rare replies: one
        # that holds a frame followed by a frame, or holds a frame and carries a command the
        # adapter never sends, is taken for a false start even when it is followed by a frame
        # start itself (20 bytes of short frames often end on one).
        weak = fixed and self.protocol == "variable"
        followed = self._follows(buf, stop, end, idle, fixed)
        if followed and not gap and not weak:
            return Verdict.ACCEPT
        while inner >= 0:
            inner_stop = self._inner_frame_end(buf, inner, end, idle, fixed)
            if inner_stop is None:
                return Verdict.WAIT
            if inner_stop >= 0:
                inner_followed = self._follows(buf, inner_stop, end, idle, fixed)
                if inner_stop == stop and (gap or weak or followed is False):
                    return Verdict.REJECT  # same end, and garbage before it or after it
                if (gap or weak) and inner_followed:
                    return Verdict.REJECT
                if weak and buf[start + 2] not in ADAPTER_COMMANDS:
                    return Verdict.REJECT  # no reply the adapter sends, and a frame inside
                if inner_followed is None:
                    return Verdict.WAIT
                if inner_followed or fixed:  # a frame inside a 20-byte one wins a tie
                    if followed is None:
                        return Verdict.WAIT
                    if not followed:
                        return Verdict.REJECT
            inner = buf.find(marker, inner + 1, limit)
        return Verdict.ACCEPT

    def _follows(
        self, buf: bytes | bytearray, at: int, end: int, idle: bool, fixed: bool
    ) -> bool | None:
        """Does a frame start at ``at``, right after a judged frame (``fixed``: a 20-byte one)?
        True also when the data ends there on an idle line; None: not known yet.

        After a variable frame the whole follower must be a valid frame, not just start with
        0xAA: a garbage 0xAA or a cut frame there means the line is damaged right there, which
        makes a false start before it likelier. Deciding that waits for at most one more frame
        (15 bytes), and only frames with a 0xAA inside are judged at all. After a 20-byte frame
        its first bytes decide (holding back a 20-byte follower as well would double the
        memory a decoder keeps).
        """
        if at >= end:
            return True if idle else None
        if buf[at] != START:
            return False
        if fixed:
            if self.protocol == "variable":
                return True
            # frames start with AA 55 here, and both bytes are asked for: a false start that
            # ran into a real 20-byte frame ends on one of its bytes, a 0xAA now and then
            return buf[at + 1] == END if at + 1 < end else (True if idle else None)
        if at + 1 < end and buf[at + 1] == END:
            return True  # a 20-byte adapter reply: its checksum settles it when it is reached
        if DATA_RE.match(buf, at) is not None:
            return True
        return None if not idle and self.could_complete(buf, at, end) else False

    def _inner_frame_end(
        self, buf: bytes | bytearray, inner: int, end: int, idle: bool, fixed: bool
    ) -> int | None:
        """Where a frame that counts starts at ``inner`` ends (-1: none does; None: not known
        until more bytes come).

        Inside a variable-protocol frame only variable frames count: a 20-byte frame there (a
        payload byte 0xAA before the 0x55 end marker starts one in 1 frame in 256) has its own
        checksum to settle it when the scan reaches it.
        """
        if inner + 1 >= end:
            return -1 if idle else None
        if buf[inner + 1] == END:
            if not fixed:
                return -1
            if inner + FIXED_LENGTH > end:
                return -1 if idle else None
            return inner + FIXED_LENGTH if checksum_ok(buf, inner) else -1
        match = DATA_RE.match(buf, inner)
        if match is not None:
            return match.end()
        return None if not idle and self.could_complete(buf, inner, end) else -1

    def held_back(self, buf: bytes | bytearray, pos: int, stop: int, end: int) -> bool:
        """True when a 0xAA in ``buf[pos:stop]`` may still grow into a frame covering ``stop``.

        Emitting the later match now would make the output depend on how the stream was chunked.
        """
        start = buf.find(START, max(pos, end - FIXED_LENGTH + 1), stop)
        while start >= 0:
            if self.could_complete(buf, start, end):
                return True
            start = buf.find(START, start + 1, stop)
        return False

    def incomplete_start(self, buf: bytes | bytearray, pos: int, end: int) -> int:
        """Index of the first 0xAA at or after ``pos`` that may still grow into a valid frame."""
        start = buf.find(START, max(pos, end - FIXED_LENGTH + 1))
        while start >= 0:
            if self.could_complete(buf, start, end):
                return start
            start = buf.find(START, start + 1)
        return end

    def could_complete(self, buf: bytes | bytearray, start: int, end: int) -> bool:
        """May the candidate at ``buf[start:end]`` (the data so far) still grow into a valid
        frame? False once it is whole (it did not match) or a field already rules it out."""
        avail = end - start
        if avail < 2:
            return True
        type_byte = buf[start + 1]
        if type_byte == END:
            return avail < FIXED_LENGTH
        if self.protocol == "fixed" or type_byte & 0xC0 != 0xC0 or type_byte & 0x0F > 8:
            return False
        ext = bool(type_byte & 0x20)
        id_len = 4 if ext else 2
        length = 3 + id_len + (0 if type_byte & 0x10 else type_byte & 0x0F)
        if avail >= length:
            return False  # complete but did not match: not a valid frame
        if avail >= 2 + id_len:
            arb_id = int.from_bytes(buf[start + 2 : start + 2 + id_len], "little")
            if arb_id > (MAX_EXT_ID if ext else MAX_STD_ID):
                return False
        return True
