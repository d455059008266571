"""A MAVLink FTP download client that waits and retries as QGroundControl's FTPManager does.

QGroundControl (src/Vehicle/FTPManager.h: ``_ackOrNakTimeoutMsecs = 1000``, ``_maxRetry = 3``;
FTPManager.cc ``_sendRequestExpectAck``: every request, a retry included, carries a new sequence
number, the expected reply's is that + 1) opens the file, reads it with BurstReadFile, restarts
its 1,000 ms timer at every packet, and asks again from the first byte it lacks when the timer
runs out, at most 3 times in a row before it gives up. This client does the same over a real
pymavlink connection, and records when each reply arrived (for the benchmark), so a test sees
what a ground station would: the file, or "no reply after 4 tries".
"""

from __future__ import annotations

import struct
import time
from dataclasses import dataclass, field
from typing import Any

HEADER = struct.Struct("<HBBBBBBI")
OP_TERMINATE_SESSION = 1
OP_OPEN_FILE_RO = 4
OP_BURST_READ_FILE = 15
OP_ACK = 128
OP_NAK = 129
ERR_EOF = 6
TIMEOUT_S = 1.0
MAX_RETRY = 3


class FtpGaveUp(RuntimeError):
    """The server did not answer within the time-out, 1 + MAX_RETRY times in a row."""


@dataclass
class Download:
    data: bytes
    seconds: float
    #: seconds between a request (or the previous packet of its burst) and each reply
    waits: list[float] = field(default_factory=list)
    retries: int = 0


class QgcLikeFtp:
    """Downloads files from ``(target_system, target_component)`` over ``conn``."""

    def __init__(
        self,
        conn: Any,
        target: tuple[int, int],
        timeout_s: float = TIMEOUT_S,
        retries: int = MAX_RETRY,
    ) -> None:
        self.conn = conn
        self.target = target
        self.timeout_s = timeout_s
        self.retries = retries
        self._seq = 0

    def download(self, path: str) -> Download:
        started = time.monotonic()
        waits: list[float] = []
        retries = 0
        name = path.encode("ascii")
        reply, wait, used = self._exchange(OP_OPEN_FILE_RO, 0, 0, name, len(name))
        waits.append(wait)
        retries += used
        session, size = reply[1], int.from_bytes(reply[7][:4], "little")
        data = b""
        tries = 0
        while len(data) < size:
            seq = self._send(OP_BURST_READ_FILE, session, len(data), b"", 239)
            sent = time.monotonic()
            got_any = False
            while len(data) < size:
                reply = self._receive(sent + self.timeout_s, burst_from=seq)
                if reply is None:
                    break
                now = time.monotonic()
                waits.append(now - sent)
                sent = now  # the timer restarts at every packet
                opcode, offset, body, complete = reply[2], reply[6], reply[7], reply[5]
                if opcode == OP_NAK:
                    if body[:1] == bytes([ERR_EOF]):
                        break
                    raise RuntimeError(f"NAK {body[:1].hex()} reading {path} at {len(data)}")
                if offset == len(data):
                    data += body
                    got_any = True
                if complete:
                    break
            if got_any:
                tries = 0
                continue
            tries += 1
            retries += 1
            if tries > self.retries:
                raise FtpGaveUp(f"{path}: no reply after {tries} tries at offset {len(data)}")
        _, wait, used = self._exchange(OP_TERMINATE_SESSION, session, 0, b"", 0)
        waits.append(wait)
        return Download(data, time.monotonic() - started, waits, retries + used)

    # ------------------------------------------------------------------ plumbing

    def _exchange(
        self, opcode: int, session: int, offset: int, body: bytes, size: int
    ) -> tuple[tuple[Any, ...], float, int]:
        """One request and its ACK, with QGroundControl's time-out and retries; returns the
        reply, the wait for it and the retries it took."""
        for attempt in range(self.retries + 1):
            seq = self._send(opcode, session, offset, body, size)
            sent = time.monotonic()
            reply = self._receive(sent + self.timeout_s, expect_seq=(seq + 1) & 0xFFFF)
            if reply is not None:
                if reply[2] == OP_NAK:
                    raise RuntimeError(f"NAK {reply[7][:1].hex()} to opcode {opcode}")
                return reply, time.monotonic() - sent, attempt
        raise FtpGaveUp(f"opcode {opcode}: no reply after {self.retries + 1} tries")

    def _send(self, opcode: int, session: int, offset: int, body: bytes, size: int) -> int:
        self._seq = (self._seq + 2) & 0xFFFF  # a new sequence number each time, as QGC
        header = HEADER.pack(self._seq, session, opcode, size, 0, 0, 0, offset)
        payload = (header + body).ljust(251, b"\x00")
        self.conn.mav.file_transfer_protocol_send(0, self.target[0], self.target[1], payload)
        return self._seq

    def _receive(
        self, deadline: float, *, expect_seq: int | None = None, burst_from: int | None = None
    ) -> tuple[Any, ...] | None:
        """The next reply for us that answers the request in flight, or None at ``deadline``."""
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            msg = self.conn.recv_match(type="FILE_TRANSFER_PROTOCOL", blocking=True, timeout=left)
            if msg is None:
                continue
            if msg.get_srcComponent() != self.target[1]:
                continue
            mine = (msg.target_system, msg.target_component)
            if mine != (self.conn.mav.srcSystem, self.conn.mav.srcComponent):
                continue
            payload = bytes(msg.payload)
            seq, session, opcode, size, req, complete, _pad, offset = HEADER.unpack_from(payload)
            reply = (seq, session, opcode, size, req, complete, offset, payload[12 : 12 + size])
            if expect_seq is not None and seq == expect_seq:
                return reply
            ours = burst_from is not None and ((seq - burst_from) & 0xFFFF) <= 64
            if ours and req == OP_BURST_READ_FILE:  # the burst's own advancing numbers
                return reply
