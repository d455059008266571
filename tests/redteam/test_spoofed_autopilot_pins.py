"""A stranger claiming the autopilot's id on an unsigned link pins nothing more than one address.

Red team (review3) of issue 32, finding 5's fix, real sockets on 127.0.0.1. Before: each
verified frame claiming the followed autopilot's (or an allowed source's) id pinned its sender's
address for good: 2,000 spoofed HEARTBEATs from 2,000 ports pinned 1,923 addresses (the pin set
grew without bound) and the ground station's next command drew no answer at all (the 16-entry
peer table was all pins); on ``tcpin:``, 8 connections from 8 loopback addresses each claiming
the autopilot held every slot, reserved ones included, and the ground station was refused.
Now each privileged identity pins one address or holds one slot, the first verified one, until
it was silent for ``PIN_REBIND_S``.
"""

from __future__ import annotations

import socket
import time

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.mavlink.link import MAX_TCP_CLIENTS, UdpServer
from tests.redteam.test_session_squatting import _drain, _heartbeat, _is_servo_ack, _udp_bridge
from tests.redteam.test_tcp_server import Station, TcpRig

DO_SET_SERVO = 183
SPOOFED_PORTS = 300


def test_spoofed_autopilot_heartbeats_from_many_ports_do_not_lock_the_ground_station_out() -> None:
    bridge, port = _udp_bridge()
    try:
        for _ in range(SPOOFED_PORTS):  # bounded: one datagram from each of 300 ports
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.bind(("127.0.0.1", 0))
            sock.sendto(_heartbeat((1, 1)), ("127.0.0.1", port))
            sock.close()
        time.sleep(0.5)
        gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        gcs.bind(("127.0.0.1", 0))
        try:
            encoder = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
            command = encoder.command_long_encode(1, 140, DO_SET_SERVO, 0, 1, 1600, 0, 0, 0, 0, 0)
            gcs.sendto(command.pack(encoder), ("127.0.0.1", port))
            got = _drain(gcs, 2.0, until=_is_servo_ack)
        finally:
            gcs.close()
        assert [m for m in got if _is_servo_ack(m)]
        assert bridge.mavlink is not None
        link = bridge.mavlink.stats()["link"]
        assert link.get("peers_refused", 0) == 0
        assert link["udp_refused_pins"] > 0  # the spoofers' claims, counted
    finally:
        bridge.stop()


def test_a_udp_identity_pins_one_address_until_it_falls_silent() -> None:
    server = UdpServer("127.0.0.1", 0, max_peers=4)
    try:
        autopilot, spoofers = ("127.0.0.1", 1000), [("127.0.0.1", 2000 + n) for n in range(50)]
        assert server.admit(autopilot, 0.0, {(1, 1)})
        for n, spoofer in enumerate(spoofers):
            assert server.admit(spoofer, 0.01 * n, {(1, 1)})  # answered, as an ordinary peer
            server.admit(autopilot, 0.01 * n, {(1, 1)})  # the autopilot keeps talking
        assert server.refused_pins == len(spoofers)
        assert autopilot in server.peers
        assert len(server.peers) == 4  # the table stays bounded, nobody refused
        late = ("127.0.0.1", 3000)  # the autopilot rebooted on a new port: the pin moves
        assert server.admit(late, 10.0, {(1, 1)})
        assert server.admit(("127.0.0.1", 4000), 10.1)  # evicts an old one, not the new pin
        assert late in server.peers
    finally:
        server.close()


def _squatter(port: int, n: int) -> Station:
    """A station on its own loopback address (127.0.0.2, ...), claiming the autopilot's id."""
    station = Station.__new__(Station)
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.bind((f"127.0.0.{2 + n}", 0))
    sock.settimeout(1.0)
    sock.connect(("127.0.0.1", port))
    station.sock = sock
    station.encoder = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    station.decoder = mavlink2.MAVLink(None)
    station.decoder.robust_parsing = True
    return station


def test_tcp_connections_claiming_the_autopilot_cannot_hold_every_slot() -> None:
    rig = TcpRig()
    try:
        squatters = []
        for n in range(MAX_TCP_CLIENTS):  # one at a time, each verified before the next
            squatter = _squatter(rig.port, n)
            rig.sockets.append(squatter)
            squatter.heartbeat()
            squatters.append(squatter)
            time.sleep(0.25)
        for squatter in squatters:
            squatter.heartbeat()
        gcs = Station(rig.port, (255, 190))
        rig.sockets.append(gcs)
        gcs.heartbeat()
        gcs.set_servo(1, 1600)
        got = gcs.messages(2.0, "COMMAND_ACK", quiet_s=0.0)  # until the first ACK
        assert [m for m in got if m.get_type() == "COMMAND_ACK"], rig.stats()["link"]
        assert rig.stats()["link"].get("tcp_clients_refused", 0) == 0
    finally:
        rig.close()
