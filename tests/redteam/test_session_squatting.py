"""Issue 32, finding 5: sessions cannot be squatted. Real TCP and UDP sockets on 127.0.0.1.

On c3ae82c: strangers that sent one HEARTBEAT each held every TCP slot and the autopilot's
reconnect was refused; verified clients never timed out; the UDP peer table never expired, so
16 stray addresses locked every later ground station out; a captured signed frame replayed
first from a new address made that address a destination for good.
"""

from __future__ import annotations

import socket
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.app.bridge import Bridge
from mavservo.config.loader import load_config_text
from mavservo.mavlink.framing import FrameScanner
from mavservo.mavlink.link import MAX_TCP_CLIENTS, MAX_UDP_PEERS, TcpServer
from mavservo.mavlink.signing import signing_timestamp
from tests.redteam.test_bridge_security import KEY, Rig
from tests.redteam.test_tcp_server import Station, TcpRig, connect, free_tcp_port
from tests.support.waiting import free_udp_port, wait_until

DO_SET_SERVO = 183


def test_strangers_holding_every_tcp_slot_cannot_keep_the_autopilot_out() -> None:
    rig = TcpRig()
    try:
        for n in range(MAX_TCP_CLIENTS):  # each one verified (an unsigned link) in turn
            stranger = Station(rig.port, (50 + n, 190))
            rig.sockets.append(stranger)
            stranger.heartbeat()
            assert wait_until(lambda n=n: rig.stats()["link"].get("received", 0) > n)
        assert rig.stats()["link"].get("tcp_clients_accepted", 0) == MAX_TCP_CLIENTS
        time.sleep(0.3)
        autopilot = Station(rig.port, (1, 1))
        rig.sockets.append(autopilot)
        autopilot.send(autopilot.encoder.heartbeat_encode(1, 3, 81, 0, 4))
        served = autopilot.messages(2.5, "HEARTBEAT")
        assert [m for m in served if m.get_srcComponent() == 140], rig.stats()["link"]
    finally:
        rig.close()


def test_a_verified_tcp_client_that_falls_silent_is_closed() -> None:
    counters: Counter[str] = Counter()
    decoder = mavlink2.MAVLink(None)
    port = free_tcp_port()
    server = TcpServer(
        "127.0.0.1", port, lambda: FrameScanner(decoder, counters), counters, verified_idle_s=0.3
    )
    client = connect(port)
    encoder = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    try:
        client.sendall(encoder.heartbeat_encode(6, 8, 0, 0, 4).pack(encoder))
        for _ in range(100):  # bounded: 100 polls of at most 0.05 s
            if server.select(0.05):
                for tcp_client, data in server.receive():
                    if tcp_client.scanner.stream(data):
                        server.verify(tcp_client)
            if counters["tcp_clients_idle_verified"]:
                break
        assert counters["tcp_clients_idle_verified"] == 1
        assert server.clients == 0
    finally:
        client.close()
        server.close()


def _udp_bridge(extra: str = "") -> tuple[Bridge, int]:
    port = free_udp_port()
    text = f"""
mavlink:
  url: udpin:127.0.0.1:{port}
  heartbeat_timeout_s: 30
{extra}servos:
  - {{name: left, profile: rmd-x, can_id: 1, limits_deg: [-30, 30]}}
channels:
  - {{servo: left, source: servo_output, channel: 1}}
"""
    return Bridge(load_config_text(text), log_dir=False).start(), port


def _heartbeat(source: tuple[int, int]) -> bytes:
    encoder = mavlink2.MAVLink(None, srcSystem=source[0], srcComponent=source[1])
    return encoder.heartbeat_encode(6, 8, 0, 0, 4).pack(encoder)


def _drain(
    sock: socket.socket, seconds: float, until: Callable[[Any], bool] | None = None
) -> list[Any]:
    """The MAVLink messages ``sock`` receives within ``seconds``; with ``until``, no longer than
    until one of them satisfies it (a test waiting for an answer need not sit the time out)."""
    decoder = mavlink2.MAVLink(None)
    decoder.robust_parsing = True
    sock.settimeout(0.05)
    out: list[Any] = []
    deadline = time.monotonic() + seconds
    for _ in range(10_000):
        if time.monotonic() >= deadline:
            break
        try:
            data = sock.recv(65536)
        except TimeoutError:
            continue
        out.extend(decoder.parse_buffer(data) or [])
        if until is not None and any(until(m) for m in out):
            break
    return out


def _is_servo_ack(msg: Any) -> bool:
    return bool(msg.get_type() == "COMMAND_ACK" and msg.command == DO_SET_SERVO)


def test_a_full_udp_peer_table_makes_room_for_a_new_ground_station() -> None:
    """17 ground-station restarts (a new port each) on an unsigned link: the newest is served
    (the least recently heard address makes room), its command ACKed."""
    bridge, port = _udp_bridge()
    socks = []
    try:
        for n in range(MAX_UDP_PEERS + 1):
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.bind(("127.0.0.1", 0))
            socks.append(sock)
            sock.sendto(_heartbeat((255, 190)), ("127.0.0.1", port))
            assert wait_until(
                lambda n=n: bridge.mavlink.stats()["link"].get("received", 0) > n  # type: ignore[union-attr]
            )
        newest = socks[-1]
        encoder = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
        command = encoder.command_long_encode(1, 140, DO_SET_SERVO, 0, 1, 1600, 0, 0, 0, 0, 0)
        newest.sendto(command.pack(encoder), ("127.0.0.1", port))
        got = _drain(newest, 2.0, until=_is_servo_ack)
        assert [m for m in got if _is_servo_ack(m)]
        assert bridge.mavlink.stats()["link"].get("peers_refused", 0) == 0
    finally:
        for sock in socks:
            sock.close()
        bridge.stop()


def test_a_replayed_signed_frame_from_a_new_address_admits_nobody() -> None:
    rig = Rig(signing=True)
    genuine = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    replayer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        genuine.bind(("127.0.0.1", 0))
        replayer.bind(("127.0.0.1", 0))
        encoder = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
        encoder.signing.secret_key = KEY
        encoder.signing.sign_outgoing = True
        encoder.signing.link_id = 0
        encoder.signing.timestamp = signing_timestamp(time.time())

        def heartbeat() -> bytes:
            return bytes(encoder.heartbeat_encode(6, 8, 0, 0, 4).pack(encoder))

        genuine.sendto(heartbeat(), ("127.0.0.1", rig.port))
        assert [m for m in _drain(genuine, 1.5) if m.get_type() == "HEARTBEAT"]
        captured = heartbeat()  # on its way elsewhere (the autopilot), seen by the attacker
        replayer.sendto(captured, ("127.0.0.1", rig.port))
        assert _drain(replayer, 1.5) == []
        assert rig.stats()["link"].get("signed_stream_elsewhere", 0) == 1
    finally:
        genuine.close()
        replayer.close()
        rig.close()
