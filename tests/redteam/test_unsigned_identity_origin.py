"""Issue 40: on an unsigned link an identity's answers, writes and session stay with the address
it speaks from, and no flood fakes an autopilot loss. Real bridges and real sockets on
127.0.0.1 (the stranger on 127.0.0.66, its own loopback address).

Each test replays a finding of the attack run and fails on the code before issue 40 (02b724c):
answers went to wherever an identity was last heard; one PARAM_SET bucket per id; any frame
claiming an allowed source's id could write; in a TCP storm a newcomer replaced the real
autopilot's connection before its first frame was read; the autopilot's HEARTBEAT waited
behind a stranger's backlog in the one UDP socket (a false failsafe).
"""

from __future__ import annotations

import io
import logging
import socket
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.app.bridge import Bridge
from mavservo.app.check import check_main
from mavservo.config.loader import load_config_text
from mavservo.mavlink import link as link_module
from mavservo.mavlink.failsafe import FailsafeEvent, HeartbeatWatchdog
from mavservo.mavlink.framing import FrameScanner
from mavservo.mavlink.link import TcpServer, UdpServer
from mavservo.mavlink.params import WritePolicy
from tests.redteam.test_session_squatting import _drain
from tests.redteam.test_tcp_server import Station, TcpRig, connect, free_tcp_port
from tests.support.waiting import free_udp_port, wait_until

GCS = (255, 190)
AUTOPILOT = (1, 1)
STRANGER_HOST = "127.0.0.66"
REQUEST_MESSAGE = 512
SET_MESSAGE_INTERVAL = 511
FRAMES_PER_DATAGRAM = 4
SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33)


ALLOW_GCS = "  allowed_sources: [{system: 255, component: 190}]\n"


def _config(port: int, extra: str = ALLOW_GCS) -> str:
    return f"""
mavlink:
  url: udpin:127.0.0.1:{port}
{extra}servos:
  - {{name: aileron, profile: rmd-x, can_id: 1, limits_deg: [-30, 30]}}
channels:
  - {{servo: aileron, source: servo_output, channel: 1}}
"""


class Peer:
    """A raw UDP socket speaking as ``source`` from ``host``."""

    def __init__(self, port: int, source: tuple[int, int], host: str = "127.0.0.1") -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((host, 0))
        self.target = ("127.0.0.1", port)
        self.encoder = mavlink2.MAVLink(None, srcSystem=source[0], srcComponent=source[1])

    def send(self, msg: Any) -> None:
        self.sock.sendto(msg.pack(self.encoder), self.target)

    def heartbeat(self, mav_type: int = 6) -> None:
        self.send(self.encoder.heartbeat_encode(mav_type, 8 if mav_type == 6 else 3, 0, 0, 4))

    def read(self, name: str) -> None:
        self.send(self.encoder.param_request_read_encode(1, 140, name.encode(), -1))

    def set(self, name: str, value: float) -> None:
        self.send(self.encoder.param_set_encode(1, 140, name.encode(), value, 9))

    def close(self) -> None:
        self.sock.close()


@contextmanager
def _bridge(extra: str = ALLOW_GCS) -> Iterator[tuple[Bridge, int]]:
    port = free_udp_port()
    bridge = Bridge(load_config_text(_config(port, extra)), log_dir=False).start()
    try:
        yield bridge, port
    finally:
        bridge.stop()


def _stats(bridge: Bridge) -> dict[str, Any]:
    assert bridge.mavlink is not None
    return bridge.mavlink.stats()


def _param_values(messages: list[Any], name: str) -> list[float]:
    return [
        m.param_value
        for m in messages
        if m.get_type() == "PARAM_VALUE" and m.param_id.rstrip("\x00") == name
    ]


# ------------------------------------------------------------------ answers


def test_answers_go_to_the_address_the_request_came_from_not_the_identitys_last() -> None:
    """A stranger sends HEARTBEAT as the ground station right after each of its requests: on
    02b724c the answer went to the stranger (the identity's last address)."""
    with _bridge() as (bridge, port):
        gcs, stranger = Peer(port, GCS), Peer(port, GCS, STRANGER_HOST)
        try:
            gcs.heartbeat()
            assert wait_until(lambda: _stats(bridge)["link"].get("received", 0) >= 1)
            got = []
            for _ in range(5):  # bounded: five requests
                gcs.read("SRV1_TRIM")
                stranger.heartbeat()
                got += _param_values(_drain(gcs.sock, 2.0, until=_is_trim), "SRV1_TRIM")
            stolen = _param_values(_drain(stranger.sock, 0.3), "SRV1_TRIM")
        finally:
            gcs.close()
            stranger.close()
        assert len(got) == 5, _stats(bridge)["link"]
        assert stolen == []


def _is_trim(msg: Any) -> bool:
    return bool(msg.get_type() == "PARAM_VALUE" and msg.param_id.rstrip("\x00") == "SRV1_TRIM")


# ------------------------------------------------------------------ writes


def test_a_set_flood_claiming_the_station_from_elsewhere_costs_it_no_set() -> None:
    """100 PARAM_SETs as 255/190 from another address, then the station's 10 sets: on
    02b724c they shared one bucket (burst 30, 10/s) and the station's were rate-limited,
    while the stranger's went through."""
    with _bridge() as (bridge, port):
        gcs, stranger = Peer(port, GCS), Peer(port, GCS, STRANGER_HOST)
        try:
            gcs.heartbeat()
            assert wait_until(lambda: _stats(bridge)["link"].get("received", 0) >= 1)
            for _ in range(100):
                stranger.set("SRV1_TRIM", 7.0)
            assert wait_until(lambda: _stats(bridge)["link"].get("received", 0) >= 101)
            for n in range(10):
                gcs.set("SRV1_TRIM", float(n + 1))
            assert wait_until(lambda: _stats(bridge)["link"].get("received", 0) >= 111)
            time.sleep(0.2)
        finally:
            gcs.close()
            stranger.close()
        parameters = _stats(bridge)["parameters"]
        assert parameters.get("set_accepted", 0) == 10, parameters
        assert parameters.get("set_rate_limited", 0) == 0, parameters
        assert bridge.parameters is not None
        assert bridge.parameters.value("SRV1_TRIM") == 10.0


def test_a_spoofed_allowed_source_writes_nothing_and_is_named(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """SRV1_TRIM=7 from 127.0.0.66 claiming 255/190 with the station present: applied 2 of 2
    on 02b724c. Now refused, counted, and a notice names the other address (a warning line
    and a STATUSTEXT the station receives)."""
    caplog.set_level(logging.WARNING, logger="mavservo.mavlink")
    with _bridge() as (bridge, port):
        gcs, stranger = Peer(port, GCS), Peer(port, GCS, STRANGER_HOST)
        try:
            gcs.heartbeat()
            assert wait_until(lambda: _stats(bridge)["link"].get("received", 0) >= 1)
            stranger.set("SRV1_TRIM", 7.0)
            stranger.set("SRV1_TRIM", 7.0)
            assert wait_until(lambda: _stats(bridge)["link"].get("received", 0) >= 3)
            # a long notice comes as MAVLink 2 chunks (same id, chunk_seq 0..): wait for the
            # last one (shorter than the 50-character field) and read the text they make
            texts = [
                m.text
                for m in _drain(gcs.sock, 2.0, until=_last_statustext_chunk)
                if m.get_type() == "STATUSTEXT"
            ]
        finally:
            gcs.close()
            stranger.close()
        assert bridge.parameters is not None
        assert bridge.parameters.value("SRV1_TRIM") == 0.0
        assert _stats(bridge)["parameters"].get("set_accepted", 0) == 0
        assert _stats(bridge)["core"].get("claims_refused", 0) == 2
        assert STRANGER_HOST in "".join(texts), texts
        assert any(STRANGER_HOST in r.getMessage() for r in caplog.records)


def _last_statustext_chunk(message: Any) -> bool:
    """A STATUSTEXT that ends its text: unchunked (id 0) or the chunk under 50 characters."""
    return message.get_type() == "STATUSTEXT" and (message.id == 0 or len(message.text) < 50)


# ------------------------------------------------------------------ TCP


def test_a_connection_storm_never_replaces_the_autopilot_before_its_first_frame_is_read() -> None:
    """The autopilot connects and sends its HEARTBEAT, then 12 connections arrive before the
    server reads anything: on 02b724c the newcomers replaced "the oldest client without a
    verified frame", the autopilot, with its frame unread in the socket."""
    counters: Counter[str] = Counter()
    decoder = mavlink2.MAVLink(None)
    port = free_tcp_port()
    server = TcpServer("127.0.0.1", port, lambda: FrameScanner(decoder, counters), counters)
    autopilot = connect(port)
    storm: list[socket.socket] = []
    encoder = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    try:
        autopilot.sendall(encoder.heartbeat_encode(1, 3, 81, 0, 4).pack(encoder))
        time.sleep(0.1)  # the autopilot's connection is the first in the accept queue
        storm = [connect(port) for _ in range(12)]
        time.sleep(0.1)
        verified = []
        for _ in range(20):  # bounded polls, as the link's receive thread makes them
            if server.select(0.05):
                for client, data in server.receive():
                    if client.scanner.stream(data):
                        server.verify(client, [AUTOPILOT])
                        verified.append(client)
        assert verified, dict(counters)
        assert counters["tcp_clients_replaced"] == 0, dict(counters)
        assert server.holder_of(AUTOPILOT) is verified[0]
        autopilot.settimeout(0.2)
        with pytest.raises(TimeoutError):  # still open: nothing to read, no EOF, no reset
            autopilot.recv(1)
    finally:
        for sock in [autopilot, *storm]:
            sock.close()
        server.close()


def test_two_connections_claiming_the_autopilot_are_reported(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.WARNING, logger="mavservo.mavlink")
    rig = TcpRig()
    try:
        first = Station(rig.port, AUTOPILOT)
        rig.sockets.append(first)
        first.send(first.encoder.heartbeat_encode(1, 3, 81, 0, 4))
        assert wait_until(lambda: rig.stats()["link"].get("received", 0) >= 1)
        second = Station(rig.port, AUTOPILOT)
        rig.sockets.append(second)
        second.send(second.encoder.heartbeat_encode(1, 3, 81, 0, 4))
        assert wait_until(lambda: rig.stats()["link"].get("received", 0) >= 2)
        first.send(first.encoder.heartbeat_encode(1, 3, 81, 0, 4))
        assert wait_until(lambda: rig.stats()["link"].get("received", 0) >= 3)
        stats = rig.stats()
        assert stats["link"].get("identity_claimed_elsewhere", 0) >= 1
        assert (
            stats["core"].get("claims_refused", 0) >= 1
        )  # the second one's heartbeat fed no watchdog
        lines = [r.getMessage() for r in caplog.records if "claims it too" in r.getMessage()]
        assert lines and "1/1" in lines[0] and lines[0].count("tcp 127.0.0.1:") == 2, lines
    finally:
        rig.close()


# ------------------------------------------------------------------ liveness


def _requests(encoder: Any, n: int) -> bytes:
    """One stranger datagram: REQUEST_MESSAGE and SET_MESSAGE_INTERVAL for messages the
    bridge publishes (ESC_STATUS 291, SERVO_OUTPUT-like streams), as :data:`FRAMES_PER_DATAGRAM`
    frames from the spoofed ids ``n`` cycles through (a datagram may carry several)."""
    frames = b""
    for k in range(FRAMES_PER_DATAGRAM):
        encoder.srcSystem = 2 + (n * FRAMES_PER_DATAGRAM + k) % 250
        if k % 2:
            msg = encoder.command_long_encode(
                1, 140, SET_MESSAGE_INTERVAL, 0, 291, 1e5, 0, 0, 0, 0, 0
            )
        else:
            msg = encoder.command_long_encode(1, 140, REQUEST_MESSAGE, 0, 291, 0, 0, 0, 0, 0, 0)
        frames += msg.pack(encoder)
    return frames


def test_a_backlog_of_10000_stranger_datagrams_ahead_of_a_heartbeat_is_no_autopilot_loss() -> None:
    """10,000 REQUEST_MESSAGEs from 250 spoofed ids wait in the socket ahead of the
    autopilot's HEARTBEAT (built while the MAVLink side is held, so the backlog is exact). On
    02b724c the heartbeat was handled after the whole backlog, seconds late: the bridge
    declared the healthy autopilot lost."""
    with _bridge("  heartbeat_timeout_s: 1.5\n") as (bridge, port):  # anyone may command
        assert bridge.mavlink is not None
        side = bridge.mavlink
        server_sock = side.link._conn._sock  # noqa: SLF001 - the test sizes the kernel queue
        try:
            server_sock.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, 64 << 20)
        except OSError:
            pytest.skip("needs SO_RCVBUFFORCE (CAP_NET_ADMIN) to queue 10,000 datagrams")
        autopilot, stranger = Peer(port, AUTOPILOT), Peer(port, (2, 1), STRANGER_HOST)
        stop = threading.Event()

        def beat() -> None:
            while not stop.wait(0.25):
                autopilot.heartbeat(mav_type=1)

        beating = threading.Thread(target=beat, daemon=True)
        try:
            autopilot.heartbeat(mav_type=1)
            assert wait_until(lambda: side.core.watchdog.last_heartbeat is not None)
            with side._lock:  # noqa: SLF001 - pause: both MAVLink threads wait here
                autopilot.heartbeat(mav_type=1)
                for n in range(10_000):
                    stranger.sock.sendto(_requests(stranger.encoder, n), stranger.target)
                autopilot.heartbeat(mav_type=1)
                beating.start()
            time.sleep(3.0)  # the backlog is handled (or shed) meanwhile
        finally:
            stop.set()
            if beating.is_alive():
                beating.join(1.0)
            autopilot.close()
            stranger.close()
        stats = side.stats()
        assert stats["link"]["udp_kernel_drops"] == 0, stats["link"]
        assert stats["failsafe_count"] == 0, stats["link"]
        assert stats["link"]["udp_shed"] > 0  # the stranger's backlog beyond the bound, said


def test_the_udp_server_handles_pinned_datagrams_first_keeps_each_senders_order_and_sheds(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Real sockets, the server driven by hand: what waits in the socket is read first, the
    pinned address's datagrams come out ahead of a stranger's backlog, a stranger's own
    datagrams keep their order, and beyond the bound the oldest waiting are shed (counted)."""
    monkeypatch.setattr(link_module, "UDP_MAX_DEFERRED", 50)
    server = UdpServer("127.0.0.1", 0)
    autopilot, stranger = Peer(server.address[1], AUTOPILOT), Peer(server.address[1], (2, 1))
    try:
        pinned_at = autopilot.sock.getsockname()
        assert server.admit(pinned_at, 0.0, {AUTOPILOT})
        for n in range(80):
            stranger.sock.sendto(n.to_bytes(2, "big"), stranger.target)
        autopilot.sock.sendto(b"hb", autopilot.target)
        assert wait_until(lambda: server.select(0.05))
        time.sleep(0.1)  # all 81 in the socket
        server.drain(0.0)
        batch = server.next_batch(others=10)
        assert batch[0] == (b"hb", pinned_at)
        rest = [int.from_bytes(d, "big") for d, _ in batch[1:]]
        for _ in range(10):  # bounded: the rest of the backlog, 10 a pass
            rest += [int.from_bytes(d, "big") for d, _ in server.next_batch(others=10)]
        assert rest == list(range(30, 80))  # in order; the 30 oldest shed
        assert server.shed == 30
    finally:
        autopilot.close()
        stranger.close()
        server.close()


def test_check_recommends_signing_wherever_writes_are_allowed() -> None:
    listed = WritePolicy(frozenset({GCS}))
    assert listed.signing_advice(signing=True) == []
    (line,) = listed.signing_advice(signing=False)
    assert "mavlink.signing" in line and "255/190" in line and "parameter sets" in line
    (line,) = WritePolicy().signing_advice(signing=False)  # commands from anyone, no sets
    assert "commands from anyone" in line and "parameter" not in line
    out, err = io.StringIO(), io.StringIO()
    port = free_udp_port()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "rig.yaml"
        path.write_text(_config(port))
        assert check_main([str(path)], out, err) == 0, err.getvalue()
    assert "recommended: mavlink.signing" in out.getvalue()


# ------------------------------------------------------------------ sessions


def test_ftp_sessions_and_answers_belong_to_the_ids_and_the_origin() -> None:
    """Two origins claiming 255/190 (its ids are not privileged here, so both are served):
    one's ResetSessions does not end the other's session, and each one's replies are
    answers to its own origin. Keyed by the ids alone (02b724c), the reset ended both."""
    from mavservo.mavlink import ftp
    from mavservo.mavlink.mavlink_core import MavlinkCore
    from mavservo.mavlink.origin import Requester, tag
    from mavservo.mavlink.settings import MavlinkSettings
    from tests.support.mavlink_doubles import RecordingBackend, wire

    core = MavlinkCore(
        MavlinkSettings(system_id=1, link_budget_bytes_s=None),
        RecordingBackend(),
        boot_time=0.0,
        metadata_files={140: {"general.json": b"{}"}},
    )
    station, stranger = ("127.0.0.1", 14550), (STRANGER_HOST, 14550)

    def send(origin: tuple[str, int], opcode: int, session: int = 0, data: bytes = b"") -> None:
        header = ftp.HEADER.pack(1, session, opcode, len(data), 0, 0, 0, 0)
        payload = list((header + data).ljust(ftp.PAYLOAD_BYTES, b"\x00"))
        msg = wire(mavlink2.MAVLink_file_transfer_protocol_message(0, 1, 140, payload), GCS)
        tag(msg, origin, True)
        core.on_message(msg, 0.0)

    def replies(now: float) -> list[tuple[Any, int, int]]:
        core.tick(now)
        return [
            (a.to, bytes(a.msg.payload)[3], bytes(a.msg.payload)[2])  # to, opcode, session
            for a in core.answers_due(now)
            if a.msg.get_type() == "FILE_TRANSFER_PROTOCOL"
        ]

    send(station, ftp.OP_OPEN_FILE_RO, data=b"general.json")
    ((to, opcode, session),) = replies(0.01)
    assert (to, opcode) == (Requester(*GCS, station), ftp.OP_ACK)
    send(stranger, ftp.OP_RESET_SESSIONS)
    assert [r[:2] for r in replies(0.02)] == [(Requester(*GCS, stranger), ftp.OP_ACK)]
    send(station, ftp.OP_READ_FILE, session=session)
    assert [r[:2] for r in replies(0.03)] == [(Requester(*GCS, station), ftp.OP_ACK)]


def test_set_message_interval_at_the_rate_in_force_does_not_replan_the_link_budget() -> None:
    """The flood's SET_MESSAGE_INTERVALs repeat the configured rates: on 02b724c each accepted
    one re-planned the budget (1,334 re-plans in 8 s) and the gimbal status fell to about
    4 Hz on the autopilot link (bench/bench_unsigned_flood.py); only a change re-plans now."""
    from mavservo.mavlink.mavlink_core import MavlinkCore
    from mavservo.mavlink.settings import MavlinkSettings
    from tests.support.mavlink_doubles import RecordingBackend, wire

    settings = MavlinkSettings(system_id=1, link_budget_bytes_s=1000.0)
    core = MavlinkCore(settings, RecordingBackend(), boot_time=0.0)
    configured = 1e6 / core.settings.telemetry.actuator_output_status_hz
    replans = core.budget.counters["replans"]
    for n in range(50):  # 50 spoofed ids repeating the rate in force
        msg = mavlink2.MAVLink_command_long_message(
            1, 140, SET_MESSAGE_INTERVAL, 0, 375, configured, 0, 0, 0, 0, 0
        )
        core.on_message(wire(msg, (2 + n, 190)), 0.01 * n)
    assert core.budget.counters["replans"] == replans
    slower = mavlink2.MAVLink_command_long_message(
        1, 140, SET_MESSAGE_INTERVAL, 0, 375, 2 * configured, 0, 0, 0, 0, 0
    )
    core.on_message(wire(slower, GCS), 1.0)
    assert core.budget.counters["replans"] == replans + 1


def test_the_watchdog_waits_for_a_reader_behind_its_deadline_at_most_one_more_timeout() -> None:
    watchdog = HeartbeatWatchdog(2.0)
    watchdog.heartbeat(10.0)
    assert watchdog.check(12.5, read_until=11.9) is None  # a heartbeat may wait unread
    assert watchdog.heartbeat(12.6) is None  # it did: never a failsafe
    assert watchdog.check(14.7, read_until=14.6) is FailsafeEvent.LOST  # read: it is gone
    stuck = HeartbeatWatchdog(2.0)
    stuck.heartbeat(10.0)
    assert stuck.check(13.9, read_until=10.5) is None
    assert stuck.check(14.0, read_until=10.5) is FailsafeEvent.LOST  # a reader stuck for good
    assert stuck.deferred == 1


def test_a_stalled_reader_is_no_autopilot_loss() -> None:
    """The receive thread stalls 2.6 s (a machine that starves the process, as in the
    benchmark's first run: the heartbeat read 2.6 s late) while the autopilot keeps sending at
    5 Hz; the tick thread runs on. On 02b724c the watchdog declared the autopilot lost."""
    with _bridge("  heartbeat_timeout_s: 2.0\n") as (bridge, port):
        assert bridge.mavlink is not None
        side = bridge.mavlink
        autopilot = Peer(port, AUTOPILOT)
        gate = threading.Event()
        gate.set()
        handle = side.link._on_message  # noqa: SLF001 - the test stalls the reader

        def stalled(msg: Any, now: float) -> None:
            gate.wait(10.0)
            handle(msg, now)

        side.link._on_message = stalled  # noqa: SLF001
        try:
            autopilot.heartbeat(mav_type=1)
            assert wait_until(lambda: side.core.watchdog.last_heartbeat is not None)
            gate.clear()
            for _ in range(13):  # 2.6 s of heartbeats at 5 Hz, unread
                autopilot.heartbeat(mav_type=1)
                time.sleep(0.2)
            gate.set()
            time.sleep(0.5)
        finally:
            gate.set()
            autopilot.close()
        stats = side.stats()
        assert stats["failsafe_count"] == 0, stats
        assert stats["failsafe_deferred"] > 0


@pytest.mark.parametrize("extra", ["", ALLOW_GCS], ids=["ids-not-privileged", "ids-allowed"])
def test_a_download_and_an_ack_go_to_the_station_while_its_ids_are_claimed_elsewhere(
    extra: str,
) -> None:
    """The merge of issue 38 (FTP replies queued per requester, within the link budget) and
    issue 40 (answers to the origin, keyed by ids and origin), end to end on the default
    budget: the station (255/190 on 127.0.0.1) downloads general.json over MAVLink FTP as
    QGroundControl does and asks for a message with REQUEST_MESSAGE, while a stranger on
    127.0.0.66 claims 255/190 with a HEARTBEAT every 50 ms (the identity's last address is
    the stranger's throughout). The station gets the file and its COMMAND_ACK; the stranger
    gets no FTP reply and no ACK, whether the ids are privileged (pinned to the station) or
    not (then both are served, each its own answers). Before (90f533f), with the ids allowed,
    the station's ACK and the message it asked for went to every peer, the stranger too: a
    verified sender's responses were sent at once, to everyone."""
    from mavservo.mavlink.connection import open_connection
    from tests.support.qgc_ftp import QgcLikeFtp

    with _bridge(extra) as (bridge, port):
        stranger = Peer(port, GCS, STRANGER_HOST)
        station = open_connection(
            f"udpout:127.0.0.1:{port}", source_system=GCS[0], source_component=GCS[1]
        )
        claiming = threading.Event()

        def claim() -> None:
            for _ in range(400):  # bounded: 20 s at most
                if claiming.wait(0.05):
                    return
                stranger.heartbeat()

        claimer = threading.Thread(target=claim, daemon=True)
        try:
            station.mav.heartbeat_send(6, 8, 0, 0, 4)
            assert wait_until(lambda: _stats(bridge)["link"].get("received", 0) >= 1)
            claimer.start()
            got = QgcLikeFtp(station, (1, 140)).download("/general.json")
            station.mav.command_long_send(1, 140, REQUEST_MESSAGE, 0, 375, 0, 0, 0, 0, 0, 0)
            ack = station.recv_match(type="COMMAND_ACK", blocking=True, timeout=3.0)
            claiming.set()
            claimer.join(2.0)
            to_stranger = _drain(stranger.sock, 0.5)
        finally:
            claiming.set()
            station.close()
            stranger.close()
        served = bytes(bridge.mavlink.core.metadata.servers[140].files["general.json"])
        assert got.data == served
        assert ack is not None and (ack.command, ack.result) == (REQUEST_MESSAGE, 0)
        kinds = Counter(m.get_type() for m in to_stranger)
        assert kinds["FILE_TRANSFER_PROTOCOL"] == 0, kinds
        assert kinds["COMMAND_ACK"] == 0, [m for m in to_stranger if m.get_type() == "COMMAND_ACK"]
        assert to_stranger  # it is a peer the bridge sends to (its broadcasts), not cut off


def test_the_doctors_tunnel_link_takes_no_can_frame_claiming_the_autopilot_from_elsewhere() -> None:
    """Issue 40 on ``mavservo doctor``'s own link (:class:`TunnelLink`, no core behind it): the
    autopilot's ids pin the address it is first heard from, so CAN_FRAMEs claiming them from
    another address (unsigned UDP) are refused and counted, not taken for servo replies. Before:
    nothing was pinned on that link and all 10 of the stranger's frames were taken."""
    from mavservo.mavlink import open_connection
    from mavservo.mavlink.settings import MavlinkSettings
    from mavservo.mavlink.tunnel_link import TunnelLink

    port = free_udp_port()
    tunnel_link = TunnelLink(MavlinkSettings(url=f"udpin:127.0.0.1:{port}", system_id=1))
    url = f"udpout:127.0.0.1:{port}"
    autopilot = open_connection(url, source_system=1, source_component=1)
    stranger = open_connection(url, source_system=1, source_component=1)
    try:
        tunnel_link.link.start()
        stats = tunnel_link.tunnel.stats

        def heartbeat() -> None:
            autopilot.mav.heartbeat_send(2, 3, 0, 0, 4)  # quadrotor, ArduPilot

        assert wait_until(lambda: (heartbeat(), tunnel_link._heard.wait(0.05))[1], 3.0)
        heartbeat()  # its address is pinned from its second frame on (the first named it)
        reply = bytes([0x9C, 40, 0, 0, 0, 0, 0x10, 0x27])
        for _ in range(10):
            autopilot.mav.can_frame_send(1, 140, 0, 8, 0x241, reply)
            stranger.mav.can_frame_send(1, 140, 0, 8, 0x241, reply)
        # no sink on bus 0: the autopilot's frames are counted unsubscribed, the stranger's not
        assert wait_until(
            lambda: stats().get("unsubscribed", 0) + stats().get("claimed_elsewhere", 0) >= 20,
            3.0,
        ), stats()
        assert stats().get("claimed_elsewhere", 0) == 10, stats()
        assert stats().get("unsubscribed", 0) == 10, stats()
    finally:
        autopilot.close()
        stranger.close()
        tunnel_link.stop()


def test_on_a_udpout_link_a_stranger_claiming_the_autopilot_is_not_from_its_address() -> None:
    """``udpout``: the socket takes datagrams from anyone who finds its port. Frames claiming the
    autopilot from another address than the one the link sends to are tagged as not from its
    pinned address (the core refuses them); the autopilot's own are. Before: untagged, all 5 of
    the stranger's HEARTBEATs counted as the autopilot's (they kept the bridge out of failsafe)."""
    from mavservo.mavlink import open_connection
    from mavservo.mavlink.link import MavlinkLink
    from mavservo.mavlink.origin import from_pinned

    port = free_udp_port()
    autopilot = open_connection(f"udpin:127.0.0.1:{port}", source_system=1, source_component=1)
    heard: list[tuple[int, bool]] = []
    link = MavlinkLink(
        f"udpout:127.0.0.1:{port}",
        lambda msg, now: heard.append((msg.custom_mode, from_pinned(msg))),
    )
    link.privileged = lambda source: source == (1, 1)
    link.add_component(140, 1)
    stranger = None
    try:
        link.start()
        ping = mavlink2.MAVLink_heartbeat_message(0, 8, 0, 0, 0, 3)
        assert wait_until(lambda: (link.send(140, ping, 1), autopilot.recv_msg())[1], 3.0)
        stranger = open_connection(
            f"udpout:127.0.0.1:{link._conn.port.getsockname()[1]}",
            source_system=1,
            source_component=1,
        )
        for _ in range(5):
            autopilot.mav.heartbeat_send(2, 3, 0, 1, 4)  # custom_mode 1: the autopilot
            stranger.mav.heartbeat_send(2, 3, 0, 2, 4)  # custom_mode 2: the stranger
        assert wait_until(lambda: len(heard) >= 10, 3.0), heard
        assert sorted(Counter(heard).items()) == [((1, True), 5), ((2, False), 5)], heard
    finally:
        link.stop()
        autopilot.close()
        if stranger is not None:
            stranger.close()
