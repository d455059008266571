"""Red-team finding G (``attack/a12_tcp.py``): the ``tcpin:`` server, over real TCP on 127.0.0.1.

pymavlink's ``mavtcpin`` served one client at a time: an idle stranger that connected first
shut the ground station out (no ACK), and the station's command was applied seconds late when
the stranger left. The link's own :class:`~mavservo.mavlink.link.TcpServer` reads every client
as its bytes arrive, each with its own framing, answers clients that sent a verified frame,
and closes clients that stay without one.
"""

from __future__ import annotations

import os
import socket
import time
from collections import Counter
from collections.abc import Iterator
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.app.bridge import Bridge
from mavservo.config.loader import load_config_text
from mavservo.mavlink.framing import FrameScanner
from mavservo.mavlink.link import MAX_TCP_CLIENTS, TCP_GRACE_S, TcpServer
from tests.redteam.test_retry_broadcast_reflection import sim_config_text
from tests.support.waiting import wait_until

os.environ.setdefault("MAVLINK20", "1")

DO_SET_SERVO = 183
ACCEPTED = 0
QUIET_S = 1.0
"""How long after an expected ACK a test keeps listening for a second one."""


def free_tcp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def connect(port: int) -> socket.socket:
    for _ in range(50):
        try:
            return socket.create_connection(("127.0.0.1", port), timeout=1.0)
        except OSError:
            time.sleep(0.1)
    raise AssertionError(f"nothing listens on TCP port {port}")


class Station:
    """A ground station on a raw TCP socket: encodes frames, decodes what comes back."""

    def __init__(self, port: int, source: tuple[int, int] = (255, 190)) -> None:
        self.sock = connect(port)
        self.encoder = mavlink2.MAVLink(None, srcSystem=source[0], srcComponent=source[1])
        self.decoder = mavlink2.MAVLink(None)
        self.decoder.robust_parsing = True

    def send(self, msg: Any) -> None:
        self.sock.sendall(msg.pack(self.encoder))

    def heartbeat(self) -> None:
        self.send(self.encoder.heartbeat_encode(6, 8, 0, 0, 4))

    def set_servo(self, channel: int, pwm: float) -> None:
        self.send(
            self.encoder.command_long_encode(1, 140, DO_SET_SERVO, 0, channel, pwm, 0, 0, 0, 0, 0)
        )

    def messages(
        self, seconds: float, kind: str | None = None, quiet_s: float | None = None
    ) -> list[Any]:
        """What arrives within ``seconds`` (bounded). ``quiet_s``: stop earlier, once nothing
        of ``kind`` came for ``quiet_s`` after the last one (a test waiting for an answer it
        expects need not sit its generous ``seconds`` out, and still sees a second answer
        following within ``quiet_s``); with none of ``kind`` it waits all of ``seconds``."""
        self.sock.settimeout(0.05)
        out: list[Any] = []
        deadline = time.monotonic() + seconds
        for _ in range(10_000):
            if time.monotonic() >= deadline:
                break
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                break
            if not data:
                break
            got = self.decoder.parse_buffer(data) or []
            out.extend(got)
            if quiet_s is not None and any(kind is None or m.get_type() == kind for m in got):
                deadline = time.monotonic() + quiet_s  # may pass ``seconds``: stricter
        return [m for m in out if kind is None or m.get_type() == kind]

    def close(self) -> None:
        self.sock.close()


class TcpRig:
    def __init__(self) -> None:
        self.port = free_tcp_port()
        text = sim_config_text(0, signing=False).replace(
            "udpin:127.0.0.1:0", f"tcpin:127.0.0.1:{self.port}"
        )
        self.bridge = Bridge(load_config_text(text), log_dir=False)
        self.bridge.start()
        self.sockets: list[Any] = []

    def station(self) -> Station:
        station = Station(self.port)
        self.sockets.append(station)
        return station

    def idle(self) -> socket.socket:
        sock = connect(self.port)
        self.sockets.append(sock)
        return sock

    def stats(self) -> dict[str, Any]:
        assert self.bridge.mavlink is not None
        return self.bridge.mavlink.stats()

    def close(self) -> None:
        for sock in self.sockets:
            sock.close()
        self.bridge.stop()


@pytest.fixture
def tcp_rig() -> Iterator[TcpRig]:
    rig = TcpRig()
    yield rig
    rig.close()


def acks(messages: list[Any]) -> list[int]:
    return [m.result for m in messages if m.get_type() == "COMMAND_ACK"]


def test_an_idle_stranger_does_not_shut_the_station_out_nor_delay_its_command(
    tcp_rig: TcpRig,
) -> None:
    """The finding: a stranger connects first and sends nothing; the station's command is
    ACKed while the stranger is still connected, and nothing more is applied when the
    stranger leaves (before: no ACK, then the command applied late)."""
    stranger = tcp_rig.idle()
    assert wait_until(lambda: tcp_rig.stats()["link"].get("tcp_clients_accepted", 0) == 1)
    station = tcp_rig.station()
    station.heartbeat()
    station.set_servo(10, 1200)
    assert acks(station.messages(3.0, "COMMAND_ACK", QUIET_S)) == [ACCEPTED]
    stranger.close()
    assert acks(station.messages(1.0, "COMMAND_ACK")) == []
    assert tcp_rig.stats()["commands"]["result_accepted"] == 1


def test_eight_idle_strangers_cannot_hold_the_port(tcp_rig: TcpRig) -> None:
    """With every slot taken by clients that never sent a verified frame, a newcomer takes
    the oldest one's place once that one's grace period is over (issue 40: never before, its
    first frames may be waiting unread): the station is served."""
    for _ in range(MAX_TCP_CLIENTS):
        tcp_rig.idle()

    def weighed() -> int:
        link = tcp_rig.stats()["link"]
        return int(link.get("tcp_clients_accepted", 0) + link.get("tcp_clients_refused", 0))

    assert wait_until(lambda: weighed() == MAX_TCP_CLIENTS)
    time.sleep(TCP_GRACE_S + 0.2)  # the idle ones' grace is over
    station = tcp_rig.station()
    station.heartbeat()
    station.set_servo(10, 1300)
    assert acks(station.messages(3.0, "COMMAND_ACK", QUIET_S)) == [ACCEPTED]
    link = tcp_rig.stats()["link"]
    # room made by the oldest idle ones: for the slots (two are reserved for the autopilot and
    # allowed sources) and for the limit per address (all of them are 127.0.0.1)
    assert link.get("tcp_clients_replaced", 0) + link.get("tcp_clients_per_address", 0) >= 1


def test_output_goes_only_to_clients_that_sent_a_verified_frame(tcp_rig: TcpRig) -> None:
    stranger = Station(tcp_rig.port)
    tcp_rig.sockets.append(stranger)
    stranger.sock.sendall(b"\xfd\x03\x00\x00\x00\x42\x42\xde\xbc\x0a\x01\x02\x03\x00\x00")
    station = tcp_rig.station()
    station.heartbeat()
    assert [m for m in station.messages(1.5, "HEARTBEAT") if m.get_srcComponent() == 140]
    assert stranger.messages(0.3) == []


def test_a_frame_is_never_completed_by_another_clients_bytes(tcp_rig: TcpRig) -> None:
    """Each client has its own framing: half a command from one client and the other half
    from another are not a command; each client's own whole command is."""
    first, second = tcp_rig.station(), tcp_rig.station()
    first.heartbeat()
    second.heartbeat()
    frame = first.encoder.command_long_encode(1, 140, DO_SET_SERVO, 0, 10, 1400, 0, 0, 0, 0, 0)
    raw = frame.pack(first.encoder)
    first.sock.sendall(raw[:12])
    second.sock.sendall(raw[12:])
    assert acks(first.messages(1.0, "COMMAND_ACK") + second.messages(0.2, "COMMAND_ACK")) == []
    second.set_servo(10, 1500)
    assert acks(second.messages(2.0, "COMMAND_ACK", QUIET_S)) == [ACCEPTED]


def test_a_client_without_a_verified_frame_is_closed_after_the_idle_time() -> None:
    """The server on its own (no bridge), with a short idle time."""
    counters: Counter[str] = Counter()
    decoder = mavlink2.MAVLink(None)
    port = free_tcp_port()
    server = TcpServer(
        "127.0.0.1", port, lambda: FrameScanner(decoder, counters), counters, idle_s=0.2
    )
    client = connect(port)
    try:
        for _ in range(100):  # bounded: 100 polls of at most 0.05 s
            if server.select(0.05):
                server.receive()
            if counters["tcp_clients_idle"]:
                break
        assert counters["tcp_clients_accepted"] == 1
        assert counters["tcp_clients_idle"] == 1
        assert server.clients == 0
        client.settimeout(1.0)
        assert client.recv(10) == b""  # closed by the server
    finally:
        client.close()
        server.close()
