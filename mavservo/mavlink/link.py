"""One MAVLink connection shared by several hosted components.

pymavlink's ``mavutil`` connection supplies the transport (UDP, TCP, serial), but one connection
object has one encoder, hence one sequence counter and one component id. A process hosting a servo
group (140) and a gimbal (154) must look like two components, so each hosted component gets its own
``MAVLink`` encoder (own sequence numbers, own signing stream) writing into the shared transport,
and parsing uses a separate decoder that checks signatures.

Signing: with a key, every outgoing message is signed; inbound messages that are unsigned (unless
``accept_unsigned``) or badly signed come out of pymavlink's parser as BAD_DATA with an "Invalid
signature" reason. They are counted here and never reach the core.

The receive thread waits at most ``POLL_S`` per call so :meth:`stop` is prompt. When the endpoint
fails (serial adapter unplugged, socket error) the link closes it, reports "link lost" through
``on_event``, and reopens it with exponential backoff, reporting "link recovered".
"""

from __future__ import annotations

import contextlib
import logging
import struct
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.mavlink.settings import SigningSettings

log = logging.getLogger(__name__)

POLL_S = 0.1
BACKOFF_START_S = 0.25
BACKOFF_MAX_S = 5.0
SIGNING_EPOCH = 1420070400  # MAVLink signing timestamps count 10 us units since 2015-01-01


def signing_timestamp(wall_time: float) -> int:
    return int(max(0.0, wall_time - SIGNING_EPOCH) * 100_000)


def _keep_stream_timestamps_on_bad_signature(decoder: mavlink2.MAVLink) -> None:
    """Undo pymavlink's stream-timestamp update when the signature then fails to verify.

    pymavlink 2.4 records a frame's timestamp for its (link, system, component) stream *before*
    checking the signature, so one forged frame with a far-future timestamp, made without the
    key, makes every genuine frame of that stream "old" and locks the autopilot out (found by
    tests/test_security.py). The MAVLink reference implementation only accepts the timestamp of
    a frame whose signature verified; this wrapper restores that order.
    """
    check = decoder.check_signature
    streams = decoder.signing.stream_timestamps

    def check_signature(msgbuf: bytearray, src_system: int, src_component: int) -> bool:
        stream = (msgbuf[-13], src_system, src_component)
        before = streams.get(stream)
        if check(msgbuf, src_system, src_component):
            return True
        if before is None:
            streams.pop(stream, None)
        else:
            streams[stream] = before
        return False

    decoder.check_signature = check_signature  # type: ignore[method-assign]


class _TransportWriter:
    """File-like object the per-component encoders write into."""

    def __init__(self, link: MavlinkLink) -> None:
        self._link = link

    def write(self, buf: bytes) -> None:
        self._link._write(buf)


class MavlinkLink:
    """Transport + per-component encoders + signature-checking decoder + receive thread."""

    def __init__(
        self,
        url: str,
        on_message: Callable[[Any, float], None],
        *,
        baud: int = 115200,
        signing: SigningSettings | None = None,
        on_event: Callable[[str], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
        monitor_outputs: Sequence[str] = (),
    ) -> None:
        self.url = url
        self.baud = baud
        self._monitor_urls = tuple(monitor_outputs)
        self._monitors: list[Any] = []
        #: ``tap(direction, raw_frame, t)`` sees every frame in ("in") and out ("out"), for the
        #: run log's .tlog; it runs on the I/O threads and must not block.
        self.tap: Callable[[str, bytes, float], None] | None = None
        self._signing = signing
        self._on_message = on_message
        self._on_event = on_event or (lambda text: None)
        self._clock = clock
        self._conn: Any = None
        self._write_lock = threading.Lock()
        self._encoders: dict[int, mavlink2.MAVLink] = {}
        self._decoder = self._new_decoder()
        self._writer = _TransportWriter(self)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._clients_before_read: set[Any] = set()
        self.counters: Counter[str] = Counter()

    # ------------------------------------------------------------------ set-up

    def _new_decoder(self) -> mavlink2.MAVLink:
        decoder = mavlink2.MAVLink(None)
        decoder.robust_parsing = True
        if self._signing is not None:
            decoder.signing.secret_key = self._signing.key
            decoder.signing.timestamp = signing_timestamp(time.time())
            if self._signing.accept_unsigned:
                decoder.signing.allow_unsigned_callback = lambda mav, msg_id: True
            _keep_stream_timestamps_on_bad_signature(decoder)
        return decoder

    def add_component(self, component_id: int, system_id: int, link_id: int = 0) -> None:
        """Host a component: its own encoder, sequence counter and signing stream."""
        encoder = mavlink2.MAVLink(self._writer, srcSystem=system_id, srcComponent=component_id)
        if self._signing is not None:
            encoder.signing.secret_key = self._signing.key
            encoder.signing.sign_outgoing = True
            encoder.signing.link_id = link_id
            encoder.signing.timestamp = signing_timestamp(time.time())
        self._encoders[component_id] = encoder

    def open(self) -> None:
        self._conn = mavutil.mavlink_connection(
            self.url, baud=self.baud, dialect="ardupilotmega", autoreconnect=False
        )

    def start(self) -> None:
        if self._conn is None:
            self.open()
        for url in self._monitor_urls:  # output-only copies; a failure there is not fatal
            try:
                self._monitors.append(mavutil.mavlink_connection(url, dialect="ardupilotmega"))
            except Exception as exc:  # noqa: BLE001 - any pymavlink open failure
                log.warning("monitor output %s unavailable: %s", url, exc)
        self._stop.clear()
        self._thread = threading.Thread(target=self._receive_loop, name="mavlink-rx", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        self._close()

    def _close(self) -> None:
        conn, self._conn = self._conn, None
        if conn is not None:
            with contextlib.suppress(OSError):
                conn.close()

    # ------------------------------------------------------------------ output

    def send(self, component_id: int, msg: Any, system_id: int) -> None:
        """Encode ``msg`` from ``component_id`` (its own sequence number and signature) and send."""
        encoder = self._encoders[component_id]
        try:
            with self._write_lock:
                encoder.srcSystem = system_id
                encoder.send(msg)
        except (struct.error, ValueError, TypeError, OverflowError):
            # a field the message cannot carry (NaN in an integer): drop this message only
            self.counters["encode_errors"] += 1
            if self.counters["encode_errors"] == 1:
                log.exception(
                    "cannot encode %s (dropped; counted in encode_errors)", msg.get_type()
                )
            return
        self.counters["sent"] += 1

    def _write(self, buf: bytes) -> None:
        conn = self._conn
        if conn is None:
            self.counters["send_dropped_link_down"] += 1
            return
        if self.tap is not None:
            self.tap("out", bytes(buf), self._clock())
        for monitor in self._monitors:
            with contextlib.suppress(OSError):
                monitor.write(buf)
        try:
            conn.write(buf)
        except OSError as exc:
            self.counters["send_errors"] += 1
            log.debug("mavlink write failed: %s", exc)

    # ------------------------------------------------------------------ input

    def _receive_loop(self) -> None:
        backoff = BACKOFF_START_S
        while not self._stop.is_set():
            conn = self._conn
            if conn is None:
                if self._stop.wait(backoff):
                    return
                backoff = min(backoff * 2, BACKOFF_MAX_S)
                try:
                    self.open()
                except Exception as exc:  # any failure to reopen: keep trying
                    log.debug("mavlink reopen failed: %s", exc)
                    continue
                backoff = BACKOFF_START_S
                self.counters["reconnects"] += 1
                self._on_event("MAVLink link recovered")
                continue
            try:
                data = self._read(conn)
            except Exception as exc:  # serial unplug, socket error: reopen with backoff
                if self._stop.is_set():
                    return
                log.warning("mavlink link lost: %s", exc)
                self.counters["link_lost"] += 1
                self._close()
                self._on_event("MAVLink link lost")
                continue
            if data and not self._feed(data):
                self._forget_new_clients(conn)

    def _read(self, conn: Any) -> bytes:
        if not conn.select(POLL_S):
            return b""
        # pymavlink's udpin adds each sender to the client set its write() iterates: a new
        # sender arriving mid-write raised "Set changed size" in the tick thread and killed it
        with self._write_lock:
            self._clients_before_read = set(getattr(conn, "clients", ()))
            data = conn.recv(4096)
        return bytes(data) if data else b""

    def _forget_new_clients(self, conn: Any) -> None:
        """pymavlink's udpin sends everything to every address a datagram ever came from: an
        address whose first datagram held nothing acceptable (garbage, unsigned or forged
        frames) must not start receiving our heartbeats, ACKs and telemetry, nor be able to
        multiply our output by spoofing many source addresses (a send racing the parse of that
        first datagram may still reach it once)."""
        clients = getattr(conn, "clients", None)
        if clients is None:
            return
        with self._write_lock:
            for address in clients - self._clients_before_read:
                clients.discard(address)
                getattr(conn, "clients_last_alive", {}).pop(address, None)
                self.counters["strangers_ignored"] += 1

    def _feed(self, data: bytes) -> int:
        """Parse ``data``; returns how many messages were accepted (signature-checked)."""
        now = self._clock()
        accepted = 0
        messages = self._decoder.parse_buffer(data) or []
        for msg in messages:
            if msg.get_type() == "BAD_DATA":
                reason = str(getattr(msg, "reason", ""))
                key = "signing_rejected" if "signature" in reason.lower() else "bad_data"
                self.counters[key] += 1
                continue
            self.counters["received"] += 1
            accepted += 1
            if self.tap is not None:
                self.tap("in", bytes(msg.get_msgbuf()), now)
            try:
                self._on_message(msg, now)
            except Exception:  # a handler bug must not kill the link
                self.counters["handler_errors"] += 1
                log.exception("error handling %s", msg.get_type())
        return accepted

    def stats(self) -> dict[str, Any]:
        # "signing_rejected" counts every frame refused by signing (unsigned or badly signed);
        # pymavlink's own reject_count stays 0 for unsigned frames, so it is not reported.
        return {
            **dict(self.counters),
            "bad_signatures": self._decoder.signing.badsig_count,
        }
