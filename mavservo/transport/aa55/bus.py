"""python-can interface ``aa55`` for the Waveshare / Seeed USB-CAN adapters, over pyserial.

Registered under the ``can.interface`` entry point group, so ``can.Bus(interface="aa55",
channel="/dev/ttyUSB0", bitrate=1_000_000)`` and python-can's own tools (``can.viewer``,
``can.logger``) use it. Compared with python-can's ``seeedstudio`` driver it reads in chunks instead
of one byte per system call, rescans rejected candidates instead of dropping them, honours
``recv(timeout)`` exactly (0 = non-blocking), never raises a TypeError on a timeout mid-frame, and
turns a vanished device into ``can.CanOperationError`` instead of a hang.
"""

from __future__ import annotations

import collections
import errno
import logging
import math
import os
import select
import threading
import time
from collections.abc import Callable
from typing import Any, Literal, TypedDict

import can
import serial

from mavservo.errors import DeviceMissingError, EndpointBusyError
from mavservo.transport.aa55 import codec as aa55
from mavservo.transport.counters import TransportCounters

log = logging.getLogger(__name__)

#: When the line has been idle this long with a partial candidate pending, the candidate was a
#: false start or a truncated frame: the decoder rescans it (a real frame takes ~65 us at 2 Mbaud).
IDLE_FLUSH_S = 0.005

#: Most bytes taken from the port in one read: 4,900 frames, ~0.3 s of a saturated 2 Mbaud line.
READ_SIZE = 65536

#: Upper bound of ``read_interval_s``: beyond it the added latency is no longer a trade-off.
MAX_READ_INTERVAL_S = 0.05

#: ``read_interval_s="auto"``: reads are spaced by up to :data:`AUTO_HOLD_S` while the bytes
#: read over the last :data:`LOAD_WINDOW_S` exceed this fraction of what the serial line can
#: carry (a quarter of 2 Mbaud is ~3,800 frames/s, more than a 1 Mbit/s CAN bus at 40 % load),
#: and follow every USB burst at once below it: a servo bus's replies never wait, a saturated
#: line costs a fraction of the CPU (the way a network driver switches to polling under load).
AUTO_BUSY_FRACTION = 0.25
AUTO_HOLD_S = 0.008
#: A hold never lets more than this gather in the kernel: half of Linux's 4 KiB tty read
#: buffer, beyond which a tty throttles its device. So a hold is at most this / the byte rate
#: (8 ms at 2 Mbaud, shorter for a faster device), and a read that brought this much (the
#: reader is behind, or the device is faster than any serial line) is followed at once.
AUTO_HOLD_BYTES = 2048
LOAD_WINDOW_S = 0.05


def _read_interval(value: float | str) -> float | Literal["auto"]:
    """``read_interval_s`` as given in code or as a string from a python-can config file."""
    if value == "auto":
        return "auto"
    try:
        seconds = float(value)
    except (TypeError, ValueError):
        seconds = math.nan
    if not 0.0 <= seconds <= MAX_READ_INTERVAL_S:
        raise can.CanInitializationError(
            f"aa55: read_interval_s={value!r} is neither 'auto' nor 0..{MAX_READ_INTERVAL_S} s"
        )
    return seconds


class LineLoad:
    """Bytes per second read lately: a byte count that decays with time constant ``window_s``.

    One multiply and one ``exp`` per read, no history kept; after a silence it has decayed to
    nothing, so the first burst after idle is read at once.
    """

    def __init__(self, window_s: float) -> None:
        self.window_s = window_s
        self._count = 0.0
        self._t = -math.inf

    def add(self, n: int, now: float) -> float:
        """Count ``n`` bytes read at ``now`` (monotonic s); the rate in bytes per second."""
        self._count = self._count * math.exp(min(0.0, self._t - now) / self.window_s) + n
        self._t = now
        return self._count / self.window_s


def auto_hold_s(rate: float, chunk_bytes: int, busy_bytes_per_s: float) -> float:
    """How long ``read_interval_s="auto"`` waits before the next read, after a read of
    ``chunk_bytes`` with the line carrying ``rate`` bytes per second (see :data:`AUTO_HOLD_S`)."""
    if rate < busy_bytes_per_s or chunk_bytes >= AUTO_HOLD_BYTES:
        return 0.0
    return min(AUTO_HOLD_S, AUTO_HOLD_BYTES / rate)


def _descriptor(port: serial.SerialBase) -> int | None:
    """The port's file descriptor, or None for pyserial URL ports that have none."""
    try:
        return port.fileno()
    except (AttributeError, NotImplementedError, OSError, ValueError):
        return None


class _AdapterSettings(TypedDict):
    """What :func:`codec.settings_frame` needs besides the hardware filter."""

    bitrate: int
    mode: str
    protocol: aa55.ProtocolName
    extended: bool


class AdapterBusyError(EndpointBusyError, can.CanInitializationError):
    """The adapter's serial port is held by another process (a python-can open failure too)."""


class AdapterMissingError(DeviceMissingError, can.CanInitializationError):
    """No adapter at that path (unplugged, or back under another device name)."""


#: errno values of an open that found no device behind the path
_NO_DEVICE_ERRNOS = frozenset({errno.ENOENT, errno.ENODEV, errno.ENXIO})


def _open_error(channel: str, exc: BaseException) -> can.CanInitializationError:
    """The typed python-can error for a failed open of ``channel``: busy, missing or other."""
    if "exclusively lock" in str(exc):
        return AdapterBusyError(
            f"aa55: {channel} is in use by another process (another mavservo, or a "
            "python-can tool on the same adapter?); stop it first"
        )
    if getattr(exc, "errno", None) in _NO_DEVICE_ERRNOS:
        return AdapterMissingError(
            f"aa55: cannot open {channel}: {exc} (no adapter there: unplugged, or named "
            "differently?)"
        )
    return can.CanInitializationError(f"aa55: cannot open {channel}: {exc}")


class AA55Bus(can.BusABC, TransportCounters):
    """A CAN bus behind an AA-55 USB-CAN adapter on a serial port.

    :param channel: serial device (``/dev/ttyUSB0``, ``COM3``) or any pyserial URL.
    :param bitrate: CAN bitrate, one of :data:`mavservo.transport.aa55.codec.BITRATE_CODES`.
    :param serial_baud: serial line speed (the adapter's default is 2,000,000).
    :param protocol: ``"variable"`` (everyday) or ``"fixed"`` (20-byte checksummed frames).
    :param mode: ``normal``, ``loopback``, ``silent`` or ``loopback_silent``.
    :param extended: configure the adapter for extended frames (its hardware filter works on one
        kind only; sending either kind works regardless).
    :param can_filters: with exactly one filter, it is also programmed into the adapter.
    :param read_interval_s: least time between two reads of the port. 0 reads as soon as
        bytes arrive: lowest latency, one wake-up per USB burst (~1,000/s on a busy line). A few
        milliseconds batches several bursts per wake-up, at a fraction of the CPU; every frame
        then waits up to that long. ``"auto"`` (default) reads at once while the line is
        lightly used and spaces reads by up to :data:`AUTO_HOLD_S` while it carries more than
        :data:`AUTO_BUSY_FRACTION` of its capacity, never letting more than
        :data:`AUTO_HOLD_BYTES` gather. (A wake-up is what costs: on the shared dev
        VM a saturated line takes 6.5% of a core at 0, 4.8% at 4 ms, 3.2% at 10 ms; see
        docs/benchmarks.md.)
    :param on_reject: called with ``(reason, raw_bytes)`` for each rejected candidate, from the
        receiving thread; must not block (it is how run logs record garbage on the line).
    """

    def __init__(
        self,
        channel: str,
        bitrate: int = 1_000_000,
        serial_baud: int = 2_000_000,
        protocol: aa55.ProtocolName = "variable",
        mode: str = "normal",
        extended: bool = False,
        can_filters: can.typechecking.CanFilters | None = None,
        on_reject: Callable[[aa55.Rejection, bytes], None] | None = None,
        read_interval_s: float | str = "auto",
        **kwargs: Any,
    ) -> None:
        if not channel:
            raise can.CanInitializationError("aa55: a serial port is required (channel=...)")
        self._settings_kwargs: _AdapterSettings = {
            "bitrate": bitrate,
            "mode": mode,
            "protocol": protocol,
            "extended": extended,
        }
        try:  # validate before opening anything
            aa55.settings_frame(**self._settings_kwargs)
        except ValueError as exc:
            raise can.CanInitializationError(f"aa55: {exc}") from exc
        self.framing: aa55.ProtocolName = protocol
        self.bitrate = bitrate
        self.serial_baud = serial_baud
        self.on_reject = on_reject
        self.read_interval_s = _read_interval(read_interval_s)
        self._hold_s = 0.0 if self.read_interval_s == "auto" else self.read_interval_s
        self._load = LineLoad(LOAD_WINDOW_S)
        self._busy_bytes_per_s = AUTO_BUSY_FRACTION * serial_baud / 10  # 8N1: 10 bits a byte
        self.decoder = aa55.Decoder(protocol, messages=True, channel=channel)
        self._rx: collections.deque[can.Message] = collections.deque()
        self._read_lock = threading.Lock()
        self._write_lock = threading.Lock()
        self._last_byte_time = 0.0
        self._seen_rejections = 0
        self._others_seen = 0
        self._hw_filter: tuple[int, int] | None = None
        self.channel_info = f"AA-55 USB-CAN on {channel}"
        try:
            # exclusive: a second process on the adapter (a bridge started by hand beside the
            # service, can.logger) would steal half of every reply; refuse it at open instead
            self._serial = serial.serial_for_url(
                channel, baudrate=serial_baud, timeout=0, write_timeout=1.0, exclusive=True
            )
        except (serial.SerialException, ValueError, OSError) as exc:
            raise _open_error(channel, exc) from exc
        self._fd = _descriptor(self._serial)
        self._protocol = can.CanProtocol.CAN_20
        super().__init__(channel=channel, can_filters=can_filters, **kwargs)
        self.channel = channel
        self._send_settings()

    # -- configuration ------------------------------------------------------------------------

    def _send_settings(self) -> None:
        filter_id, mask = self._hw_filter if self._hw_filter else (0, 0)
        frame = aa55.settings_frame(filter_id=filter_id, mask=mask, **self._settings_kwargs)
        self._write(frame)

    def _apply_filters(self, filters: can.typechecking.CanFilters | None) -> None:
        # Software filtering stays on (BusABC applies self._filters in recv); the hardware filter
        # only spares the serial line when one filter of the adapter's ID kind is given.
        hw = None
        if filters and len(filters) == 1:
            only = filters[0]
            extended = bool(only.get("extended", False))
            if extended == self._settings_kwargs["extended"]:
                hw = (only["can_id"], only["can_mask"])
        changed = hw != self._hw_filter
        self._hw_filter = hw
        if changed and hasattr(self, "_serial"):
            self._send_settings()

    # -- sending ------------------------------------------------------------------------------

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        try:
            data = aa55.encode(msg, self.framing)
        except ValueError as exc:
            raise can.CanOperationError(f"aa55: cannot send {msg}: {exc}") from exc
        self._write(data)

    def _write(self, data: bytes) -> None:
        with self._write_lock:
            try:
                self._serial.write(data)
            except serial.SerialTimeoutException as exc:
                raise can.CanTimeoutError(f"aa55: write timed out on {self.channel}") from exc
            except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
                raise self._gone(exc) from exc

    # -- receiving ----------------------------------------------------------------------------

    def _read_available(self, wait: float, expect: bool = False) -> bool:
        """Read what the port has, waiting up to ``wait`` s for the first byte. False on timeout.

        On a port with a descriptor this is one ``select`` and one ``read`` of up to
        :data:`READ_SIZE` bytes, straight on the descriptor (pyserial opened it non-blocking).
        Going through ``Serial.in_waiting`` + ``Serial.read`` instead costs two more system calls
        and ~10 us of Python per wake-up, and a USB adapter wakes us ~1,000 times a second.
        ``expect``: bytes are probably waiting (the caller slept ``read_interval_s`` to let them
        gather), so read first and ``select`` only if there were none: one system call, and
        one piece of code less to fetch into a cold cache, per wake-up.
        """
        fd = self._fd
        if fd is None:
            return self._read_available_url(wait)
        try:
            chunk = b""
            if expect:
                try:
                    # Empty (VMIN=0) or EAGAIN: nothing yet, wait for it as usual; only an empty
                    # read of a port select calls readable means the device is gone.
                    chunk = os.read(fd, READ_SIZE)
                except BlockingIOError:
                    chunk = b""
            if not chunk:
                ready, _, _ = select.select([fd], [], [], max(wait, 0.0))
                if not ready:
                    return False
                chunk = os.read(fd, READ_SIZE)
        except (BlockingIOError, InterruptedError):
            return False
        except (OSError, ValueError, TypeError) as exc:
            raise self._gone(exc) from exc
        if not chunk:  # readable but empty: what a vanished USB device looks like on Linux
            raise self._gone("readable but no data")
        self._absorb_chunk(chunk)
        return True

    def _read_available_url(self, wait: float) -> bool:
        """:meth:`_read_available` for pyserial URL ports (``loop://``) that have no descriptor."""
        ser = self._serial
        try:
            if wait > 0 and not ser.in_waiting:
                time.sleep(min(wait, 0.001))
            waiting = ser.in_waiting
            chunk = ser.read(waiting) if waiting else b""
        except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
            raise self._gone(exc) from exc
        if not chunk:
            return False
        self._absorb_chunk(chunk)
        return True

    def _gone(self, why: object) -> can.CanOperationError:
        """The error every failed read or write turns into: the device went away."""
        return can.CanOperationError(f"aa55: the adapter on {self.channel} is gone ({why})")

    def _absorb_chunk(self, chunk: bytes) -> None:
        now = time.monotonic()
        if self.read_interval_s == "auto":
            rate = self._load.add(len(chunk), now)
            self._hold_s = auto_hold_s(rate, len(chunk), self._busy_bytes_per_s)
        self._last_byte_time = now
        self._absorb(self.decoder.feed(chunk, time.time()))

    def _absorb(self, items: list[Any]) -> None:
        """Queue the decoder's messages (it makes ``can.Message``s, see ``Decoder(messages=)``).

        Only settings and control frames are not messages, and the decoder counts them: an
        unchanged count means every item is a message, known without looking at each one.
        """
        decoder = self.decoder
        others = decoder.settings + decoder.control
        if others == self._others_seen:  # the usual case
            self._rx.extend(items)
        else:
            self._others_seen = others
            for item in items:
                if type(item) is can.Message:
                    self._rx.append(item)
                else:
                    log.debug("aa55: control frame from adapter: %s", item)
        if self.on_reject is not None:
            self._report_rejections()

    def _report_rejections(self) -> None:
        total = sum(self.decoder.rejected.values())
        new = total - self._seen_rejections
        self._seen_rejections = total
        if new <= 0 or self.on_reject is None:
            return
        recent = list(self.decoder.rejections)[-new:]
        for reason, raw in recent:
            self.on_reject(reason, raw)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """``BusABC.recv``: the next message that passes the filters, or None after ``timeout``.

        One read brings ~15 frames at a saturated line; the 2nd to 15th need no clock, lock or
        loop, only the filter check. The 1st is read on a thread that has just slept, when every
        instruction and object it touches is out of the caches (20-60 us per wake-up after 1 ms
        of sleep on a shared VM, see docs/benchmarks.md), so the wait is one loop of our
        own instead of ``BusABC.recv`` (its clock, logging and filter layers) over
        :meth:`_recv_internal`. Same contract: ``timeout`` None waits for ever, 0 does not
        block, and a message the filters drop does not end the wait.
        """
        if self._rx:  # checked first: raising IndexError is costly on a cold CPU
            try:
                msg = self._rx.popleft()  # deque.popleft is atomic: safe beside a reading thread
            except IndexError:  # another thread took the last one
                pass
            else:
                if self._filters is None or self._matches_filters(msg):
                    return msg
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:  # ends on a message that passes the filters, or at the deadline
            received = self._receive(deadline)
            if received is None or self._filters is None or self._matches_filters(received):
                return received

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        deadline = None if timeout is None else time.monotonic() + timeout
        return self._receive(deadline), False

    def _receive(self, deadline: float | None) -> can.Message | None:
        """The next decoded message, reading the port until ``deadline`` (None: no limit)."""
        slept = False
        with self._read_lock:
            while True:
                if self._rx:
                    return self._rx.popleft()
                now = time.monotonic()
                idle = now - self._last_byte_time
                if self.decoder.pending and idle >= IDLE_FLUSH_S:
                    # The rest of the candidate may be waiting in the port (the caller was
                    # slow to come back): read it before declaring the line idle.
                    if not self._read_available(0):
                        self._absorb(self.decoder.flush(time.time()))
                    continue
                if deadline is not None and now >= deadline:
                    if self._read_available(0):
                        continue
                    return None
                wait = 0.1 if deadline is None else deadline - now
                if self.decoder.pending:
                    wait = min(wait, IDLE_FLUSH_S - idle)
                hold = self._last_byte_time + self._hold_s - now
                if hold > 0.0:  # let more bursts gather before the next read
                    time.sleep(min(hold, wait))
                    slept = True
                    continue
                self._read_available(wait, expect=slept)
                slept = False

    # -- lifecycle ----------------------------------------------------------------------------

    def fileno(self) -> int:
        """The serial port's descriptor (for ``select`` and python-can's asyncio ``Notifier``).

        -1 only for a pyserial URL port that has no descriptor (``loop://``, ``socket://``...),
        as python-can's contract allows; a port that is closed or gone raises
        ``CanOperationError`` instead of passing for a bus without a descriptor.
        """
        if self._fd is None:
            return -1
        try:
            return int(self._serial.fileno())
        except (serial.SerialException, OSError, ValueError, AttributeError) as exc:
            raise self._gone(exc) from exc

    def stats(self) -> dict[str, Any]:
        """Decoder counters, for summaries and run logs."""
        d = self.decoder
        return {
            "frames": d.frames,
            "bytes_discarded": d.bytes_discarded,
            "rejected": {r.value: n for r, n in d.rejected.items()},
            "control_frames": d.control + d.settings,
            "read_interval_s": self._hold_s,
        }

    def shutdown(self) -> None:
        super().shutdown()
        try:
            self._serial.close()
        except Exception as exc:  # closing a vanished device must not raise
            log.debug("aa55: close failed: %s", exc)

    @staticmethod
    def _detect_available_configs() -> list[can.typechecking.AutoDetectedConfig]:
        try:
            from serial.tools import list_ports
        except ImportError:  # pragma: no cover
            return []
        return [
            {"interface": "aa55", "channel": port.device}
            for port in list_ports.comports()
            if port.vid == 0x1A86  # QinHeng CH340/CH341, the chip inside these adapters
        ]
