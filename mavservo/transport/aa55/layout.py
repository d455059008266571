"""What an AA-55 frame looks like on the serial line: markers, lengths, ID ranges, the layout
patterns and the 20-byte frames' checksum (sans-I/O, imports nothing of the project).

Its own module because two parts read these facts: the codec (:mod:`.codec`, encoding and
decoding) and the judge of candidates (:mod:`.candidates`, deciding whether a match is a false
start over a real frame), which the codec owns; neither may import the other's module for them.
Wire facts: the Waveshare USB-CAN-A / Seeed USB-CAN Analyzer protocol, see :mod:`.codec`.
"""

from __future__ import annotations

import re

START = 0xAA
END = 0x55
FIXED_LENGTH = 20
FIXED_START = b"\xaa\x55"
MAX_STD_ID = 0x7FF
MAX_EXT_ID = 0x1FFFFFFF

# Command bytes of the fixed 20-byte frames (byte 2).
CMD_FIXED_DATA = 0x01
CMD_SETTINGS_FIXED = 0x02  # settings, then use the fixed 20-byte protocol
CMD_SETTINGS_VARIABLE = 0x12  # settings, then use the variable-length protocol
CMD_STATUS = 0x04
#: The commands the adapter's own 20-byte frames carry (data, settings echoes, status).
ADAPTER_COMMANDS = frozenset(
    (CMD_FIXED_DATA, CMD_SETTINGS_FIXED, CMD_SETTINGS_VARIABLE, CMD_STATUS)
)


def layout_pattern(ext: bool, rtr: bool, dlc: int) -> bytes:
    """Regex for one valid variable-length frame of one layout (ID kind, remote or not, DLC).

    The ID's top byte is bounded so out-of-range IDs never match, and the payload length is tied
    to the DLC nibble (remote frames carry none).
    """
    type_byte = 0xC0 | (0x20 if ext else 0) | (0x10 if rtr else 0) | dlc
    ident = rb"...[\x00-\x1f]" if ext else rb".[\x00-\x07]"
    payload = b"" if rtr else b".{%d}" % dlc
    return re.escape(bytes((START, type_byte))) + ident + payload + rb"\x55"


LAYOUTS = [(ext, rtr, dlc) for dlc in range(9) for ext in (False, True) for rtr in (False, True)]

# Searching for the leftmost match of any layout from a position is the same as the byte-by-byte
# state machine that rescans after every rejected 0xAA, but runs in C.
DATA_ALTERNATIVES = b"|".join(layout_pattern(*layout) for layout in LAYOUTS)
#: One valid variable-length data frame of any layout (no fixed 20-byte frames).
DATA_RE = re.compile(DATA_ALTERNATIVES, re.DOTALL)


def checksum_ok(buf: bytes | bytearray, start: int) -> bool:
    """Does the 20-byte frame at ``start`` carry the low byte of the sum of its bytes 2..18?"""
    return sum(buf[start + 2 : start + 19]) & 0xFF == buf[start + 19]
