"""MAVLink frames out of hostile bytes, and secrets out of logged frames.

Why not pymavlink's ``parse_buffer``: its parser (1) hands back a ``MAVLink_unknown`` for any
message id outside the dialect *before* checking the CRC or the signature, so one 15-byte frame
with a made-up id passed as "received" with signing on; (2) trusts the length byte of any
header: a 10-byte datagram announcing 255 bytes swallowed the next 267 bytes, i.e. the next
senders' datagrams on a shared UDP port, and on a stream it skips the whole announced length
after a bad frame, losing the good frames inside it.

:class:`FrameScanner` frames and classifies itself and asks pymavlink only to ``decode`` one
complete candidate frame (CRC, signature, fields):

* a UDP datagram is parsed on its own (:meth:`FrameScanner.datagram`): a datagram never
  continues another, so nothing one sender sends can affect how the next datagram is read;
* a stream (serial, TCP) keeps the bytes of an incomplete frame for the next read
  (:meth:`FrameScanner.stream`), unless a complete frame with a right CRC already follows
  inside it (then its length was bogus); a candidate that fails its CRC, has an unknown id
  or bad flags is skipped by one byte only, so a good frame that starts inside it is found
  again, not lost;
* unknown ids are counted (``unknown_id``) and never returned: without the dialect's CRC
  extra byte their CRC cannot be checked, nor, before that, can their framing be trusted.

:func:`redact_secrets` zeroes secret fields (signing keys, passwords) in a raw frame before it
is written to the run's tlog.
"""

from __future__ import annotations

import re
import struct
from collections import Counter
from functools import cache
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

MAGIC_V1 = 0xFE
MAGIC_V2 = 0xFD
HEADER_V1 = 6
HEADER_V2 = 10
CHECKSUM_LEN = 2
SIGNATURE_LEN = 13
IFLAG_SIGNED = 0x01
MAX_FRAME_LEN = HEADER_V2 + 255 + CHECKSUM_LEN + SIGNATURE_LEN
#: Refused candidate frames after which the rest of a datagram is dropped unread.
MAX_REFUSED_PER_DATAGRAM = 64

#: Message fields that carry a secret, by (message name, field name). SETUP_SIGNING hands a
#: signing key over; the others carry passwords or authentication keys.
SECRET_FIELDS: tuple[tuple[str, str], ...] = (
    ("SETUP_SIGNING", "secret_key"),
    ("CHANGE_OPERATOR_CONTROL", "passkey"),
    ("AUTH_KEY", "key"),
    ("WIFI_CONFIG_AP", "password"),
    ("AIRLINK_AUTH", "password"),
)

# what a candidate frame turned out to be (besides a decoded message)
BAD_DATA = "bad_data"
SIGNING_REJECTED = "signing_rejected"
UNKNOWN_ID = "unknown_id"


def frame_length(buf: bytes | bytearray, pos: int) -> int | None:
    """Total length of the frame whose marker is at ``buf[pos]``; None until the header bytes
    that give it are there."""
    if buf[pos] == MAGIC_V1:
        return buf[pos + 1] + HEADER_V1 + CHECKSUM_LEN if len(buf) > pos + 1 else None
    if len(buf) <= pos + 2:
        return None
    signature = SIGNATURE_LEN if buf[pos + 2] & IFLAG_SIGNED else 0
    return buf[pos + 1] + HEADER_V2 + CHECKSUM_LEN + signature


def message_id(frame: bytes | bytearray, pos: int = 0) -> int:
    """Message id of the (header-complete) frame starting at ``frame[pos]``."""
    if frame[pos] == MAGIC_V1:
        return frame[pos + 5]
    return frame[pos + 7] | frame[pos + 8] << 8 | frame[pos + 9] << 16


def crc_ok(frame: bytes | bytearray) -> bool:
    """Whether a complete candidate frame of a known message has a right CRC (no signature
    check: no side effect on the signing streams)."""
    message_class = mavlink2.mavlink_map.get(message_id(frame))
    if message_class is None:
        return False
    header = HEADER_V1 if frame[0] == MAGIC_V1 else HEADER_V2
    end = header + frame[1]
    crc = mavlink2.x25crc(frame[1:end])
    crc.accumulate(bytes([message_class.crc_extra]))
    return int(struct.unpack_from("<H", frame, end)[0]) == crc.crc


def complete_frame_after(buf: bytearray, start: int) -> bool:
    """Whether a complete frame with a right CRC starts at or after ``start``: then a frame
    before it that is still "incomplete" announced a length it does not have (a stream must not
    wait for 280 bytes behind a bogus header: at one heartbeat a second that is longer than
    the autopilot's heartbeat timeout)."""
    pos = start
    while pos < len(buf):
        if buf[pos] in (MAGIC_V1, MAGIC_V2):
            length = frame_length(buf, pos)
            if (
                length is not None
                and pos + length <= len(buf)
                and not (buf[pos] == MAGIC_V2 and buf[pos + 2] & ~IFLAG_SIGNED)
                and crc_ok(buf[pos : pos + length])
            ):
                return True
        pos += 1
    return False


class FrameScanner:
    """Frames, classifies and decodes MAVLink input; counts what it refuses in ``counters``
    (``bad_data``, ``signing_rejected``, ``unknown_id``)."""

    def __init__(self, decoder: mavlink2.MAVLink, counters: Counter[str] | None = None) -> None:
        self._decoder = decoder
        self._pending = bytearray()
        self.counters: Counter[str] = Counter() if counters is None else counters

    def datagram(self, data: bytes) -> list[Any]:
        """Messages of one UDP datagram, parsed on its own; an incomplete frame at its end is
        bad data (nothing is kept for the next datagram)."""
        messages, _ = self._scan(bytearray(data), final=True)
        return messages

    def stream(self, data: bytes) -> list[Any]:
        """Messages completed by the next chunk of a byte stream."""
        buf = self._pending + data
        messages, used = self._scan(buf, final=False)
        self._pending = buf[used:]
        return messages

    def _scan(self, buf: bytearray, final: bool) -> tuple[list[Any], int]:
        messages: list[Any] = []
        pos = 0
        garbage = False  # inside a run of bytes that belong to no frame (counted once per run)
        refused = 0  # candidates that failed in this datagram
        while pos < len(buf):
            if buf[pos] not in (MAGIC_V1, MAGIC_V2):
                pos, garbage = pos + 1, True
                continue
            length = frame_length(buf, pos)
            if length is None or pos + length > len(buf):
                if not final and not complete_frame_after(buf, pos + 1):
                    break  # the rest of this frame is still on its way
                pos, garbage = pos + 1, True  # truncated, or a bogus length: look inside it
                continue
            if garbage:
                self.counters[BAD_DATA] += 1
                garbage = False
            verdict = self._classify(buf, pos, length)
            if not isinstance(verdict, str):
                messages.append(verdict)
                pos += length
                continue
            self.counters[verdict] += 1
            # a frame whose CRC held (only its signature failed) is skipped whole; anything
            # else proves nothing about its length: resynchronise on the next byte
            pos += length if verdict == SIGNING_REJECTED else 1
            refused += 1
            if final and refused >= MAX_REFUSED_PER_DATAGRAM:
                # a datagram of crafted candidates (65 KB of FE 00 ...) would cost ~0.2 s of
                # CPU, byte by byte; real senders send a few frames per datagram
                self.counters["datagram_rest_dropped"] += 1
                return messages, len(buf)
        if garbage:
            self.counters[BAD_DATA] += 1
        return messages, pos

    def _classify(self, buf: bytearray, pos: int, length: int) -> Any:
        """The decoded message of the candidate at ``pos``, or why it was refused. The cheap
        checks (flags, known id, CRC) come first: no copy, no exception for most garbage."""
        if buf[pos] == MAGIC_V2 and buf[pos + 2] & ~IFLAG_SIGNED:
            return BAD_DATA  # an incompatibility flag we do not understand: must be dropped
        if message_id(buf, pos) not in mavlink2.mavlink_map:
            return UNKNOWN_ID
        frame = buf[pos : pos + length]
        if not crc_ok(frame):
            return BAD_DATA
        try:
            return self._decoder.decode(frame)
        except mavlink2.MAVError as exc:
            return SIGNING_REJECTED if "signature" in str(exc).lower() else BAD_DATA
        except Exception:  # noqa: BLE001 - any other decode failure of hostile bytes
            return BAD_DATA


# ---------------------------------------------------------------------- redaction

_FORMAT_TOKEN = re.compile(r"(\d*)([xcbB?hHiIlLqQnNefdspP])")


def _field_spans(message_class: Any) -> dict[str, tuple[int, int]]:
    """(offset, size) of each field in the message's wire payload (fields in wire order)."""
    tokens = _FORMAT_TOKEN.findall(message_class.unpacker.format)
    spans: dict[str, tuple[int, int]] = {}
    offset = 0
    for name, (count, code) in zip(message_class.ordered_fieldnames, tokens, strict=True):
        size = struct.calcsize(f"<{count}{code}")
        spans[name] = (offset, size)
        offset += size
    return spans


@cache
def _secret_spans() -> dict[int, tuple[tuple[int, int], ...]]:
    """Message id -> payload spans to zero, built once from the dialect."""
    spans: dict[int, list[tuple[int, int]]] = {}
    for message_name, field in SECRET_FIELDS:
        msg_id = getattr(mavlink2, f"MAVLINK_MSG_ID_{message_name}", None)
        if msg_id is None:
            continue
        spans.setdefault(msg_id, []).append(_field_spans(mavlink2.mavlink_map[msg_id])[field])
    return {msg_id: tuple(s) for msg_id, s in spans.items()}


def redact_secrets(frame: bytes) -> bytes:
    """``frame`` with its secret fields zeroed and its CRC recomputed (so log readers still
    decode it); frames without secrets are returned unchanged. The signature, if any, no
    longer matches: a redacted frame is a record, never something to replay."""
    if len(frame) < HEADER_V1 + CHECKSUM_LEN or frame[0] not in (MAGIC_V1, MAGIC_V2):
        return frame
    header = HEADER_V1 if frame[0] == MAGIC_V1 else HEADER_V2
    if len(frame) < header + CHECKSUM_LEN:
        return frame
    spans = _secret_spans().get(message_id(frame))
    if not spans:
        return frame
    payload_len = frame[1]
    if len(frame) < header + payload_len + CHECKSUM_LEN:
        return frame
    out = bytearray(frame)
    for offset, size in spans:
        start = header + min(offset, payload_len)
        end = header + min(offset + size, payload_len)
        out[start:end] = bytes(end - start)
    crc = mavlink2.x25crc(out[1 : header + payload_len])
    crc.accumulate(bytes([mavlink2.mavlink_map[message_id(frame)].crc_extra]))
    struct.pack_into("<H", out, header + payload_len, crc.crc)
    return bytes(out)
