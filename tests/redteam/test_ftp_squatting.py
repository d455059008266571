"""MAVLink FTP: squatted sessions and a flooded reply queue do not keep a ground station out.

Red team (review3) of issue 30 item 3's FTP server. Before: 4 sessions, 2 per sender, each
kept for 10 s after its last request, so two senders' four OpenFileRO every 10 s kept every
ground station out (NAK NoSessionsAvailable for good); and one 16-entry reply queue for all
senders, drained at the FTP share of the link (about 100 B/s at a 1 kB/s budget): one sender's
10 requests a second kept it full and every other requester's replies were dropped.
"""

from __future__ import annotations

import socket
import time
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.app.bridge import Bridge
from mavservo.config.loader import load_config
from mavservo.mavlink import ftp
from mavservo.mavlink.connection import open_connection
from mavservo.mavlink.ftp import FtpServer
from tests.mavlink.test_ftp_metadata import CONFIG, FILES, GCS, answers, request
from tests.support.waiting import free_udp_port

SQUATTERS = [(100 + n, 190) for n in range(ftp.MAX_SESSIONS)]


def _opened(server: FtpServer, sender: tuple[int, int], now: float) -> bool:
    server.handle(request(ftp.OP_OPEN_FILE_RO, data=b"general.json"), sender, now)
    replies = [p for to, p in server.periodic(now + 0.001) if to == sender]
    return any(p[3] == ftp.OP_ACK for p in replies)


def test_sessions_left_idle_by_squatters_make_room_for_a_ground_station() -> None:
    server = FtpServer(FILES, bytes_per_s=1e9)
    for squatter in SQUATTERS:  # as many sessions as there are, two per sender at most
        for _ in range(2):
            _opened(server, squatter, 0.0)
    assert server.stats()["sessions"] == ftp.MAX_SESSIONS
    assert not _opened(server, GCS, 0.5)  # all in use just now: refused
    assert _opened(server, GCS, 2.0)  # idle for 2 s (not 10): the oldest makes room


def test_a_session_in_use_is_never_evicted() -> None:
    server = FtpServer(FILES, bytes_per_s=1e9)
    assert _opened(server, GCS, 0.0)
    for n, squatter in enumerate(SQUATTERS * 2):  # a flood of opens, 0.1 s apart
        now = 0.1 * (n + 1)
        server.handle(request(ftp.OP_READ_FILE, session=0, size=10), GCS, now)  # in use
        _opened(server, squatter, now)
    server.handle(request(ftp.OP_READ_FILE, session=0, size=10), GCS, 10.0)
    replies = [ftp.HEADER.unpack_from(p) for to, p in server.periodic(10.0) if to == GCS]
    assert replies and replies[-1][2] == ftp.OP_ACK


def test_a_flooding_sender_cannot_fill_the_reply_queue_for_everyone() -> None:
    server = FtpServer(FILES, bytes_per_s=1.0)  # a window that lets almost nothing out
    rogue = (66, 190)
    answers(server, 0.0)
    for n in range(200):
        server.handle(request(ftp.OP_NONE, seq=n), rogue, 0.0)
    server.handle(request(ftp.OP_OPEN_FILE_RO, data=b"general.json"), GCS, 0.0)
    assert server.queued_for(GCS) == 1  # what waits for the window
    assert server.queued_for(rogue) <= ftp.MAX_QUEUED_PER_SENDER


def test_over_udp_a_real_ftp_client_reads_past_squatted_sessions(tmp_path: Path) -> None:
    from pymavlink.mavftp import MAVFTP

    port = free_udp_port()
    path = tmp_path / "rig.yaml"
    path.write_text(CONFIG.format(port=port))
    bridge = Bridge(load_config(path), config_path=path, log_dir=False).start()
    squatter = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    conn = open_connection(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190)
    try:
        for system, component in SQUATTERS:  # two sessions each, then silence
            encoder = mavlink2.MAVLink(None, srcSystem=system, srcComponent=component)
            for seq in range(2):
                payload = request(ftp.OP_OPEN_FILE_RO, seq=seq, data=b"/general.json")
                message = encoder.file_transfer_protocol_encode(0, 1, 140, list(payload))
                squatter.sendto(message.pack(encoder), ("127.0.0.1", port))
        time.sleep(1.5)
        conn.mav.heartbeat_send(6, 8, 0, 0, 4)
        client = MAVFTP(conn, 1, 140)
        assert client.cmd_get(["/general.json", str(tmp_path / "general.json")]).error_code == 0
        assert client.process_ftp_reply("OpenFileRO", timeout=8).error_code == 0
        assert (tmp_path / "general.json").read_bytes().startswith(b"{")
        assert bridge.mavlink is not None
        assert bridge.mavlink.stats()["ftp"]["140"]["opened"] >= ftp.MAX_SESSIONS
    finally:
        squatter.close()
        conn.close()
        bridge.stop()


def test_ftp_replies_go_to_the_requester_only(tmp_path: Path) -> None:
    """Before: FTP replies went out with the tick's output, to every peer (a bystander got
    the stranger's OpenFileRO ACK and burst data); now only the requester gets them."""
    port = free_udp_port()
    path = tmp_path / "rig.yaml"
    path.write_text(CONFIG.format(port=port))
    bridge = Bridge(load_config(path), config_path=path, log_dir=False).start()
    bystander = open_connection(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190)
    requester = open_connection(f"udpout:127.0.0.1:{port}", source_system=66, source_component=190)
    try:
        for conn in (bystander, requester):
            conn.mav.heartbeat_send(6, 8, 0, 0, 4)
        time.sleep(0.5)
        opened = request(ftp.OP_OPEN_FILE_RO, data=b"/parameters.json.xz")
        requester.mav.file_transfer_protocol_send(0, 1, 140, list(opened))
        replies = []
        for _ in range(30):  # bounded: 3 s
            msg = requester.recv_match(type="FILE_TRANSFER_PROTOCOL", blocking=True, timeout=0.1)
            if msg is not None:
                replies.append(msg)
                break
        assert replies, "the requester got no reply"
        burst = request(ftp.OP_BURST_READ_FILE, seq=2, session=0, size=239)
        requester.mav.file_transfer_protocol_send(0, 1, 140, list(burst))
        seen = 0
        for _ in range(20):  # bounded: 2 s
            msg = bystander.recv_match(type="FILE_TRANSFER_PROTOCOL", blocking=True, timeout=0.1)
            seen += msg is not None
        assert seen == 0
    finally:
        bystander.close()
        requester.close()
        bridge.stop()
