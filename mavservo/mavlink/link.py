"""One MAVLink connection shared by several hosted components.

pymavlink's ``mavutil`` connection supplies the transport (UDP, TCP, serial), but one connection
object has one encoder, hence one sequence counter and one component id. A process hosting a servo
group (140) and a gimbal (154) must look like two components, so each hosted component gets its own
``MAVLink`` encoder (own sequence numbers, own signing stream) writing into the shared transport,
and parsing uses a separate decoder that checks signatures.

Signing: with a key, every outgoing message is signed; inbound messages that are unsigned (unless
``accept_unsigned``), badly signed, or timestamped more than ``SIGNING_FUTURE_S`` ahead of this
computer's clock are counted here and never reach the core. The rules are
:class:`~.signing.LinkSigning`'s; the link owns one and hands it its encoders, decoder and
verified frames.

Input is framed by :class:`~mavservo.mavlink.framing.FrameScanner`: each UDP datagram on its own
(one sender's bytes never swallow another's), a stream (serial, TCP) resynchronising byte by
byte after a bad frame; unknown message ids are dropped like any frame that cannot be verified.
Only verified frames reach the core and the run log's tlog (secret fields zeroed).

A UDP server (``udpin:``/``udp:``) is :class:`UdpServer`, not pymavlink's: the port is bound
without ``SO_REUSEADDR`` (a second process on the same port is refused at start instead of
silently taking half the commands), and output goes only to addresses that sent a verified
frame (never to an address that sent only garbage, unknown ids or unsigned frames: no
reflector), at most ``MAX_UDP_PEERS`` of them. A TCP server (``tcpin:``) is :class:`TcpServer`:
several clients, each framed on its own, answered once verified (pymavlink's serves one).

A frame claiming one of the link's own hosted identities is never a peer's: dropped and counted
(``own_identity``) before it can admit an address or reach the core.

Every frame a server hands on is tagged with its origin (UDP address, TCP client) and whether
that origin holds the pin of the privileged identity it claims (:mod:`.origin`): answers go
back to the origin of their request, and the core refuses a privileged identity's unsigned
frames from anywhere else (issue 40). A UDP server reads what waits in its socket before it
handles any of it, the pinned addresses' datagrams first, so a stranger's backlog never holds
the autopilot's HEARTBEAT (:data:`UDP_DRAIN_PER_PASS`).

A handler that raises is counted per kind (message type and exception) and logged once per
kind with its traceback, then summarised at most every ``HANDLER_ERROR_SUMMARY_S``.

The receive thread waits at most ``POLL_S`` per call so :meth:`stop` is prompt. When the endpoint
fails (serial adapter unplugged, socket error) the link closes it, reports "link lost" through
``on_event``, and reopens it with exponential backoff, reporting "link recovered".
"""

from __future__ import annotations

import contextlib
import errno
import functools
import logging
import select
import socket
import struct
import sys
import threading
import time
from collections import Counter, OrderedDict, deque
from collections.abc import Callable, Hashable, Iterable, Sequence
from typing import Any

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.errors import EndpointBusyError
from mavservo.mavlink.commands import RateLimitedLog
from mavservo.mavlink.connection import open_connection
from mavservo.mavlink.framing import FrameScanner, redact_secrets
from mavservo.mavlink.origin import Requester, describe, tag
from mavservo.mavlink.settings import SigningSettings
from mavservo.mavlink.signing import LinkSigning
from mavservo.threads import BackgroundLoop

log = logging.getLogger(__name__)

POLL_S = 0.1
BACKOFF_START_S = 0.25
BACKOFF_MAX_S = 5.0
#: At most one "cannot reopen" warning per this many seconds of one outage (the first at once).
REOPEN_WARNING_INTERVAL_S = 30.0
UDP_MAX_DATAGRAM = 65535
#: Most addresses a UDP server sends to; each one had to send a verified frame first.
MAX_UDP_PEERS = 16
#: A UDP peer not heard from for this long stops being answered (the autopilot's and the
#: allowed sources' addresses excepted); when the table is full the least recently heard goes.
UDP_PEER_IDLE_S = 30.0
#: Most clients a TCP server (``tcpin:``) serves at once.
MAX_TCP_CLIENTS = 8
#: Of those, slots only the followed autopilot and ``allowed_sources`` may hold: strangers
#: (six HEARTBEATs) filled every slot and the autopilot's reconnect was refused (issue 32).
RESERVED_TCP_SLOTS = 2
#: Clients from one address (other than the autopilot's and allowed sources').
MAX_TCP_PER_ADDRESS = 4
#: Connections waiting in the kernel to be accepted.
TCP_BACKLOG = 64
#: A TCP client that has not sent a verified frame within this many seconds is closed.
TCP_UNVERIFIED_IDLE_S = 5.0
#: A verified TCP client silent this long is closed (a ground station sends HEARTBEAT at 1 Hz).
TCP_VERIFIED_IDLE_S = 10.0
#: A privileged identity (the followed autopilot, an allowed source) pins one UDP address or
#: holds one TCP slot: the one it was first verified from; another address claiming it takes
#: the pin over only once the holder was silent this long (an autopilot rebooted on a new
#: port). Why: on an unsigned link anyone can claim the autopilot's id; each claim pinned one
#: more address (never expired, never evicted, the pin set grew without bound: 1,923 pins from
#: 2,000 spoofed HEARTBEATs) and 16 of them locked every later ground station out; 8 TCP
#: connections claiming it held every slot, the reserved ones included.
PIN_REBIND_S = 3.0
HANDLER_ERROR_SUMMARY_S = 60.0
#: Receive buffer a UDP server asks for. Linux's default (net.core.rmem_default, 208 KiB) held
#: too few datagrams: a 5,000/s command flood lost a median 441 per 10 s in the kernel, unseen.
#: The kernel caps the request at net.core.rmem_max; what it granted is read back and reported.
UDP_RCVBUF_BYTES = 1 << 20
#: Linux's SO_RXQ_OVFL (socket(7)): every datagram carries the socket's count of datagrams the
#: kernel dropped so far; Python's socket module does not name it. None: not on this system.
SO_RXQ_OVFL: int | None = getattr(
    socket, "SO_RXQ_OVFL", 40 if sys.platform.startswith("linux") else None
)
#: At most one warning about kernel drops per this many seconds (every drop is counted).
UDP_DROP_LOG_INTERVAL_S = 10.0
#: Datagrams a UDP server reads from its socket per pass at most before it handles some: it
#: reads what is waiting first, so the pinned addresses' datagrams (the autopilot's, the allowed
#: sources') are handled ahead of a stranger's backlog (issue 40: a 1,000/s flood from 250
#: spoofed ids held the autopilot's HEARTBEAT behind the queue in the one socket: a false
#: failsafe, "autopilot heartbeat lost" for 1 s with the throttle to idle).
UDP_DRAIN_PER_PASS = 512
#: Other addresses' datagrams handled per pass at most, between two reads of the socket.
UDP_OTHERS_PER_PASS = 32
#: Other addresses' datagrams waiting to be handled at most (and their bytes): beyond, the
#: oldest is shed, counted in ``udp_shed`` and warned about like a kernel drop (a command that
#: waited that long would be applied late).
UDP_MAX_DEFERRED = 2048
UDP_MAX_DEFERRED_BYTES = 1 << 20
#: A TCP client's first frames are read before a newcomer may replace it: a client younger than
#: this is never replaced (issue 40: in a reconnect storm the real autopilot's connection was
#: closed right after its first frame, unread in its socket, for a newcomer).
TCP_GRACE_S = 2.0
#: At most one warning per identity per this many seconds about a second address claiming it.
CLAIM_LOG_INTERVAL_S = 10.0


class LinkBusyError(EndpointBusyError, OSError):
    """The endpoint is already used by another process (start-up refuses, with this text); an
    ``OSError`` too, with the ``errno`` of the failed bind, for callers of a socket API."""


class HandlerErrors:
    """Errors raised by the message handler, counted per kind, logged without a flood.

    Hostile input can make a handler raise on every message (97 crafted messages gave 2,419
    traceback lines): the first error of each kind (message type + exception type) is logged
    with its traceback, later ones only counted and summed up in one line at most every
    ``summary_s`` per kind.
    """

    def __init__(
        self,
        summary_s: float = HANDLER_ERROR_SUMMARY_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.summary_s = summary_s
        self._clock = clock
        self.by_kind: Counter[str] = Counter()
        self._unlogged: Counter[str] = Counter()
        self._last_logged: dict[str, float] = {}

    def record(self, message_type: str, exc: BaseException) -> None:
        kind = f"{message_type}/{type(exc).__name__}"
        self.by_kind[kind] += 1
        now = self._clock()
        last = self._last_logged.get(kind)
        if last is None:
            self._last_logged[kind] = now
            log.warning(
                "error handling %s: %s (logged once per kind; repeats counted in "
                "handler_errors and summed up every %.0f s)",
                message_type,
                exc,
                self.summary_s,
                exc_info=exc,
            )
            return
        self._unlogged[kind] += 1
        if now - last >= self.summary_s:
            log.warning(
                "%d more errors handling %s (%s: %s) in the last %.0f s",
                self._unlogged.pop(kind),
                message_type,
                type(exc).__name__,
                exc,
                now - last,
            )
            self._last_logged[kind] = now


class UdpServer:
    """A UDP server endpoint (``udpin:HOST:PORT``) that answers verified peers only.

    Differences from pymavlink's ``mavudp(input=True)``, each a finding of an attack run:
    no ``SO_REUSEADDR`` (with it a second bridge bound the same port and the kernel handed the
    ground station's commands to whichever process it picked); a sender becomes a destination
    only when :meth:`admit` is called for it, i.e. after one of its frames verified (pymavlink
    sends everything to every address a datagram ever came from: a reflector); at most
    ``max_peers`` destinations.

    Datagrams the kernel drops because the receive queue is full (a flood, a stalled reader)
    are counted (:attr:`kernel_drops`, from ``SO_RXQ_OVFL`` where the system has it) and
    warned about at most every ``UDP_DROP_LOG_INTERVAL_S``; the receive buffer is enlarged to
    ``UDP_RCVBUF_BYTES`` (as far as the kernel allows, :attr:`rcvbuf_bytes` is what it gave).
    Both counters and the buffer size reach the link's stats (``udp_*``).
    """

    def __init__(
        self,
        host: str,
        port: int,
        max_peers: int = MAX_UDP_PEERS,
        peers: tuple[tuple[str, int], ...] = (),
        idle_s: float = UDP_PEER_IDLE_S,
    ) -> None:
        self.address = (host, port)
        self.max_peers = max_peers
        self.idle_s = idle_s
        self._peers: tuple[tuple[str, int], ...] = peers[:max_peers]
        #: when each peer was last heard (least recently heard first), and the pinned ones
        #: (the autopilot's and allowed sources' addresses: never expired nor evicted)
        self._heard: OrderedDict[tuple[str, int], float] = OrderedDict(
            (peer, time.monotonic()) for peer in self._peers
        )
        #: privileged identity -> the one address it pins (see :data:`PIN_REBIND_S`)
        self._pins: dict[Hashable, tuple[str, int]] = {}
        self.refused_peers = 0
        #: claims of a privileged identity from a second address while the first is heard
        self.refused_pins = 0
        self.expired_peers = 0
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.bind(self.address)
        except OSError as exc:
            self._sock.close()
            if exc.errno == errno.EADDRINUSE:
                busy = LinkBusyError(
                    f"mavlink: UDP port {host}:{port} is in use by another process (another "
                    "mavservo, a MAVLink router or MAVProxy?); stop it first"
                )
                busy.errno = exc.errno
                raise busy from exc
            raise
        self._sock.setblocking(False)
        self.address = self._sock.getsockname()[:2]  # the port the kernel chose for port 0
        self.rcvbuf_bytes = self._enlarge_receive_buffer(UDP_RCVBUF_BYTES)
        self.counts_kernel_drops = self._enable_drop_count()
        #: datagrams read from the socket, and datagrams the kernel dropped before they could
        #: be read (as far as the last datagram read tells: drops after it show with the next)
        self.datagrams = 0
        self.kernel_drops = 0
        self._kernel_drop_mark = 0
        self._drops_logged_at: float | None = None
        self._drops_logged = 0
        #: datagrams read and not handled yet: from pinned addresses (handled first), from the
        #: others (in arrival order, bounded: the oldest is shed), and how many of each other
        #: address wait (its later datagrams wait behind them: one sender's order is kept)
        self._pinned_queue: deque[tuple[bytes, tuple[str, int]]] = deque()
        self._others: deque[tuple[bytes, tuple[str, int]]] = deque()
        self._others_bytes = 0
        self._waiting: Counter[tuple[str, int]] = Counter()
        self.shed = 0
        self._shed_log = RateLimitedLog(UDP_DROP_LOG_INTERVAL_S)
        self._shed_logged = 0
        #: (identity, its pinned address, the other address claiming it), since last taken
        self._claims: list[tuple[Hashable, tuple[str, int], tuple[str, int]]] = []

    def _enlarge_receive_buffer(self, wanted: int) -> int:
        """Ask for ``wanted`` bytes of receive buffer; returns what the kernel granted (Linux
        doubles the request for its bookkeeping and caps it at net.core.rmem_max)."""
        with contextlib.suppress(OSError):
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, wanted)
        granted = int(self._sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF))
        if granted < wanted:
            log.info(
                "UDP receive buffer of %s:%d is %d KiB, asked for %d KiB (the kernel caps it at "
                "net.core.rmem_max; raise that for more room under a flood)",
                *self.address,
                granted // 1024,
                wanted // 1024,
            )
        return granted

    def _enable_drop_count(self) -> bool:
        """Ask the kernel to tell each datagram's drop count (Linux); False elsewhere."""
        if SO_RXQ_OVFL is None:
            return False
        try:
            self._sock.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
        except OSError:
            return False
        return True

    @classmethod
    def from_url(cls, url: str, peers: tuple[tuple[str, int], ...] = ()) -> UdpServer:
        host, _, port = url.split(":", 1)[1].rpartition(":")
        return cls(host, int(port), peers=peers)

    @property
    def peers(self) -> tuple[tuple[str, int], ...]:
        return self._peers

    def select(self, timeout: float) -> bool:
        if self._pinned_queue or self._others:
            return True
        readable, _, _ = select.select([self._sock], [], [], timeout)
        return bool(readable)

    def drain(self, now: float, limit: int = UDP_DRAIN_PER_PASS) -> bool:
        """Read what waits in the socket (at most ``limit`` datagrams): a pinned address's
        datagrams to the front line, the others' behind (bounded, see :meth:`_defer`).
        True when the socket is empty (everything that came before the call was read)."""
        pinned = set(self._pins.values())
        for _ in range(limit):
            received = self.recv_from()
            if received is None:
                return True
            sender = received[1]
            if sender in pinned and not self._waiting[sender]:
                self._pinned_queue.append(received)
            else:
                self._defer(received, now)
        return False

    def _defer(self, received: tuple[bytes, tuple[str, int]], now: float) -> None:
        self._others.append(received)
        self._others_bytes += len(received[0])
        self._waiting[received[1]] += 1
        shed = self.shed
        while len(self._others) > UDP_MAX_DEFERRED or self._others_bytes > UDP_MAX_DEFERRED_BYTES:
            self._take_other()
            self.shed += 1
        if self.shed != shed:
            self._warn_shed(now)

    def _take_other(self) -> tuple[bytes, tuple[str, int]]:
        data, sender = self._others.popleft()
        self._others_bytes -= len(data)
        self._waiting[sender] -= 1
        if not self._waiting[sender]:
            del self._waiting[sender]
        return data, sender

    def _warn_shed(self, now: float) -> None:
        """One warning per ``UDP_DROP_LOG_INTERVAL_S`` at most, with the datagrams shed since."""
        if self._shed_log.quiet_since_last("shed", now) is None:
            return
        log.warning(
            "MAVLink UDP %s:%d: %d datagrams from unpinned addresses shed (more than %d "
            "waiting: a flood; the autopilot's and allowed sources' addresses are read first; "
            "%d in all, counted in udp_shed)",
            *self.address,
            self.shed - self._shed_logged,
            UDP_MAX_DEFERRED,
            self.shed,
        )
        self._shed_logged = self.shed

    def next_batch(self, others: int = UDP_OTHERS_PER_PASS) -> list[tuple[bytes, tuple[str, int]]]:
        """The datagrams to handle now: every pinned one, then at most ``others`` others."""
        batch = list(self._pinned_queue)
        self._pinned_queue.clear()
        for _ in range(min(others, len(self._others))):
            batch.append(self._take_other())
        return batch

    def pin_of(self, identity: Hashable) -> tuple[str, int] | None:
        """The address ``identity`` is pinned to (None: not pinned)."""
        return self._pins.get(identity)

    def take_claims(self) -> list[tuple[Hashable, tuple[str, int], tuple[str, int]]]:
        """The refused claims since the last call: (identity, pinned address, claimant)."""
        claims, self._claims = self._claims, []
        return claims

    def recv_from(self) -> tuple[bytes, tuple[str, int]] | None:
        try:
            if self.counts_kernel_drops:
                data, ancillary, _, address = self._sock.recvmsg(
                    UDP_MAX_DATAGRAM, socket.CMSG_SPACE(4)
                )
                self._note_kernel_drops(ancillary)
            else:
                data, address = self._sock.recvfrom(UDP_MAX_DATAGRAM)
        except (BlockingIOError, InterruptedError):
            return None
        except ConnectionRefusedError:  # ICMP unreachable from an earlier send: not fatal
            return None
        self.datagrams += 1
        return data, address

    def _note_kernel_drops(self, ancillary: list[tuple[int, int, bytes]]) -> None:
        """Take the socket's drop count from a datagram's ancillary data (absent: none yet).

        The kernel's count is cumulative for the socket and 32 bits wide: the growth since the
        last datagram is added, modulo 2**32."""
        for level, kind, payload in ancillary:
            if level != socket.SOL_SOCKET or kind != SO_RXQ_OVFL or len(payload) < 4:
                continue
            (mark,) = struct.unpack_from("=I", payload)
            grown = (mark - self._kernel_drop_mark) & 0xFFFFFFFF
            self._kernel_drop_mark = mark
            if grown:
                self.kernel_drops += grown
                self._warn_kernel_drops(time.monotonic())

    def _warn_kernel_drops(self, now: float) -> None:
        """One warning per ``UDP_DROP_LOG_INTERVAL_S`` at most, with the drops since the last."""
        last = self._drops_logged_at
        if last is not None and now - last < UDP_DROP_LOG_INTERVAL_S:
            return
        log.warning(
            "MAVLink UDP %s:%d: the kernel dropped %d datagrams (receive queue full: a flood or "
            "a stalled reader; %d in all, counted in udp_kernel_drops; receive buffer %d KiB)",
            *self.address,
            self.kernel_drops - self._drops_logged,
            self.kernel_drops,
            self.rcvbuf_bytes // 1024,
        )
        self._drops_logged_at = now
        self._drops_logged = self.kernel_drops

    def is_peer(self, address: tuple[str, int]) -> bool:
        return address in self._peers

    def admit(
        self, address: tuple[str, int], now: float, pinned_as: Iterable[Hashable] = ()
    ) -> bool:
        """``address`` sent a verified frame: answer it from now on. When the table is full
        the least recently heard peer that is not pinned makes room; False when all are
        pinned. A known peer is only marked heard. ``pinned_as``: the privileged identities
        its frames claimed; each pins one address at most (:data:`PIN_REBIND_S`)."""
        if address in self._heard:
            self._heard[address] = now
            self._heard.move_to_end(address)
            self._pin(address, pinned_as, now)
            return True
        self._expire(now)
        if len(self._heard) >= self.max_peers:
            pinned = set(self._pins.values())
            victim = next((peer for peer in self._heard if peer not in pinned), None)
            if victim is None:
                self.refused_peers += 1
                return False
            del self._heard[victim]
            self.expired_peers += 1
        self._heard[address] = now
        self._peers = tuple(self._heard)  # replaced, never mutated: write() needs no lock
        self._pin(address, pinned_as, now)
        return True

    def _pin(self, address: tuple[str, int], identities: Iterable[Hashable], now: float) -> None:
        """Pin ``address`` for each identity whose pin is free, its own, or held by an
        address silent for :data:`PIN_REBIND_S` (or gone from the table)."""
        for identity in identities:
            holder = self._pins.get(identity)
            heard = self._heard.get(holder) if holder is not None else None
            if holder == address or heard is None or now - heard > PIN_REBIND_S:
                self._pins[identity] = address
            else:
                self.refused_pins += 1
                if holder is not None and len(self._claims) < MAX_UDP_PEERS:
                    self._claims.append((identity, holder, address))

    def _expire(self, now: float) -> None:
        """Forget peers not heard from for ``idle_s`` (pinned ones excepted)."""
        pinned = set(self._pins.values())
        stale = [
            peer
            for peer, heard in self._heard.items()
            if now - heard > self.idle_s and peer not in pinned
        ]
        for peer in stale:
            del self._heard[peer]
            self.expired_peers += 1
        if stale:
            self._peers = tuple(self._heard)

    def write_to(self, buf: bytes, address: tuple[str, int]) -> None:
        """Send to one peer only (an answer to its request)."""
        if address in self._peers:  # the tuple: replaced, never mutated (no lock needed)
            with contextlib.suppress(BlockingIOError, ConnectionRefusedError):
                self._sock.sendto(buf, address)

    def write(self, buf: bytes) -> None:
        for address in self._peers:
            with contextlib.suppress(BlockingIOError, ConnectionRefusedError):
                self._sock.sendto(buf, address)

    def tick(self, now: float) -> None:
        """Expire idle peers (called by the receive loop at every poll)."""
        self._expire(now)

    def close(self) -> None:
        self._sock.close()


class UdpServerTotals:
    """The UDP server figures of a link across reopens (each socket counts from zero).

    Why here and not in the server: a reopen makes a new :class:`UdpServer`; the totals add up
    the servers seen by :meth:`observe` (the last one's figures stay readable after it closed).
    """

    def __init__(self) -> None:
        self._current: UdpServer | None = None
        self._earlier = Counter[str]()

    def observe(self, conn: Any) -> dict[str, int | bool]:
        """The ``udp_*`` stats with ``conn`` (the link's endpoint now, or None) taken in."""
        if isinstance(conn, UdpServer) and conn is not self._current:
            if self._current is not None:
                self._earlier.update(self._figures(self._current))
            self._current = conn
        if self._current is None:
            return {}
        totals = self._earlier + Counter(self._figures(self._current))
        return {
            "udp_datagrams": totals["udp_datagrams"],
            "udp_kernel_drops": totals["udp_kernel_drops"],
            "udp_refused_pins": totals["udp_refused_pins"],
            "udp_shed": totals["udp_shed"],
            "udp_rcvbuf_bytes": self._current.rcvbuf_bytes,
            "udp_kernel_drops_counted": self._current.counts_kernel_drops,
        }

    @staticmethod
    def _figures(server: UdpServer) -> dict[str, int]:
        return {
            "udp_datagrams": server.datagrams,
            "udp_kernel_drops": server.kernel_drops,
            "udp_refused_pins": server.refused_pins,
            "udp_shed": server.shed,
        }


def is_udp_server_url(url: str) -> bool:
    return url.startswith(("udpin:", "udp:"))


def is_tcp_server_url(url: str) -> bool:
    return url.startswith("tcpin:")


class TcpClient:
    """One connection to a :class:`TcpServer`: its own stream framing state (a frame split
    over two writes of one client never continues with another client's bytes)."""

    def __init__(
        self,
        sock: socket.socket,
        scanner: FrameScanner,
        since: float,
        address: tuple[str, int] = ("", 0),
    ) -> None:
        self.sock = sock
        self.scanner = scanner
        self.since = since
        self.address = address
        self.verified = False
        #: sent a verified frame as the followed autopilot or an allowed source: holds a
        #: reserved slot, never evicted for a newcomer
        self.privileged = False
        self.last_heard = since
        #: why a writer gave up on it; the read thread closes it (only it closes sockets, so a
        #: socket is never closed under its select)
        self.dropped: str | None = None
        #: claimed a privileged identity another client holds (evicted last among ordinary)
        self.claims_privilege = False


class TcpServer:
    """A TCP server endpoint (``tcpin:HOST:PORT``) for several clients at once.

    pymavlink's ``mavtcpin`` accepts one client and serves the next only when it closes: an
    idle stranger that connected first shut the ground station out, and the station's
    command, queued in the kernel, was applied seconds late when the stranger left (finding
    G). Here every client is read as its bytes arrive (a command is handled when it comes or
    not at all, never queued behind another client), at most ``max_clients`` at once; output
    goes to clients that sent a verified frame (:meth:`verify`), as on UDP; a client without
    a verified frame for ``idle_s`` is closed, and when the table is full the oldest such
    client past its grace period (``grace_s``: its first frames are read first) makes room for
    a newcomer (strangers cannot hold the port against a station for longer); a
    client that does not read what it is sent (its socket buffer full) is closed rather than
    allowed to block the bridge's writers.
    """

    def __init__(
        self,
        host: str,
        port: int,
        new_scanner: Callable[[], FrameScanner],
        counters: Counter[str],
        max_clients: int = MAX_TCP_CLIENTS,
        idle_s: float = TCP_UNVERIFIED_IDLE_S,
        clock: Callable[[], float] = time.monotonic,
        verified_idle_s: float = TCP_VERIFIED_IDLE_S,
        reserved: int = RESERVED_TCP_SLOTS,
        per_address: int = MAX_TCP_PER_ADDRESS,
        grace_s: float = TCP_GRACE_S,
    ) -> None:
        self.max_clients = max_clients
        self.idle_s = idle_s
        self.verified_idle_s = verified_idle_s
        self.reserved = min(reserved, max_clients - 1)
        self.per_address = per_address
        self._new_scanner = new_scanner
        self._counters = counters
        self._clock = clock
        self._lock = threading.Lock()  # the client table: read thread vs. writers
        self._clients: dict[socket.socket, TcpClient] = {}
        #: privileged identity -> the client holding its reserved slot (one each)
        self._holders: dict[Hashable, TcpClient] = {}
        #: (identity, its holder, another client claiming it), since last taken
        self._claims: list[tuple[Hashable, TcpClient, TcpClient]] = []
        self.grace_s = grace_s
        self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        # on Linux SO_REUSEADDR lets a restarted bridge bind past TIME_WAIT; it never lets
        # a second process listen on the same port
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self._listener.bind((host, port))
            self._listener.listen(TCP_BACKLOG)
        except OSError as exc:
            self._listener.close()
            if exc.errno == errno.EADDRINUSE:
                busy = LinkBusyError(
                    f"mavlink: TCP port {host}:{port} is in use by another process (another "
                    "mavservo, a MAVLink router or MAVProxy?); stop it first"
                )
                busy.errno = exc.errno
                raise busy from exc
            raise
        self._listener.setblocking(False)

    @classmethod
    def from_url(
        cls, url: str, new_scanner: Callable[[], FrameScanner], counters: Counter[str]
    ) -> TcpServer:
        host, _, port = url.split(":", 1)[1].rpartition(":")
        return cls(host, int(port), new_scanner, counters)

    @property
    def clients(self) -> int:
        return len(self._clients)

    def select(self, timeout: float) -> bool:
        self._sweep()
        readable, _, _ = select.select([self._listener, *self._sockets()], [], [], timeout)
        return bool(readable)

    def _sockets(self) -> list[socket.socket]:
        with self._lock:
            return list(self._clients)

    def receive(self, accept: bool = True) -> list[tuple[TcpClient, bytes]]:
        """The bytes of every client that has some (without waiting), then (unless
        ``accept`` is False: the caller calls :meth:`accept` once it verified them) accept
        whoever connects: a client's first frames are read before a newcomer is weighed
        against it (a client that closed or failed is removed)."""
        ready, _, _ = select.select(self._sockets(), [], [], 0)
        received = []
        for sock in ready:
            client = self._clients.get(sock)
            if client is None:
                continue
            try:
                data = sock.recv(4096)
            except (BlockingIOError, InterruptedError):
                continue
            except OSError:
                data = b""
            if not data:
                self._remove(client, client.dropped or "tcp_clients_closed")
                continue
            received.append((client, data))
        if accept:
            self.accept()
        return received

    def verify(self, client: TcpClient, privileged_as: Iterable[Hashable] = ()) -> None:
        """``client`` sent a verified frame: it receives our output from now on
        (``privileged_as``: the autopilot's or allowed sources' identities its frames claimed;
        each holds one reserved slot at most, see :data:`PIN_REBIND_S`)."""
        now = self._clock()
        client.last_heard = now
        for identity in privileged_as:
            holder = self._holders.get(identity)
            if (
                holder is not None
                and holder is not client
                and self._clients.get(holder.sock) is holder
                and now - holder.last_heard <= PIN_REBIND_S
            ):
                self._counters["tcp_privilege_refused"] += 1
                client.claims_privilege = True
                if len(self._claims) < MAX_TCP_CLIENTS:
                    self._claims.append((identity, holder, client))
                continue
            self._holders[identity] = client
            client.privileged = True
            if holder is not None and holder is not client:
                holder.privileged = any(h is holder for h in self._holders.values())
        if not client.verified:
            client.verified = True
            log.info("MAVLink TCP client %s answered from now on", _peer_name(client.sock))

    def holder_of(self, identity: Hashable) -> TcpClient | None:
        """The client holding ``identity``'s reserved slot (None: nobody)."""
        return self._holders.get(identity)

    def take_claims(self) -> list[tuple[Hashable, TcpClient, TcpClient]]:
        """The refused claims since the last call: (identity, holder, claimant)."""
        claims, self._claims = self._claims, []
        return claims

    def write_to(self, buf: bytes, client: TcpClient) -> None:
        """Send to one client only (an answer to its request)."""
        with self._lock:
            if self._clients.get(client.sock) is not client:
                return
        self._send(client, buf)

    def write(self, buf: bytes) -> None:
        with self._lock:
            targets = [c for c in self._clients.values() if c.verified and not c.dropped]
        for client in targets:
            self._send(client, buf)

    @staticmethod
    def _send(client: TcpClient, buf: bytes) -> None:
        try:
            sent = client.sock.send(buf)
        except (BlockingIOError, InterruptedError):
            sent = 0
        except OSError:
            sent = -1
        if sent != len(buf):  # a part of a frame would corrupt its stream: let it go
            client.dropped = "tcp_clients_closed" if sent < 0 else "tcp_clients_not_reading"
            with contextlib.suppress(OSError):
                client.sock.shutdown(socket.SHUT_RDWR)  # wakes the read thread

    def close(self) -> None:
        with self._lock:
            clients, self._clients = list(self._clients.values()), {}
        for client in clients:
            client.sock.close()
        self._listener.close()

    def accept(self) -> None:
        """Accept whoever waits to connect (bounded per call), as room allows."""
        for _ in range(self.max_clients):  # bounded per call
            try:
                sock, address = self._listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            sock.setblocking(False)
            address = tuple(address[:2])
            if not (self._limit_address(address) and self._make_room()):
                self._counters["tcp_clients_refused"] += 1
                sock.close()
                continue
            with self._lock:
                client = TcpClient(sock, self._new_scanner(), self._clock(), address)
                self._clients[sock] = client
            self._counters["tcp_clients_accepted"] += 1

    def _ordinary(self) -> list[TcpClient]:
        """Clients that hold no reserved slot, the first to make room first: those without a
        verified frame (oldest first), then the verified ones least recently heard, those
        claiming a privileged identity another client holds last (the real autopilot may be
        the second to claim it: only signing tells)."""
        ordinary = [c for c in self._clients.values() if not c.privileged]
        return sorted(
            ordinary,
            key=lambda c: (c.verified, c.claims_privilege, c.last_heard if c.verified else c.since),
        )

    def _make_room(self) -> bool:
        """Room for a newcomer: strangers may hold ``max_clients - reserved`` slots, so the
        reserved ones stay free for the autopilot and allowed sources (a newcomer is anybody
        until its first verified frame, so it gets in at an ordinary client's cost, but never
        at the cost of a client in its first :data:`TCP_GRACE_S`, whose first frames may be
        waiting unread); False when every slot is privileged or in its grace period."""
        ordinary = self._ordinary()
        if (
            len(ordinary) < self.max_clients - self.reserved
            and len(self._clients) < self.max_clients
        ):
            return True
        victim = next((c for c in ordinary if self._replaceable(c)), None)
        if victim is None:
            return False
        self._remove(
            victim, "tcp_clients_replaced" if not victim.verified else "tcp_clients_evicted"
        )
        return True

    def _limit_address(self, address: tuple[str, int]) -> bool:
        """At most ``per_address`` ordinary clients from one address: its oldest past its
        grace period makes room; False when none is (the newcomer is refused)."""
        same = [c for c in self._ordinary() if c.address[0] == address[0]]
        if len(same) < self.per_address:
            return True
        victim = next((c for c in same if self._replaceable(c)), None)
        if victim is None:
            return False
        self._remove(victim, "tcp_clients_per_address")
        return True

    def _replaceable(self, client: TcpClient) -> bool:
        """A client a newcomer may replace: one whose first frames were read (verified), or
        one without a verified frame after its grace period (``grace_s``)."""
        return client.verified or self._clock() - client.since >= self.grace_s

    def _sweep(self) -> None:
        """Close the clients a writer gave up on, those idle without a verified frame, and
        verified ones silent for ``verified_idle_s``."""
        now = self._clock()
        with self._lock:
            clients = list(self._clients.values())
        for client in clients:
            if client.dropped:
                self._remove(client, client.dropped)
            elif not client.verified and now - client.since > self.idle_s:
                self._remove(client, "tcp_clients_idle")
            elif client.verified and now - client.last_heard > self.verified_idle_s:
                self._remove(client, "tcp_clients_idle_verified")

    def _remove(self, client: TcpClient, reason: str) -> None:
        with self._lock:
            if self._clients.pop(client.sock, None) is None:
                return
        self._counters[reason] += 1
        with contextlib.suppress(OSError):
            client.sock.close()


def _peer_name(sock: socket.socket) -> str:
    try:
        host, port = sock.getpeername()[:2]
    except OSError:
        return "(gone)"
    return f"{host}:{port}"


class _TransportWriter:
    """File-like object the per-component encoders write into."""

    def __init__(self, link: MavlinkLink) -> None:
        self._link = link

    def write(self, buf: bytes) -> None:
        self._link._write(buf)


class _MonitorWriter:
    """File-like object the monitor encoders write into: the monitor outputs only."""

    def __init__(self, link: MavlinkLink) -> None:
        self._link = link

    def write(self, buf: bytes) -> None:
        self._link._write_monitors(buf)


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
        self._on_message = on_message
        self._on_event = on_event or (lambda text: None)
        self._clock = clock
        self._conn: Any = None
        self._write_lock = threading.Lock()
        self._encoders: dict[int, mavlink2.MAVLink] = {}
        #: Monitor outputs get every message, the autopilot link what its budget lets through:
        #: each has its own encoders, so each sees an unbroken sequence per component (a gap
        #: would read as lost packets in a ground station).
        self._monitor_encoders: dict[int, mavlink2.MAVLink] = {}
        self.counters: Counter[str] = Counter()
        #: the key and the rules on signed frames (None: an unsigned link)
        self._signing = None if signing is None else LinkSigning(signing, self.counters, clock)
        self.handler_errors = HandlerErrors()
        self._udp_totals = UdpServerTotals()
        self._udp_peers: tuple[tuple[str, int], ...] = ()
        self._decoder = self._new_decoder()
        self._scanner = FrameScanner(self._decoder, self.counters)
        self._writer = _TransportWriter(self)
        self._monitor_writer = _MonitorWriter(self)
        self._loop = BackgroundLoop(self._receive_loop, name="mavlink-rx")
        self.failed_reopens = 0  # in the current outage
        self._reopen_log = RateLimitedLog(REOPEN_WARNING_INTERVAL_S)
        #: whether a (system, component) is the followed autopilot or an allowed source: its
        #: address is pinned in the UDP peer table, its TCP client holds a reserved slot
        self.privileged: Callable[[tuple[int, int]], bool] = lambda source: False
        self._claim_log = RateLimitedLog(CLAIM_LOG_INTERVAL_S)
        self._read_until: float | None = None
        self._read_mark: float | None = None
        #: where the frame being written goes (None: every peer); set under the write lock
        self._destination: Any = None

    @property
    def read_until(self) -> float | None:
        """The time up to which everything received was read and handed on (None: no limit:
        not read yet, or the endpoint is closed and nothing can wait in it): the failsafe
        waits for it to pass its deadline (``HeartbeatWatchdog.check``)."""
        return None if self._conn is None else self._read_until

    @property
    def is_open(self) -> bool:
        """Whether the endpoint is open now (not before ``start``, nor while being reopened)."""
        return self._conn is not None

    # ------------------------------------------------------------------ set-up

    def _new_decoder(self) -> mavlink2.MAVLink:
        decoder = mavlink2.MAVLink(None)
        decoder.robust_parsing = True
        if self._signing is not None:
            self._signing.verify_inbound(decoder)
        return decoder

    def add_component(self, component_id: int, system_id: int, link_id: int = 0) -> None:
        """Host a component: its own encoder, sequence counter and signing stream."""
        self._encoders[component_id] = self._encoder(self._writer, system_id, component_id, link_id)
        self._monitor_encoders[component_id] = self._encoder(
            self._monitor_writer, system_id, component_id, (link_id + 1) % 256
        )

    def _encoder(
        self, writer: Any, system_id: int, component_id: int, link_id: int
    ) -> mavlink2.MAVLink:
        encoder = mavlink2.MAVLink(writer, srcSystem=system_id, srcComponent=component_id)
        if self._signing is not None:
            self._signing.sign_outbound(encoder, link_id)
        return encoder

    def open(self) -> None:
        """Open the endpoint; :class:`LinkBusyError` when a UDP server port is taken."""
        if is_udp_server_url(self.url):
            # peers verified before a reopen stay peers: they need not speak first again
            self._conn = UdpServer.from_url(self.url, peers=self._udp_peers)
        elif is_tcp_server_url(self.url):
            self._conn = TcpServer.from_url(
                self.url, lambda: FrameScanner(self._decoder, self.counters), self.counters
            )
        else:
            self._conn = open_connection(self.url, baud=self.baud, autoreconnect=False)
        self._scanner = FrameScanner(self._decoder, self.counters)  # nothing left from before

    def start(self) -> None:
        if self._conn is None:
            self.open()
        for url in self._monitor_urls:  # output-only copies; a failure there is not fatal
            try:
                self._monitors.append(open_connection(url))
            except Exception as exc:  # noqa: BLE001 - any pymavlink open failure
                log.warning("monitor output %s unavailable: %s", url, exc)
        self._loop.start()

    def stop(self) -> None:
        self._loop.stop()
        self._close()

    def _close(self) -> None:
        conn, self._conn = self._conn, None
        if isinstance(conn, UdpServer):
            self._udp_peers = conn.peers
        if conn is not None:
            with contextlib.suppress(OSError):
                conn.close()

    # ------------------------------------------------------------------ output

    def send(
        self,
        component_id: int,
        msg: Any,
        system_id: int,
        *,
        to_link: bool = True,
        to_monitors: bool = True,
        reply_to: Requester | None = None,
    ) -> None:
        """Encode ``msg`` from ``component_id`` (its own sequence number and signature) and send
        it to the monitor outputs (unless ``to_monitors`` is False: a message that waited for
        the link budget, which the monitors had when it was made) and, unless ``to_link`` is
        False, on the link: to every peer,
        or with ``reply_to`` (an answer) only to the address or connection its request came
        from on a UDP or TCP server (never to the other peers: issue 32, finding 3; never to
        wherever the identity was heard last: a stranger claiming it from elsewhere took the
        ground station's answers, issue 40)."""
        try:
            with self._write_lock:
                if self._monitors and to_monitors:
                    monitor = self._monitor_encoders[component_id]
                    monitor.srcSystem = system_id
                    monitor.send(msg)
                if not to_link:
                    return
                self._destination = None
                if reply_to is not None and isinstance(self._conn, UdpServer | TcpServer):
                    self._destination = reply_to.origin
                    if self._destination is None:
                        self.counters["answers_unroutable"] += 1
                        return
                encoder = self._encoders[component_id]
                encoder.srcSystem = system_id
                try:
                    encoder.send(msg)
                finally:
                    self._destination = None
        except (struct.error, ValueError, TypeError, OverflowError):
            # a field the message cannot carry (NaN in an integer): drop this message only
            self.counters["encode_errors"] += 1
            if self.counters["encode_errors"] == 1:
                log.exception(
                    "cannot encode %s (dropped; counted in encode_errors)", msg.get_type()
                )
            return
        self.counters["sent"] += 1

    def _write_monitors(self, buf: bytes) -> None:
        for monitor in self._monitors:
            with contextlib.suppress(OSError):
                monitor.write(buf)

    def _write(self, buf: bytes) -> None:
        conn = self._conn
        if conn is None:
            self.counters["send_dropped_link_down"] += 1
            return
        if self.tap is not None:
            self.tap("out", redact_secrets(bytes(buf)), self._clock())
        try:
            destination = self._destination
            if destination is None:
                conn.write(buf)
            else:
                self._write_to(conn, buf, destination)
        except OSError as exc:
            self.counters["send_errors"] += 1
            log.debug("mavlink write failed: %s", exc)

    @staticmethod
    def _write_to(conn: Any, buf: bytes, destination: Any) -> None:
        """An answer to one peer: a UDP address or a TCP client, as its server holds it."""
        udp = isinstance(conn, UdpServer) and isinstance(destination, tuple)
        tcp = isinstance(conn, TcpServer) and isinstance(destination, TcpClient)
        if udp or tcp:
            conn.write_to(buf, destination)

    # ------------------------------------------------------------------ input

    def _receive_loop(self) -> None:
        backoff = BACKOFF_START_S
        while not self._loop.stopping:
            conn = self._conn
            if conn is None:
                if self._loop.wait(backoff):
                    return
                backoff = min(backoff * 2, BACKOFF_MAX_S)
                try:
                    self.open()
                except Exception as exc:  # noqa: BLE001 - any failure to reopen: keep trying
                    self._reopen_failed(exc)
                    continue
                self.failed_reopens = 0  # the next outage warns at its first failure again
                self._reopen_log = RateLimitedLog(REOPEN_WARNING_INTERVAL_S)
                backoff = BACKOFF_START_S
                self.counters["reconnects"] += 1
                self._on_event("MAVLink link recovered")
                continue
            try:
                messages = self._receive(conn)
            except Exception as exc:  # serial unplug, socket error: reopen with backoff
                if self._loop.stopping:
                    return
                log.warning("mavlink link lost: %s", exc)
                self.counters["link_lost"] += 1
                self._close()
                self._on_event("MAVLink link lost")
                continue
            self._feed(messages)
            if self._read_mark is not None:  # handed on: the reader is caught up to there
                self._read_until, self._read_mark = self._read_mark, None

    def _reopen_failed(self, exc: BaseException) -> None:
        """A reopen that keeps failing is a warning naming the endpoint and the error: at the
        first failure, then at most once per :data:`REOPEN_WARNING_INTERVAL_S` with the count,
        so a telemetry radio that came back under another device name is noticed."""
        self.failed_reopens += 1
        if self._reopen_log.quiet_since_last("reopen", self._clock()) is None:
            log.debug("mavlink: reopen of %s failed: %s", self.url, exc)
            return
        log.warning(
            "mavlink: cannot reopen %s (%d failed attempts since it was lost): %s; still trying",
            self.url,
            self.failed_reopens,
            exc,
        )

    def _receive(self, conn: Any) -> list[Any]:
        """The verified messages of one datagram, or those completed by the next bytes of a
        stream; empty when nothing came within ``POLL_S``. Marks how far the reader is
        (:attr:`read_until`, once the messages are handed on)."""
        mark = self._clock()
        if not conn.select(POLL_S):
            self._read_mark = mark  # nothing was waiting
            return []
        if not isinstance(conn, UdpServer):
            self._read_mark = mark  # a stream, a client's socket: read as it comes
        if isinstance(conn, UdpServer):
            return self._receive_udp_server(conn)
        if isinstance(conn, TcpServer):
            return self._receive_tcp(conn)
        if isinstance(conn, mavutil.mavudp):
            return self._receive_udp_client(conn)
        data = conn.recv(4096)
        return self._not_our_own(self._scanner.stream(bytes(data))) if data else []

    def _receive_udp_server(self, conn: UdpServer) -> list[Any]:
        """The verified messages of the datagrams to handle now: what waits in the socket is
        read first, the pinned addresses' datagrams handled ahead of the others' (see
        :data:`UDP_DRAIN_PER_PASS`), each message tagged with its sender's address."""
        now = self._clock()
        conn.tick(now)
        if conn.drain(now):  # the socket emptied: what came before ``now`` is read
            self._read_mark = now
        messages: list[Any] = []
        for datagram, sender in conn.next_batch():
            verified = self._not_our_own(self._scanner.datagram(datagram))
            verified = self._bound_to_origin(verified, sender)
            self._answer_or_ignore(conn, sender, verified)  # before the answers go out
            self._tag_origin(verified, sender, conn.pin_of)
            messages.extend(verified)
        self._report_claims(conn.take_claims())
        return messages

    def _tag_origin(
        self, messages: list[Any], origin: Hashable, holder_of: Callable[[Hashable], Any]
    ) -> None:
        """Tag each message with ``origin`` and whether it holds the pin of the privileged
        identity the message claims (:mod:`.origin`)."""
        for msg in messages:
            identity = (msg.get_srcSystem(), msg.get_srcComponent())
            holder = holder_of(identity) if self.privileged(identity) else None
            tag(msg, origin, holder is None or holder == origin)

    def _report_claims(self, claims: Iterable[tuple[Hashable, Hashable, Hashable]]) -> None:
        for identity, holder, claimant in claims:
            self._claimed_elsewhere(identity, describe(holder), describe(claimant))

    def _claimed_elsewhere(self, identity: Hashable, holder: str, claimant: str) -> None:
        """A privileged identity heard from a second address or connection while its pinned
        one is heard: counted, and said at most every :data:`CLAIM_LOG_INTERVAL_S` per
        identity with both places (on an unsigned link one of them is lying; only signing
        tells which)."""
        self.counters["identity_claimed_elsewhere"] += 1
        name = "/".join(map(str, identity)) if isinstance(identity, tuple) else str(identity)
        quiet = self._claim_log.quiet_since_last(name, self._clock())
        if quiet is None:
            return
        log.warning(
            "MAVLink %s is pinned to %s, and %s claims it too: its writes and heartbeats "
            "from there are refused (%d more claims since the last line; on an unsigned link "
            "ids are claims: use mavlink.signing)",
            name,
            holder,
            claimant,
            quiet,
        )

    def _not_our_own(self, messages: list[Any]) -> list[Any]:
        """``messages`` without those claiming a hosted component's identity (our system id,
        a component added with :meth:`add_component`), counted in ``own_identity``.

        Why: no peer may speak as us. A stranger without the key replayed one of the bridge's
        own signed HEARTBEATs (seen by anyone on the path): it verified (same key, a stream
        never seen as input), so the stranger became a UDP destination of the whole output
        (378 datagrams in 3 s, finding H); the core dropped it only afterwards, as an echo. A
        router's echo of our own traffic is dropped here the same way."""
        own = {(encoder.srcSystem, component) for component, encoder in self._encoders.items()}
        kept = [m for m in messages if (m.get_srcSystem(), m.get_srcComponent()) not in own]
        if len(kept) != len(messages):
            self.counters["own_identity"] += len(messages) - len(kept)
        return kept

    def _receive_tcp(self, conn: TcpServer) -> list[Any]:
        """The verified messages the ready TCP clients completed, each client framed on its
        own; a client is answered from its first verified frame (before the answers go out)."""
        messages: list[Any] = []
        for client, data in conn.receive(accept=False):
            verified = self._not_our_own(client.scanner.stream(data))
            verified = self._bound_to_origin(verified, client.address)
            if verified:
                conn.verify(client, self._privileged_identities(verified))
            self._tag_origin(verified, client, conn.holder_of)
            messages.extend(verified)
        conn.accept()  # after verifying: a client's first frames count before a newcomer's
        self._report_claims(conn.take_claims())
        return messages

    def _receive_udp_client(self, conn: Any) -> list[Any]:
        """``udpout``/``udpbcast``: in broadcast mode pymavlink sends, from the first write on,
        to the address of the last datagram received, whoever sent it: a stranger's datagram
        must not choose it. Under the write lock, so no write sees the stranger's address."""
        with self._write_lock:
            before = getattr(conn, "last_address", None)
            try:  # pymavlink's mavudp.recv without dropping the sender's address
                data, sender = conn.port.recvfrom(UDP_MAX_DATAGRAM)
            except OSError as exc:
                if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK, errno.ECONNREFUSED):
                    return []
                raise
            broadcast = getattr(conn, "broadcast", False)
            if broadcast:
                conn.last_address = sender
            messages = self._not_our_own(self._scanner.datagram(bytes(data)) if data else [])
            if data and not messages and broadcast:
                conn.last_address = before
                self.counters["strangers_ignored"] += 1
        if messages and not broadcast:
            self._tag_stranger(messages, sender, conn)
        return messages

    def _tag_stranger(self, messages: list[Any], sender: Hashable, conn: Any) -> None:
        """``udpout``: frames from another address than the one we send to are tagged with it,
        the peer we send to holding every privileged identity. Why (issue 40, review): the
        socket takes datagrams from anyone who finds its port, and untagged they all counted
        as from the single peer: a stranger's HEARTBEAT claiming the autopilot kept the
        bridge out of failsafe, its SERVO_OUTPUT_RAW was mirrored."""
        peer = self._udpout_peer(conn.destination_addr)
        if sender != peer:
            self._tag_origin(messages, sender, lambda identity: peer)

    @staticmethod
    @functools.lru_cache(maxsize=4)
    def _udpout_peer(destination: tuple[str, int]) -> Hashable:
        """The address datagrams from the ``udpout`` peer come from: its host resolved once
        (a name is looked up the first time, never per datagram on the receive path)."""
        host, port = destination
        try:
            return (socket.gethostbyname(host), int(port))
        except OSError:
            return (host, int(port))

    def _answer_or_ignore(
        self, conn: UdpServer, sender: tuple[str, int], messages: list[Any]
    ) -> None:
        """A sender becomes a destination of our output only once one of its frames verified:
        garbage, unknown ids, unsigned or forged frames from a stranger (or from 200 spoofed
        addresses) draw nothing back. The autopilot's and allowed sources' addresses are
        pinned (never expired nor evicted); others expire when not heard from."""
        if not messages:
            if not conn.is_peer(sender):
                self.counters["strangers_ignored"] += 1
            return
        known = conn.is_peer(sender)
        if conn.admit(sender, self._clock(), self._privileged_identities(messages)):
            if not known:
                log.info("MAVLink peer %s:%d answered from now on", *sender)
            return
        self.counters["peers_refused"] += 1
        if self.counters["peers_refused"] == 1:
            log.warning(
                "MAVLink peer %s:%d not answered: already %d pinned peers (repeats counted in "
                "peers_refused)",
                *sender,
                conn.max_peers,
            )

    def _privileged_identities(self, messages: list[Any]) -> set[tuple[int, int]]:
        """The autopilot's or allowed sources' identities ``messages`` claim."""
        sources = {(m.get_srcSystem(), m.get_srcComponent()) for m in messages}
        return {source for source in sources if self.privileged(source)}

    def _bound_to_origin(self, messages: list[Any], origin: Hashable) -> list[Any]:
        """Signed frames only from where their stream was first verified (:mod:`.signing`)."""
        if self._signing is None:
            return messages
        return self._signing.bound_to_origin(messages, origin)

    def _feed(self, messages: list[Any]) -> int:
        """Hand verified ``messages`` to the handler; returns how many there were."""
        now = self._clock()
        for msg in messages:
            self.counters["received"] += 1
            if self.tap is not None:
                self.tap("in", redact_secrets(bytes(msg.get_msgbuf())), now)
            try:
                self._on_message(msg, now)
            except Exception as exc:  # a handler bug must not kill the link
                self.counters["handler_errors"] += 1
                self.handler_errors.record(msg.get_type(), exc)
        return len(messages)

    def stats(self) -> dict[str, Any]:
        # "signing_rejected" counts every frame refused by signing (unsigned or badly signed);
        # pymavlink's own reject_count stays 0 for unsigned frames, so it is not reported.
        stats: dict[str, Any] = {
            **dict(self.counters),
            "bad_signatures": self._decoder.signing.badsig_count,
        }
        if self.handler_errors.by_kind:
            stats["handler_error_kinds"] = dict(self.handler_errors.by_kind)
        stats.update(self._udp_totals.observe(self._conn))
        return stats
