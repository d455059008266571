"""Datagrams the kernel drops on a full UDP receive queue are counted and reported, over real
sockets on 127.0.0.1.

Why: under a 5,000/s command flood the kernel dropped a median 441 datagrams per 10 s run and
the bridge neither saw nor counted them. The UDP server now asks for a 1 MiB receive buffer and
reads Linux's SO_RXQ_OVFL count with each datagram: ``udp_kernel_drops`` in the link stats, one
warning line. Everything sent is accounted for: read by the link or dropped by the kernel.

How the flood outruns the reader deterministically: the reader is stopped while 50,000
datagrams go out (the server is not read at all; in the bridge its receive thread is held in the
link's public ``tap`` hook), so the queue fills and the rest is dropped whatever the machine's
speed. Drops after the last datagram read show with the next one, so a marker follows.
"""

from __future__ import annotations

import logging
import socket
import sys
import threading
from collections.abc import Iterator
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.mavlink.link import UdpServer, UdpServerTotals
from tests.redteam.test_bridge_security import Rig
from tests.support.waiting import wait_until

pytestmark = pytest.mark.skipif(
    not sys.platform.startswith("linux"), reason="SO_RXQ_OVFL is Linux's"
)

BURST = 50_000
MARKERS = 50
HOLD_S = 20.0  # upper bound of the stop-the-world; released as soon as the burst is out


def heartbeat_frame() -> bytes:
    encoder = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    return bytes(encoder.heartbeat_encode(6, 8, 0, 0, 4).pack(encoder))


def burst(sock: socket.socket, address: tuple[str, int], payload: bytes, count: int) -> None:
    for _ in range(count):
        sock.sendto(payload, address)


def test_udp_server_counts_every_datagram_the_kernel_dropped(
    caplog: pytest.LogCaptureFixture,
) -> None:
    server = UdpServer("127.0.0.1", 0)
    address = server.address
    caplog.set_level(logging.WARNING, logger="mavservo.mavlink.link")
    try:
        assert server.counts_kernel_drops
        assert server.rcvbuf_bytes >= 256 * 1024  # more than the stock default, whatever cap
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
            burst(sender, address, b"flood", BURST)  # nobody reads meanwhile
            read = 0
            for _ in range(BURST):  # bounded: at most what was sent
                if not server.select(0.2) or server.recv_from() is None:
                    break
                read += 1
            sender.sendto(b"marker", address)
            assert server.select(2.0) and server.recv_from() is not None
    finally:
        server.close()
    assert server.kernel_drops > 0
    assert server.datagrams == read + 1
    assert server.datagrams + server.kernel_drops == BURST + 1
    warnings = [r for r in caplog.records if "the kernel dropped" in r.getMessage()]
    assert len(warnings) == 1
    assert f"{server.kernel_drops} in all" in warnings[0].getMessage()


@pytest.fixture
def rig() -> Iterator[Rig]:
    rig = Rig(signing=False)
    yield rig
    rig.close()


def link_stats(rig: Rig) -> dict[str, Any]:
    return dict(rig.stats()["link"])


def accounted(rig: Rig) -> int:
    """Datagrams the link read plus those the kernel dropped, as far as the link knows."""
    stats = link_stats(rig)
    return int(stats.get("udp_datagrams", 0) + stats.get("udp_kernel_drops", 0))


def test_bridge_reports_kernel_drops_of_a_flood_its_reader_could_not_take(rig: Rig) -> None:
    assert rig.bridge.mavlink is not None
    link = rig.bridge.mavlink.link
    address = ("127.0.0.1", rig.port)
    frame = heartbeat_frame()
    held, release = threading.Event(), threading.Event()

    def hold_the_reader(direction: str, raw: bytes, t: float) -> None:
        if direction == "in" and not release.is_set():
            held.set()
            release.wait(HOLD_S)

    assert link.tap is None  # no run log in this rig: the hook is free
    link.tap = hold_the_reader
    sent = 0
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
            sender.sendto(frame, address)
            sent += 1
            assert held.wait(5.0)  # the receive thread now sits in the hook
            burst(sender, address, frame, BURST)
            sent += BURST
            release.set()
            # markers until one is read after every drop: it brings the drop count along (a
            # marker the still-full queue drops is reported by the next one)
            for _ in range(MARKERS):
                sender.sendto(frame, address)
                sent += 1
                if wait_until(lambda n=sent: accounted(rig) == n, 1.0):
                    break
    finally:
        release.set()
        link.tap = None
    stats = link_stats(rig)
    assert accounted(rig) == sent
    assert stats["udp_kernel_drops"] > 0
    assert stats["udp_kernel_drops"] == sent - stats["udp_datagrams"]
    assert stats["udp_kernel_drops_counted"] is True
    assert stats["received"] == stats["udp_datagrams"]  # each one read was a verified frame


def test_link_totals_carry_over_a_reopen() -> None:
    """A reopen makes a new server counting from zero; the link's totals keep the earlier ones."""
    totals = UdpServerTotals()
    first, second = UdpServer("127.0.0.1", 0), UdpServer("127.0.0.1", 0)
    try:
        first.datagrams, first.kernel_drops = 10, 3
        assert totals.observe(first)["udp_kernel_drops"] == 3
        first.close()
        second.datagrams, second.kernel_drops = 4, 2
        stats = totals.observe(second)
        assert (stats["udp_datagrams"], stats["udp_kernel_drops"]) == (14, 5)
        assert totals.observe(None)["udp_datagrams"] == 14  # link down: the last figures stay
    finally:
        first.close()
        second.close()
