"""MAVLink FTP as the clients nobody here wrote expect it (issue 38, item 1).

The CRC is ArduPilot's ``crc_crc32(0, data)`` (libraries/AP_Math/crc.cpp), the value MAVSDK
compares in ``are_files_identical``; the reference below is computed bit by bit from the
algorithm as published (reflected polynomial 0xEDB88320, register starting at 0, no final
XOR) and by ``crcmod`` with the same parameters, never from the project's function. Then the
server's behaviour with clients that retry: the same sequence number answered once, a retry
with a new number replacing the stale reply, and 64 strangers' refusals never ahead of a ground
station's read.
"""

from __future__ import annotations

import json
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mavservo.app.component_metadata import metadata_files
from mavservo.config.loader import load_config
from mavservo.mavlink import ftp
from mavservo.mavlink.ftp import FtpServer, crc32
from mavservo.mavlink.metadata_service import MetadataService
from tests.mavlink.test_ftp_metadata import parse as _parse
from tests.mavlink.test_ftp_metadata import request as _request
from tests.support.paths import REPO

GCS = (255, 190)
FILES = {"general.json": b'{"version": 1}', "parameters.json.xz": bytes(range(256)) * 3}


def ardupilot_crc32(data: bytes) -> int:
    """CRC-32 as libraries/AP_Math/crc.cpp's ``crc_crc32`` computes it, called with 0 as
    ``AP_Filesystem::crc32`` does, written bit by bit from the description (reflected
    polynomial 0xEDB88320, no final XOR) rather than from a table."""
    register = 0
    for byte in data:
        register ^= byte
        for _ in range(8):
            register = (register >> 1) ^ (0xEDB88320 if register & 1 else 0)
    return register


#: Reference vectors: fixed byte strings and their CRC with the register starting at 0 and no
#: final XOR (0x2DFD2D88 for "123456789"; zlib's CRC-32 of it is the catalogue's 0xCBF43926).
VECTORS = [(b"", 0), (b"123456789", 0x2DFD2D88), (b"\x00", 0), (b"a", 0x3AB551CE)]


@pytest.mark.parametrize(("data", "expected"), VECTORS)
def test_the_crc_is_ardupilots_on_reference_vectors(data: bytes, expected: int) -> None:
    assert ardupilot_crc32(data) == expected
    assert crc32(data) == expected


def test_an_independent_crc_library_agrees() -> None:
    crcmod = pytest.importorskip("crcmod")
    # crcmod: polynomial with its x^32 term, reflected, initial value 0, no final XOR
    reference = crcmod.mkCrcFun(0x104C11DB7, initCrc=0, rev=True, xorOut=0)
    for data, expected in VECTORS:
        assert reference(data) == expected


@given(st.binary(max_size=2048))
def test_the_crc_equals_the_bitwise_reference_on_any_bytes(data: bytes) -> None:
    assert crc32(data) == ardupilot_crc32(data)


def test_every_served_file_and_component_metadata_carry_ardupilots_crc() -> None:
    """The shipped simulation config's files: CalcFileCRC32, COMPONENT_METADATA.file_crc and the
    general file's ``fileCrc`` all equal the reference (zlib's value, sent before, did not)."""
    config = load_config(REPO / "config" / "sim.yaml")
    files = metadata_files(config)
    service = MetadataService(files, files, bytes_per_s=1e6, boot_time=0.0)
    for cid, served in files.items():
        server = service.servers[cid]
        for name, content in served.items():
            server.handle(_request(ftp.OP_CALC_FILE_CRC32, data=name.encode()), GCS, 0.0)
            ((_to, payload),) = server.periodic(0.0)
            assert int.from_bytes(_parse(payload)[7], "little") == ardupilot_crc32(content)
        general = served["general.json"]
        message = service.component_metadata(cid, 0.0)
        assert message is not None and message.file_crc == ardupilot_crc32(general)
        (entry,) = json.loads(general)["metadataTypes"]
        assert entry["fileCrc"] == ardupilot_crc32(served["parameters.json.xz"])


# ------------------------------------------------------------------------------ retries


def test_a_request_repeated_with_its_sequence_number_is_answered_once() -> None:
    """While its reply waits, a repeat adds nothing; once it went, the same reply goes again
    (ArduPilot's GCS_FTP re-sends its last reply), never a second queued copy."""
    server = FtpServer(FILES)
    server.handle(_request(ftp.OP_OPEN_FILE_RO, seq=7, data=b"general.json"), GCS, 0.0)
    server.handle(_request(ftp.OP_OPEN_FILE_RO, seq=7, data=b"general.json"), GCS, 0.1)
    server.handle(_request(ftp.OP_OPEN_FILE_RO, seq=7, data=b"general.json"), GCS, 0.2)
    (first,) = server.periodic(0.3)
    assert server.stats()["sessions"] == 1
    server.handle(_request(ftp.OP_OPEN_FILE_RO, seq=7, data=b"general.json"), GCS, 1.5)
    (again,) = server.periodic(1.5)
    assert again == first and server.stats()["sessions"] == 1  # no second session opened
    session = _parse(first[1])[1]
    for _ in range(4):  # a read asked four times before its reply went: one reply
        server.handle(_request(ftp.OP_READ_FILE, seq=9, session=session, size=239), GCS, 2.0)
    assert [_parse(p)[:3] for _to, p in server.periodic(2.0)] == [(10, session, ftp.OP_ACK)]


def test_a_retry_with_a_new_sequence_number_replaces_the_stale_reply() -> None:
    """MAVSDK and QGroundControl retry with a new number and take only the reply carrying it:
    the old reply still queued is dropped, not sent ahead of the one the client waits for."""
    server = FtpServer(FILES, bytes_per_s=1.0)  # a window that lets one frame out
    server.handle(_request(ftp.OP_OPEN_FILE_RO, seq=1, data=b"parameters.json.xz"), GCS, 0.0)
    (opened,) = server.periodic(0.0)
    session = _parse(opened[1])[1]
    for seq in (3, 5, 7, 9):  # the reply to each waits for the window; the client retries
        read = _request(ftp.OP_READ_FILE, seq=seq, session=session, size=239, offset=0)
        server.handle(read, GCS, 0.1 * seq)
    assert server.queued_for(GCS) == 1
    (reply,) = server.periodic(2.0)
    assert _parse(reply[1])[0] == 10  # the newest request's reply
    assert server.counters["stale_dropped"] == 3


def test_ending_a_session_drops_the_replies_waiting_for_it() -> None:
    server = FtpServer(FILES, bytes_per_s=1.0)
    server.handle(_request(ftp.OP_OPEN_FILE_RO, seq=1, data=b"parameters.json.xz"), GCS, 0.0)
    session = _parse(server.periodic(0.0)[0][1])[1]
    server.handle(_request(ftp.OP_READ_FILE, seq=3, session=session, size=239), GCS, 0.1)
    server.handle(_request(ftp.OP_TERMINATE_SESSION, seq=5, session=session), GCS, 0.2)
    (reply,) = server.periodic(2.0)
    assert _parse(reply[1])[4] == ftp.OP_TERMINATE_SESSION and server.queued_for(GCS) == 0


def test_strangers_refusals_never_go_before_a_ground_stations_read() -> None:
    """64 spoofed senders open sessions as fast as they like: every session is taken, each
    gets NoSessionsAvailable; the ground station's reads (its session was open before) go
    first, one reply per admitted slot, whatever the strangers queued."""
    service = MetadataService([140], {140: FILES}, bytes_per_s=1e6, boot_time=0.0)
    server = service.servers[140]
    server.handle(_request(ftp.OP_OPEN_FILE_RO, seq=1, data=b"parameters.json.xz"), GCS, 0.0)
    session = _parse(server.periodic(0.0)[0][1])[1]
    strangers = [(10 + n, 190) for n in range(64)]
    offset, now = 0, 0.0
    for round_ in range(4):
        for n, stranger in enumerate(strangers):
            opened = _request(ftp.OP_OPEN_FILE_RO, seq=round_, data=b"general.json")
            server.handle(opened, stranger, now + n * 1e-4)
        now += 0.1
        read = _request(
            ftp.OP_READ_FILE, seq=2 * round_ + 3, session=session, size=239, offset=offset
        )
        server.handle(read, GCS, now)
        one = [True]  # the link takes one reply at this tick

        def admit(_cid: int, _msg: Any, _awaited: bool, one: list[bool] = one) -> bool:
            return one.pop() if one else False

        (answer,) = service.due(now, admit)
        assert answer.to == GCS
        offset += _parse(bytes(answer.msg.payload))[3]
    assert offset == min(4 * 239, len(FILES["parameters.json.xz"]))
    assert server.stats()["queued"] <= ftp.MAX_QUEUED


def test_a_burst_goes_one_packet_per_admission_and_stays_inside_it() -> None:
    """Burst packets are made when the link takes them: a refusal stops the burst, nothing is
    queued for later at once (before, a burst could be queued whole)."""
    server = FtpServer(FILES)
    server.handle(_request(ftp.OP_OPEN_FILE_RO, seq=1, data=b"parameters.json.xz"), GCS, 0.0)
    session = _parse(server.periodic(0.0)[0][1])[1]
    server.handle(_request(ftp.OP_BURST_READ_FILE, seq=3, session=session, size=239), GCS, 0.0)
    allowed = [True, True]
    got = server.due(0.1, lambda _p, _a: allowed.pop() if allowed else False)
    assert len(got) == 2 and server.queued() == 0
    rest = server.periodic(0.2)
    data = b"".join(_parse(p)[7] for _to, p in got + rest)
    assert data == FILES["parameters.json.xz"]


def test_on_a_slow_link_read_replies_carry_fewer_bytes_than_asked() -> None:
    """At the default 1,000 B/s a reply carries 123 data bytes (a 150-byte frame, ~0.4 s of
    the answers' tokens) instead of 239; the reply's size says so and the next read asks on
    from there, as the clients do (ArduPilot sends 48 on a busy link)."""
    assert ftp.chunk_for_budget(1000.0) == 123
    assert ftp.chunk_for_budget(None) == ftp.chunk_for_budget(1e6) == ftp.MAX_DATA
    assert ftp.chunk_for_budget(100.0) == ftp.MIN_CHUNK
    server = FtpServer(FILES, chunk_bytes=ftp.chunk_for_budget(1000.0))
    server.handle(_request(ftp.OP_OPEN_FILE_RO, seq=1, data=b"parameters.json.xz"), GCS, 0.0)
    session = _parse(server.periodic(0.0)[0][1])[1]
    server.handle(_request(ftp.OP_READ_FILE, seq=3, session=session, size=239), GCS, 0.0)
    ((_to, reply),) = server.periodic(0.0)
    assert _parse(reply)[3] == 123 and ftp.frame_bytes(reply) == 150
    server.handle(_request(ftp.OP_BURST_READ_FILE, seq=5, session=session, size=239), GCS, 0.0)
    sizes = [_parse(p)[3] for _to, p in server.periodic(0.0)]
    assert sum(sizes) == len(FILES["parameters.json.xz"]) and max(sizes) == 123


@pytest.mark.parametrize("starts_at", [1.0, 5.0], ids=["early-in-the-attack", "under-way"])
def test_a_ground_station_downloads_while_64_spoofed_ids_open_sessions(starts_at: float) -> None:
    """On a simulated clock and link (432 B/s for answers, the default budget's share): 64
    spoofed ids each open a session once a second and never read; a ground station opens
    parameters metadata and burst-reads it as QGroundControl does, with its 1,000 ms time-out.
    Every reply it waits for comes within 1 s, and the file arrives whole. Before: the queue
    was one FIFO shared with the strangers' NAKs (239-478 B in 50 s, issue 38); then the
    strangers' opens won every idle session and their ACKs took 16 of 17 turns."""
    content = bytes(range(256)) * 7
    server = FtpServer({"general.json": b"x" * 229, "p.xz": content}, chunk_bytes=123)
    spoofed = [(100 + n, 190) for n in range(64)]
    tokens, seq, session, offset, asked_at = 0.0, 0, None, 0, None
    waits: list[float] = []

    def gcs(opcode: int, now: float, **fields: Any) -> None:
        nonlocal seq, asked_at
        seq += 2
        asked_at = now
        server.handle(_request(opcode, seq=seq, **fields), GCS, now)

    def admit(payload: bytes, _awaited: bool) -> bool:
        nonlocal tokens
        cost = ftp.frame_bytes(payload)
        if tokens < cost:
            return False
        tokens -= cost
        return True

    for step in range(2000):  # 20 s of 10 ms ticks
        now = step * 0.01
        if step % 100 < 64:
            opened = _request(ftp.OP_OPEN_FILE_RO, seq=step, data=b"/general.json")
            server.handle(opened, spoofed[step % 100], now)
        if abs(now - starts_at) < 1e-9:
            gcs(ftp.OP_OPEN_FILE_RO, now, data=b"/p.xz")
        tokens = min(tokens + 4.32, 300.0)
        for to, payload in server.due(now, admit):
            if to != GCS:
                continue
            _seq, number, opcode, size, req, complete, at, _data = _parse(payload)
            assert asked_at is not None
            waits.append(now - asked_at)
            asked_at = now
            assert opcode == ftp.OP_ACK, _parse(payload)
            if req == ftp.OP_OPEN_FILE_RO:
                session = number
                gcs(ftp.OP_BURST_READ_FILE, now, session=session, size=239)
            elif req == ftp.OP_BURST_READ_FILE and at == offset:
                offset += size
                if offset < len(content) and complete:
                    gcs(ftp.OP_BURST_READ_FILE, now, session=session, size=239, offset=offset)
        if offset >= len(content):
            break
    assert offset == len(content)
    assert max(waits) < 1.0, max(waits)
    assert server.counters["squatter_refused"] > 0
