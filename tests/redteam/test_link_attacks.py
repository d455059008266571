"""Attacks on the MAVLink link itself, over real sockets on 127.0.0.1
(docs/engineering/security.md).

Each test replays one finding of an attack run against ``mavservo/mavlink/link.py``:

1. unknown message ids passed before the CRC and signature checks, made their sender a
   destination of the bridge's output (an amplifier), and were logged as input;
2. one parser shared by every UDP sender: a keyless header announcing 255 bytes swallowed the
   next senders' datagrams (and on a stream, good frames were lost after a bad one);
3. a ground station's SETUP_SIGNING put the 32-byte key into ``mavlink.tlog``;
4. one correctly keyed frame timestamped 10 years ahead locked out every new signed stream;
5. a second process silently shared the ``udpin`` port (pymavlink sets SO_REUSEADDR);
9. every handler exception logged a traceback, unbounded.
"""

from __future__ import annotations

import contextlib
import logging
import selectors
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.app.bridge import Bridge
from mavservo.app.startup_errors import DeviceOpenError
from mavservo.config.loader import load_config_text
from mavservo.mavlink.framing import MAX_REFUSED_PER_DATAGRAM, redact_secrets
from mavservo.mavlink.link import (
    MAX_UDP_PEERS,
    HandlerErrors,
    MavlinkLink,
)
from mavservo.mavlink.signing import signing_timestamp
from tests.redteam.test_bridge_security import (
    DO_SET_SERVO,
    GCS,
    KEY,
    Rig,
    acks,
    config_text,
    set_servo,
)
from tests.support.paths import REPO
from tests.support.waiting import free_udp_port, wait_until

UNKNOWN_V2 = bytes.fromhex("FD 03 00 00 00 42 42 DE BC 0A 01 02 03 00 00")  # id 0x0ABCDE
UNKNOWN_V1 = bytes.fromhex("FE 03 00 42 42 FF 01 02 03 00 00")  # MAVLink 1, id 255
BLINDING_HEADER = bytes.fromhex("FD FF 00 00 00 01 01 4C 00 00")  # announces 255 bytes
TEN_YEARS_S = 10 * 365 * 86400
QUIET_S = 1.0
"""How long after an expected ACK a test keeps listening for a second one (see ``acks``)."""
NEW_KEY = bytes(range(100, 132))
PASSKEY = b"operator-passkey-secret"


def drain(sock: socket.socket, seconds: float) -> int:
    """How many datagrams ``sock`` receives within ``seconds`` (bounded count)."""
    sock.settimeout(0.05)
    count = 0
    deadline = time.monotonic() + seconds
    for _ in range(100_000):
        if time.monotonic() >= deadline:
            break
        try:
            sock.recv(4096)
            count += 1
        except TimeoutError:
            continue
    return count


def answered_within(socks: list[socket.socket], seconds: float) -> list[bool]:
    """For each socket, whether it received a datagram within ``seconds``: all of them watched
    over the same window (one socket after the other, each with its own window, took 20 times
    as long and saw no more)."""
    got = [False] * len(socks)
    index = {sock.fileno(): i for i, sock in enumerate(socks)}
    with selectors.DefaultSelector() as selector:
        for sock in socks:
            selector.register(sock, selectors.EVENT_READ)
        deadline = time.monotonic() + seconds
        for _ in range(100_000):
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                break
            for key, _ in selector.select(remaining):
                got[index[key.fd]] = True
                selector.unregister(key.fileobj)
            if all(got):
                break
    return got


def flush(sock: socket.socket) -> int:
    """Drop the datagrams already waiting on ``sock`` (bounded count); how many."""
    sock.setblocking(False)
    dropped = 0
    try:
        for _ in range(10_000):
            sock.recv(4096)
            dropped += 1
    except BlockingIOError:
        pass
    finally:
        sock.setblocking(True)
    return dropped


def stranger() -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    return sock


class LoggedRig(Rig):
    """:class:`tests.redteam.test_bridge_security.Rig` with a run directory, so the tlog can be
    read."""

    def __init__(self, signing: bool, log_dir: Path) -> None:
        self.port = free_udp_port()
        text = config_text(self.port, signing).replace("logging: {dir: runs}", "")
        self.bridge = Bridge(load_config_text(text), log_dir=log_dir)
        self.bridge.start()
        self.peers: list[Any] = []

    def tlog(self) -> bytes:
        assert self.bridge.runlog is not None
        return (self.bridge.runlog.directory / "mavlink.tlog").read_bytes()


@pytest.fixture(params=[True, False], ids=["signed", "unsigned"])
def logged_rig(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[LoggedRig]:
    rig = LoggedRig(signing=request.param, log_dir=tmp_path)
    yield rig
    rig.close()


@pytest.fixture
def signed_rig() -> Iterator[Rig]:
    rig = Rig(signing=True)
    yield rig
    rig.close()


# ---------------------------------------------------------------------- 1: unknown ids


def test_unknown_ids_are_dropped_and_draw_nothing_back(
    logged_rig: LoggedRig, caplog: pytest.LogCaptureFixture
) -> None:
    """20 addresses (stand-ins for spoofed ones) send one unknown-id frame each, MAVLink 2 and
    MAVLink 1: none of them receives a single datagram, nothing is counted as received or
    written to the tlog, and no log line is written per frame."""
    rig = logged_rig
    caplog.set_level(logging.INFO)
    received_before = rig.stats()["link"].get("received", 0)
    strangers = [stranger() for _ in range(20)]
    try:
        for sock in strangers:
            sock.sendto(UNKNOWN_V2, ("127.0.0.1", rig.port))
            sock.sendto(UNKNOWN_V1, ("127.0.0.1", rig.port))
        back = sum(drain(sock, 1.0 if i == 0 else 0.05) for i, sock in enumerate(strangers))
    finally:
        for sock in strangers:
            sock.close()
    assert back == 0
    assert wait_until(lambda: rig.stats()["link"].get("unknown_id", 0) >= 40)
    link = rig.stats()["link"]
    assert link.get("received", 0) == received_before
    assert link["unknown_id"] == 40
    assert link["strangers_ignored"] >= 40
    assert UNKNOWN_V2[10:13] not in rig.tlog()  # its payload bytes were never logged as input
    assert not [r for r in caplog.records if "UNKNOWN" in r.getMessage()]


def heard(rig: Rig) -> int:
    link = rig.stats()["link"]
    return int(link.get("received", 0))


def test_output_goes_to_at_most_max_udp_peers_verified_addresses() -> None:
    """On an unsigned link any address can send a valid frame; the number of addresses the
    bridge sends to is capped. The identity (an allowed source here) pins its first address
    only; the others make room for newcomers least recently heard first (review3: before,
    every address claiming it was pinned, so these 16 locked every later peer out)."""
    rig = Rig(signing=False)
    extra = 4
    socks = [stranger() for _ in range(MAX_UDP_PEERS + extra)]
    encoder = mavlink2.MAVLink(None, srcSystem=GCS[0], srcComponent=GCS[1])
    heartbeat = encoder.heartbeat_encode(6, 8, 0, 0, 4).pack(encoder)
    try:
        for sent, sock in enumerate(socks, start=1):  # one after the other: a known order
            sock.sendto(heartbeat, ("127.0.0.1", rig.port))
            assert wait_until(lambda sent=sent: heard(rig) >= sent)
        for sock in socks:  # what came while a socket was still a peer is not the question
            flush(sock)
        answered = answered_within(socks, 1.5)
    finally:
        for sock in socks:
            sock.close()
        rig.close()
    expected = [True] + [False] * extra + [True] * (MAX_UDP_PEERS - 1)
    assert answered == expected
    assert rig.stats()["link"].get("peers_refused", 0) == 0


def test_a_strangers_datagram_does_not_choose_where_a_udpbcast_link_sends() -> None:
    """``udpbcast:``: pymavlink sends, from its first write after a datagram came in, to the
    address of that datagram, whoever sent it. Garbage from a stranger must not redirect the
    bridge's output away from the ground station to the stranger."""
    with stranger() as gcs, stranger() as attacker:
        gcs.settimeout(3.0)
        link = MavlinkLink(f"udpbcast:127.0.0.1:{gcs.getsockname()[1]}", lambda m, t: None)
        link.add_component(140, 1)
        link.start()
        heartbeat = mavlink2.MAVLink_heartbeat_message(26, 8, 0, 0, 4, 3)
        try:
            link.send(140, heartbeat, 1)
            _, link_address = gcs.recvfrom(4096)  # where the link sends from
            attacker.sendto(b"garbage", link_address)
            assert wait_until(lambda: link.counters["bad_data"] >= 1)
            for _ in range(3):
                link.send(140, heartbeat, 1)
            to_gcs = drain(gcs, 1.0)
            to_attacker = drain(attacker, 0.3)
        finally:
            link.stop()
    assert (to_gcs, to_attacker) == (3, 0)


def test_verified_peers_stay_destinations_across_a_reopen() -> None:
    """After the endpoint is closed and reopened (the link's recovery from a socket error),
    a ground station that spoke before still gets the output without speaking again."""
    port = free_udp_port()
    link = MavlinkLink(f"udpin:127.0.0.1:{port}", lambda m, t: None)
    link.add_component(140, 1)
    link.start()
    heartbeat = mavlink2.MAVLink_heartbeat_message(26, 8, 0, 0, 4, 3)
    try:
        with stranger() as gcs:
            gcs.sendto(heartbeat_frames(1)[0], ("127.0.0.1", port))
            assert wait_until(lambda: link.counters["received"] >= 1)
            link._close()  # what the receive loop does on a socket error
            assert wait_until(lambda: link.counters["reconnects"] >= 1)
            link.send(140, heartbeat, 1)
            assert drain(gcs, 1.0) == 1
    finally:
        link.stop()


# ---------------------------------------------------------------------- 2: one parser for all


def test_a_header_announcing_255_bytes_swallows_no_other_senders_command(
    signed_rig: Rig,
) -> None:
    """A keyless 10-byte datagram announcing 255 bytes, sent just before each of 10 signed
    commands from the ground station: every command is applied and ACKed."""
    rig = signed_rig
    gcs = rig.peer(GCS, key=KEY)
    with stranger() as attacker:
        for i in range(10):
            attacker.sendto(BLINDING_HEADER, ("127.0.0.1", rig.port))
            set_servo(gcs, 1, 1100 + 10 * i)
            # the next command goes once this one's ACK came and a short quiet followed; a
            # late second ACK of it would land in the next command's list (or the last wait)
            got = acks(gcs, DO_SET_SERVO, 2.0, quiet_s=0.2)
            assert [a.result for a in got] == [0], f"command {i}"
        assert acks(gcs, DO_SET_SERVO, QUIET_S) == []  # none answered twice, none late
    assert rig.setpoint("left") == pytest.approx(-30 + 60 * 0.19, abs=0.01)


def test_a_datagram_of_crafted_candidates_is_cut_short_and_the_next_one_is_read() -> None:
    """65,000 bytes of ``FE 00`` (a candidate frame at every other byte) cost the parser
    0.1-0.2 s of CPU byte by byte; after MAX_REFUSED_PER_DATAGRAM refusals the rest of the
    datagram is dropped (counted), and the heartbeat in the next datagram is handled."""
    port = free_udp_port()
    seen: list[str] = []
    link = MavlinkLink(f"udpin:127.0.0.1:{port}", lambda msg, t: seen.append(msg.get_type()))
    link.start()
    try:
        with stranger() as sender:
            sender.sendto(b"\xfe\x00" * 32_500, ("127.0.0.1", port))
            sender.sendto(heartbeat_frames(1)[0], ("127.0.0.1", port))
            assert wait_until(lambda: len(seen) >= 1)
    finally:
        link.stop()
    assert seen == ["HEARTBEAT"]
    assert link.counters["datagram_rest_dropped"] == 1
    assert MAX_REFUSED_PER_DATAGRAM <= link.counters["bad_data"] <= 2 * MAX_REFUSED_PER_DATAGRAM


def heartbeat_frames(count: int) -> list[bytes]:
    encoder = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    frames = []
    for _ in range(count):
        frames.append(encoder.heartbeat_encode(2, 3, 0, 0, 4).pack(encoder))
        encoder.seq = (encoder.seq + 1) % 256
    return frames


@contextlib.contextmanager
def link_on_a_stream() -> Iterator[tuple[socket.socket, MavlinkLink, list[int]]]:
    """A started link on a TCP stream (like a serial line) and the peer's end of it; yields
    (peer socket, link, sequence numbers of the messages the link handled, in order)."""
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    server.settimeout(5.0)
    seen: list[int] = []
    link = MavlinkLink(
        f"tcp:127.0.0.1:{server.getsockname()[1]}", lambda msg, t: seen.append(msg.get_seq())
    )
    link.start()
    try:
        conn, _ = server.accept()
        with conn:
            yield conn, link, seen
    finally:
        link.stop()
        server.close()


def test_a_stream_resynchronises_after_a_bad_header_without_losing_a_frame() -> None:
    """On TCP (a stream, like serial) the same 255-byte header is followed by 30 heartbeats:
    all 30 arrive, in order (the parser skips the bogus header, not the bytes it announced);
    a frame with an unknown id inside the stream costs nothing either."""
    with link_on_a_stream() as (conn, link, seen):
        frames = heartbeat_frames(30)
        stream = BLINDING_HEADER + b"".join(frames[:15]) + UNKNOWN_V2 + b"".join(frames[15:])
        conn.sendall(stream)
        assert wait_until(lambda: len(seen) >= 30)
    assert seen == list(range(30))
    assert link.counters["unknown_id"] == 1


def test_a_stream_does_not_hold_a_good_frame_behind_a_bogus_length() -> None:
    """On a quiet stream (one heartbeat a second on a serial link) a header announcing 255
    bytes followed by one heartbeat: the heartbeat is handled now, not once 280 bytes came."""
    with link_on_a_stream() as (conn, _link, seen):
        conn.sendall(BLINDING_HEADER + heartbeat_frames(1)[0])
        assert wait_until(lambda: len(seen) >= 1)
    assert seen == [0]


# ---------------------------------------------------------------------- 3: secrets in the tlog


def test_signing_key_and_passkey_never_reach_the_tlog(logged_rig: LoggedRig) -> None:
    """A ground station's SETUP_SIGNING (MAVProxy ``signing setup``) and
    CHANGE_OPERATOR_CONTROL are recorded with their secret fields zeroed."""
    rig = logged_rig
    signing = rig.bridge.config.mavlink.signing is not None
    gcs = rig.peer(GCS, key=KEY if signing else None)
    gcs.mav.setup_signing_send(1, 140, NEW_KEY, signing_timestamp(time.time()))
    gcs.mav.change_operator_control_send(1, 0, 0, PASSKEY)
    set_servo(gcs, 1, 1500)  # the ACK says everything before it was handled
    assert [a.result for a in acks(gcs, DO_SET_SERVO, 3.0, QUIET_S)] == [0]
    rig.bridge.stop()
    tlog = rig.tlog()
    assert NEW_KEY not in tlog and PASSKEY not in tlog
    records = mavutil.mavlink_connection(
        str(rig.bridge.runlog.directory / "mavlink.tlog"), dialect="ardupilotmega"
    )
    logged = []
    for _ in range(10_000):
        msg = records.recv_match(type=["SETUP_SIGNING", "CHANGE_OPERATOR_CONTROL"])
        if msg is None:
            break
        logged.append(msg)
    records.close()
    assert [m.get_type() for m in logged] == ["SETUP_SIGNING", "CHANGE_OPERATOR_CONTROL"]
    assert list(logged[0].secret_key) == [0] * 32 and logged[1].passkey in ("", b"")


def test_redaction_keeps_the_frame_readable_and_leaves_other_frames_alone() -> None:
    encoder = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    frame = bytes(encoder.setup_signing_encode(1, 140, NEW_KEY, 1234).pack(encoder))
    redacted = redact_secrets(frame)
    assert NEW_KEY not in redacted
    decoded = mavlink2.MAVLink(None).decode(bytearray(redacted))  # CRC recomputed: decodes
    assert decoded.initial_timestamp == 1234 and list(decoded.secret_key) == [0] * 32
    other = bytes(encoder.heartbeat_encode(6, 8, 0, 0, 4).pack(encoder))
    assert redact_secrets(other) == other


# ---------------------------------------------------------------------- 4: future timestamps


def test_a_frame_from_the_far_future_does_not_lock_out_new_streams(signed_rig: Rig) -> None:
    """A key holder with a clock 10 years ahead is refused (counted), and a ground station
    that starts its signed stream afterwards is still accepted."""
    rig = signed_rig
    wrong_clock = rig.peer((255, 191))  # a second GCS component, with the key
    wrong_clock.setup_signing(
        KEY, sign_outgoing=True, initial_timestamp=signing_timestamp(time.time() + TEN_YEARS_S)
    )
    wrong_clock.mav.heartbeat_send(6, 8, 0, 0, 4)
    gcs = rig.peer(GCS, key=KEY)
    set_servo(gcs, 1, 1750)
    assert [a.result for a in acks(gcs, DO_SET_SERVO, 3.0, QUIET_S)] == [0]
    assert rig.setpoint("left") == pytest.approx(15.0, abs=0.01)
    assert rig.stats()["link"]["signing_future"] == 1


def test_a_clock_a_little_ahead_is_still_accepted(signed_rig: Rig) -> None:
    """Within the window (30 s ahead of this computer's clock) a signed stream is accepted."""
    rig = signed_rig
    gcs = rig.peer(GCS)
    gcs.setup_signing(
        KEY, sign_outgoing=True, initial_timestamp=signing_timestamp(time.time() + 30)
    )
    set_servo(gcs, 1, 1250)
    assert [a.result for a in acks(gcs, DO_SET_SERVO, 3.0, QUIET_S)] == [0]
    assert rig.stats()["link"].get("signing_future", 0) == 0


class UnboundedClockRig(Rig):
    """A signing bridge configured for a companion without a synchronised clock."""

    def __init__(self) -> None:
        self.port = free_udp_port()
        text = config_text(self.port, signing=True).replace(
            f"key: {KEY.hex()}}}", f"key: {KEY.hex()}, max_clock_ahead_s: null}}"
        )
        assert "max_clock_ahead_s: null" in text
        self.bridge = Bridge(load_config_text(text), log_dir=False)
        self.bridge.start()
        self.peers = []


def test_without_the_ahead_bound_a_peer_ahead_is_accepted_and_locks_nobody_out() -> None:
    """``max_clock_ahead_s: null`` (a companion whose clock is behind its autopilot's): a
    stream 10 years ahead of this computer's clock is accepted, and a ground station on this
    computer's time that starts afterwards is accepted too (the clock new streams are compared
    with is never raised by a received timestamp)."""
    rig = UnboundedClockRig()
    try:
        ahead = rig.peer(GCS)  # link id 1 here, 0 below: two streams of the ground station
        ahead.setup_signing(
            KEY,
            sign_outgoing=True,
            link_id=1,
            initial_timestamp=signing_timestamp(time.time() + TEN_YEARS_S),
        )
        set_servo(ahead, 1, 1750)
        # (its ACK is signed on this computer's time, which that peer's own pymavlink refuses
        # as 10 years old: the setpoint shows the command was applied)
        assert wait_until(lambda: rig.setpoint("left") == pytest.approx(15.0, abs=0.01))
        gcs = rig.peer(GCS, key=KEY)
        set_servo(gcs, 1, 1250)
        assert [a.result for a in acks(gcs, DO_SET_SERVO, 3.0, QUIET_S)] == [0]
        assert rig.setpoint("left") == pytest.approx(-15.0, abs=0.01)
        assert rig.stats()["link"].get("signing_future", 0) == 0
    finally:
        rig.close()


# ---------------------------------------------------------------------- 5: a taken UDP port


def held_port() -> socket.socket:
    """A UDP socket bound the way pymavlink's udpin binds (SO_REUSEADDR), i.e. the way an old
    bridge, MAVProxy or a script holds the port."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind(("127.0.0.1", 0))
    return sock


def test_a_bridge_refuses_a_udp_port_another_process_holds() -> None:
    with held_port() as holder:
        port = holder.getsockname()[1]
        bridge = Bridge(load_config_text(config_text(port, signing=True)), log_dir=False)
        # the bridge names the link it could not open around the link's own error
        with pytest.raises(DeviceOpenError, match=f"127.0.0.1:{port} is in use by another process"):
            bridge.start()


def test_a_second_bridge_on_the_same_port_is_refused(signed_rig: Rig) -> None:
    second = Bridge(load_config_text(config_text(signed_rig.port, signing=True)), log_dir=False)
    with pytest.raises(DeviceOpenError, match="in use by another process"):
        second.start()
    gcs = signed_rig.peer(GCS, key=KEY)  # the first one still has every command
    set_servo(gcs, 1, 1500)
    assert [a.result for a in acks(gcs, DO_SET_SERVO, 3.0, QUIET_S)] == [0]


def test_run_on_a_taken_udp_port_is_one_clear_line_and_status_1(tmp_path: Path) -> None:
    """Same wording and status as a busy serial adapter: ``mavservo: cannot start: ...``."""
    with held_port() as holder:
        port = holder.getsockname()[1]
        cfg = tmp_path / "taken.yaml"
        cfg.write_text(config_text(port, signing=False))
        proc = subprocess.run(
            [sys.executable, "-m", "mavservo", "run", "--config", str(cfg), "--duration", "1"]
            + ["--no-log"],
            capture_output=True,
            text=True,
            timeout=60,
            cwd=REPO,
        )
    assert proc.returncode == 1
    assert "mavservo: cannot start: the autopilot link (" in proc.stderr  # (FILE:LINE: key)
    assert "mavlink: UDP port" in proc.stderr
    assert "in use by another process" in proc.stderr and "stop it first" in proc.stderr
    assert "Traceback" not in proc.stderr


# ---------------------------------------------------------------------- 9: handler errors


def test_handler_errors_are_counted_per_kind_and_logged_once(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """60 messages that make the handler raise: 60 counted under their kind, one warning with
    a traceback, no flood."""
    port = free_udp_port()

    def handler(msg: Any, t: float) -> None:
        if msg.get_type() == "HEARTBEAT":
            raise ValueError("hostile field")

    caplog.set_level(logging.DEBUG, logger="mavservo.mavlink.link")
    link = MavlinkLink(f"udpin:127.0.0.1:{port}", handler)
    link.start()
    peer = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", dialect="ardupilotmega")
    try:
        for _ in range(60):
            peer.mav.heartbeat_send(6, 8, 0, 0, 4)
        assert wait_until(lambda: link.counters["handler_errors"] >= 60)
    finally:
        peer.close()
        link.stop()
    errors = [r for r in caplog.records if "handling HEARTBEAT" in r.getMessage()]
    assert len(errors) == 1 and errors[0].levelno == logging.WARNING
    assert errors[0].exc_info is not None
    assert caplog.text.count("Traceback") == 1
    assert link.stats()["handler_error_kinds"] == {"HEARTBEAT/ValueError": 60}


def test_handler_error_repeats_are_summed_up_once_per_interval(
    caplog: pytest.LogCaptureFixture,
) -> None:
    now = [0.0]
    errors = HandlerErrors(summary_s=60.0, clock=lambda: now[0])
    caplog.set_level(logging.WARNING, logger="mavservo.mavlink.link")
    for step in range(200):  # 200 errors over 199 s: first, then a summary per 60 s
        now[0] = float(step)
        errors.record("GIMBAL_DEVICE_SET_ATTITUDE", TypeError("bad quaternion"))
    errors.record("COMMAND_LONG", ValueError("nan"))
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 5
    assert lines[1].startswith("60 more errors handling GIMBAL_DEVICE_SET_ATTITUDE (TypeError")
    assert errors.by_kind == {
        "GIMBAL_DEVICE_SET_ATTITUDE/TypeError": 200,
        "COMMAND_LONG/ValueError": 1,
    }
