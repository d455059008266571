"""A simulated slcan adapter (CANable, CANUSB, CAN232): LAWICEL ASCII on a pseudo-terminal.

python-can's own ``slcan`` interface opens its path like a real stick, so the bridge, the doctor
and the tests reach the simulated servos through the same driver a user's CANable runs.

The command set is the LAWICEL CANUSB / CAN232 manual's (LAWICEL AB, "CANUSB ASCII commands"),
each command a line ending in CR, each answered with CR (OK) or BEL (error):

* ``Sn`` set a standard bitrate (``S0`` 10k, ``S1`` 20k, ``S2`` 50k, ``S3`` 100k, ``S4`` 125k,
  ``S5`` 250k, ``S6`` 500k, ``S7`` 800k, ``S8`` 1M); only while the channel is closed.
  ``sxxyy`` (raw BTR0/BTR1 registers) is refused here: the simulation has no SJA1000 clock.
* ``O`` open the channel; ``L`` open it listen-only (it receives, never transmits or ACKs);
  ``C`` close it.
* ``tiiildd..`` / ``Tiiiiiiiildd..`` send a standard / extended data frame, answered ``z`` /
  ``Z`` then CR; ``riiil`` / ``Riiiiiiiil`` the remote frames. Refused (BEL) while closed,
  listen-only, or malformed (bad hex, a DLC above 8, data length not the DLC's).
* ``F`` status flags ``Fxx`` (bit 3 data overrun, bit 7 bus error: frames lost to a bitrate
  mismatch); open only. ``V`` hardware/software version ``Vhhss``; ``N`` serial ``Nxxxx``.
* ``Zn`` timestamps off/on (on: 4 hex digits of milliseconds, modulo 60,000, after the data).

Received frames go to the host in the same ``t``/``T``/``r``/``R`` notation. A line longer than
the longest command, or one that is not ASCII, is discarded with BEL.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable

import can

from .pty_adapter import LineFaults, PtyAdapter
from .servo import SimServo

OK = b"\r"
ERROR = b"\a"

#: LAWICEL ``Sn``: the manual's table of standard bitrates.
BITRATES = {
    "0": 10_000,
    "1": 20_000,
    "2": 50_000,
    "3": 100_000,
    "4": 125_000,
    "5": 250_000,
    "6": 500_000,
    "7": 800_000,
    "8": 1_000_000,
}
#: ``T`` + 8 id digits + DLC + 16 data digits + 4 timestamp digits: the longest line.
MAX_LINE = 30
VERSION = "V1013"
SERIAL = "NSIM1"


def format_frame(msg: can.Message, timestamp_ms: int | None = None) -> bytes:
    """``msg`` in LAWICEL notation, without the CR."""
    if msg.is_extended_id:
        head = f"{'R' if msg.is_remote_frame else 'T'}{msg.arbitration_id:08X}{msg.dlc:d}"
    else:
        head = f"{'r' if msg.is_remote_frame else 't'}{msg.arbitration_id:03X}{msg.dlc:d}"
    body = "" if msg.is_remote_frame else bytes(msg.data[: msg.dlc]).hex().upper()
    stamp = "" if timestamp_ms is None else f"{timestamp_ms % 60_000:04X}"
    return (head + body + stamp).encode("ascii")


_HEX = frozenset("0123456789ABCDEFabcdef")


def _hex(text: str, digits: int) -> int | None:
    """``text`` as a number of exactly ``digits`` hex digits (``int()`` alone would also take
    signs, spaces and underscores)."""
    if len(text) != digits or not set(text) <= _HEX:
        return None
    return int(text, 16)


def parse_frame(line: str) -> can.Message | None:
    """A ``t``/``T``/``r``/``R`` command as a message; None when malformed."""
    kind = line[:1]
    if kind not in ("t", "T", "r", "R"):
        return None
    extended = kind in "TR"
    id_digits = 8 if extended else 3
    arbitration_id = _hex(line[1 : 1 + id_digits], id_digits)
    dlc_text = line[1 + id_digits : 2 + id_digits]
    if arbitration_id is None or not dlc_text.isdigit():
        return None
    dlc = int(dlc_text)
    if dlc > 8 or arbitration_id >= (1 << 29 if extended else 1 << 11):
        return None
    rest = line[2 + id_digits :]
    remote = kind in "rR"
    if remote and rest:
        return None
    if not remote and (len(rest) != 2 * dlc or not set(rest) <= _HEX):
        return None
    return can.Message(
        arbitration_id=arbitration_id,
        is_extended_id=extended,
        is_remote_frame=remote,
        dlc=dlc,
        data=b"" if remote else bytes.fromhex(rest),
    )


class SlcanEmulator(PtyAdapter):
    """A LAWICEL/slcan adapter on a pty, carrying frames to simulated servos (see module).

    It powers up closed, at ``bitrate`` (a CANable keeps none, but a host that sends no
    ``Sn`` gets this one), timestamps off.
    """

    thread_name = "sim-slcan-adapter"

    def __init__(
        self,
        servos: Iterable[SimServo],
        *,
        bitrate: int = 1_000_000,
        line_faults: LineFaults | None = None,
        link_path: str | None = None,
        seed: int = 0,
        clock: Callable[[], float] = time.monotonic,
        nodes_bitrate: int | None = None,
    ) -> None:
        self.state = "closed"
        """``closed``, ``open`` or ``listen``."""
        self.timestamps = False
        self.commands = 0
        self.errors = 0
        """Commands answered with BEL."""
        self.listen_opens = 0
        self._line = bytearray()
        self._discarding = False
        super().__init__(
            servos,
            bitrate=bitrate,
            line_faults=line_faults,
            link_path=link_path,
            seed=seed,
            clock=clock,
            nodes_bitrate=nodes_bitrate,
        )

    @property
    def mode(self) -> str:
        """``normal`` or ``silent`` (listen-only), like the AA-55 emulator's, or ``closed``."""
        return {"open": "normal", "listen": "silent"}.get(self.state, "closed")

    def _on_plug(self) -> None:
        self._line.clear()
        self._discarding = False

    def _from_host(self, data: bytes, now: float) -> None:
        data = self._line_to_adapter(data)
        replies: list[bytes] = []
        for byte in data:
            if byte == 0x0D:
                if self._discarding:
                    self._discarding = False
                    replies.append(self._error())
                else:
                    replies.append(self._command(bytes(self._line), now))
                self._line.clear()
            elif self._discarding:
                continue
            elif len(self._line) >= MAX_LINE:
                self._line.clear()
                self._discarding = True
            else:
                self._line.append(byte)
        if replies:
            self._write(b"".join(replies), 0)

    def _error(self) -> bytes:
        self.errors += 1
        return ERROR

    def _command(self, raw: bytes, now: float) -> bytes:
        self.commands += 1
        try:
            line = raw.decode("ascii")
        except UnicodeDecodeError:
            return self._error()
        if not line:
            return OK  # an empty line (a host clearing the parser) is harmless
        head = line[0]
        if head in "tTrR":
            return self._transmit(line, now)
        if head == "S" and len(line) == 2:
            if self.state != "closed" or line[1] not in BITRATES:
                return self._error()
            self.canbus.bitrate = BITRATES[line[1]]
            return OK
        if head in "OL" and len(line) == 1:
            if self.state != "closed":
                return self._error()
            self.state = "open" if head == "O" else "listen"
            self.listen_opens += head == "L"
            return OK
        if line == "C":
            self.state = "closed"
            return OK
        if line == "F":
            if self.state == "closed":
                return self._error()
            flags = (0x08 if self.bytes_overflowed else 0) | (
                0x80 if self.canbus.bitrate_mismatches else 0
            )
            return f"F{flags:02X}".encode() + OK
        if line == "V":
            return VERSION.encode() + OK
        if line == "N":
            return SERIAL.encode() + OK
        if head == "Z" and line[1:] in ("0", "1"):
            if self.state != "closed":
                return self._error()
            self.timestamps = line[1] == "1"
            return OK
        return self._error()  # sxxyy and anything else this adapter does not do

    def _transmit(self, line: str, now: float) -> bytes:
        if self.state != "open":
            return self._error()
        msg = parse_frame(line)
        if msg is None:
            return self._error()
        self.frames_from_host += 1
        self.canbus.submit(msg, now)
        return (b"Z" if msg.is_extended_id else b"z") + OK

    def _to_host(self, frames: list[tuple[float, can.Message]]) -> None:
        if self.state == "closed" or not frames:
            return
        lines = []
        for end, msg in frames:
            stamp = int(end * 1000) if self.timestamps else None
            lines.append(format_frame(msg, stamp) + OK)
        self._write(b"".join(lines), len(lines))
