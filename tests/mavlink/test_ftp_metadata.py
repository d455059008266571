"""Parameter metadata for ground stations: COMPONENT_METADATA and a read-only MAVLink FTP server.

What QGroundControl does with a component: ask it for COMPONENT_METADATA (397), read the
general metadata file at its URI over MAVLink FTP, then the parameter metadata file listed
there. A real FTP client (pymavlink's ``mavftp``) does the same against a running bridge here,
and the files validate against MAVLink's component-metadata schemas (tests/data). The server
itself is then attacked: any opcode, size, offset, session, path, sender.
"""

from __future__ import annotations

import json
import logging
import lzma
import time
from pathlib import Path
from typing import Any

import jsonschema
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mavservo.app.bridge import Bridge
from mavservo.config.loader import load_config
from mavservo.mavlink import ftp
from mavservo.mavlink.connection import open_connection
from mavservo.mavlink.ftp import FtpServer, crc32
from tests.support.paths import TEST_DATA
from tests.support.waiting import free_udp_port, wait_until
from tests.support.wip_dialect import decode

SCHEMAS = TEST_DATA / "component_metadata"
GCS = (255, 190)
FILES = {"general.json": b'{"version": 1}', "parameters.json.xz": bytes(range(256)) * 3}

CONFIG = """\
mavlink:
  url: udpin:127.0.0.1:{port}
  link_budget_bytes_s: 40000
servos:
  - {{name: aileron, profile: rmd-x, can_id: 1, limits_deg: [-30, 30]}}
  - {{name: pan, profile: rmd-x, can_id: 2}}
  - {{name: tilt, profile: rmd-x, can_id: 3}}
channels:
  - {{source: servo_output, channel: 1, servo: aileron}}
gimbals:
  - {{name: cam, component_id: 154, yaw: pan, pitch: tilt}}
"""


def schema(name: str) -> dict[str, Any]:
    return json.loads((SCHEMAS / f"{name}.schema.json").read_text())


def request(
    opcode: int, *, seq: int = 1, session: int = 0, size: int = 0, offset: int = 0, data=b""
) -> bytes:
    header = ftp.HEADER.pack(seq, session, opcode, size or len(data), 0, 0, 0, offset)
    return (header + data).ljust(ftp.PAYLOAD_BYTES, b"\x00")


def parse(payload: bytes) -> tuple[Any, ...]:
    seq, session, opcode, size, req, burst, _pad, offset = ftp.HEADER.unpack_from(payload)
    return seq, session, opcode, size, req, burst, offset, payload[12 : 12 + size]


def answers(server: FtpServer, now: float = 0.0) -> list[tuple[Any, ...]]:
    return [parse(p) for _sender, p in server.periodic(now)]


# ------------------------------------------------------------------------------ the server


def test_open_read_burst_list_crc_and_terminate_serve_only_the_files() -> None:
    server = FtpServer(FILES)
    server.handle(request(ftp.OP_OPEN_FILE_RO, seq=4, data=b"/parameters.json.xz"), GCS, 0.0)
    ((seq, session, opcode, size, req, _b, _o, data),) = answers(server)
    assert (seq, opcode, req, size) == (5, ftp.OP_ACK, ftp.OP_OPEN_FILE_RO, 4)
    assert int.from_bytes(data, "little") == len(FILES["parameters.json.xz"])

    server.handle(request(ftp.OP_READ_FILE, seq=6, session=session, size=100, offset=700), GCS, 0)
    ((_s, _ss, opcode, size, _r, _b, offset, data),) = answers(server)
    assert (opcode, offset, data) == (ftp.OP_ACK, 700, FILES["parameters.json.xz"][700:768])

    server.handle(request(ftp.OP_BURST_READ_FILE, seq=8, session=session, size=239), GCS, 0)
    got = b"".join(a[7] for a in answers(server, 0.0))
    assert got == FILES["parameters.json.xz"]

    server.handle(request(ftp.OP_LIST_DIRECTORY, seq=10, data=b"/"), GCS, 0)
    ((_s, _ss, opcode, _size, _r, _b, _o, data),) = answers(server)
    assert data.split(b"\x00")[:-1] == [b"Fgeneral.json\t14", b"Fparameters.json.xz\t768"]
    server.handle(request(ftp.OP_LIST_DIRECTORY, seq=12, offset=2, data=b"/"), GCS, 0)
    assert [(a[2], a[7]) for a in answers(server)] == [(ftp.OP_NAK, bytes([ftp.ERR_EOF]))]

    server.handle(request(ftp.OP_CALC_FILE_CRC32, data=b"general.json"), GCS, 0)
    ((*_, data),) = answers(server)
    assert int.from_bytes(data, "little") == crc32(FILES["general.json"])

    server.handle(request(ftp.OP_TERMINATE_SESSION, session=session), GCS, 0)
    server.handle(request(ftp.OP_READ_FILE, session=session, size=10), GCS, 0)
    assert [a[2] for a in answers(server)] == [ftp.OP_ACK, ftp.OP_NAK]


@pytest.mark.parametrize(
    "path",
    [b"/etc/passwd", b"../../etc/passwd", b"/general.json/..", b"@PARAM/param.pck", b"/\xff", b""],
)
def test_nothing_else_is_reachable(path: bytes) -> None:
    server = FtpServer(FILES)
    server.handle(request(ftp.OP_OPEN_FILE_RO, data=path), GCS, 0.0)
    assert [(a[2], a[7]) for a in answers(server)] == [
        (ftp.OP_NAK, bytes([ftp.ERR_FILE_NOT_FOUND]))
    ]


def test_writes_are_refused_and_sessions_belong_to_their_opener() -> None:
    server = FtpServer(FILES)
    for opcode in sorted(ftp.WRITE_OPS):
        server.handle(request(opcode, data=b"general.json"), GCS, 0.0)
    assert {(a[2], a[7]) for a in answers(server)} == {
        (ftp.OP_NAK, bytes([ftp.ERR_FILE_PROTECTED]))
    }
    server.handle(request(ftp.OP_OPEN_FILE_RO, data=b"general.json"), GCS, 0.0)
    ((_s, session, *_),) = answers(server)
    stranger = (7, 1)
    server.handle(request(ftp.OP_READ_FILE, session=session, size=10), stranger, 0.0)
    server.handle(request(ftp.OP_TERMINATE_SESSION, session=session), stranger, 0.0)
    server.handle(request(ftp.OP_RESET_SESSIONS), stranger, 0.0)  # resets the stranger's only
    server.handle(request(ftp.OP_READ_FILE, session=session, size=4), GCS, 0.0)
    replies = [(to, parse(p)) for to, p in server.periodic(0.0)]
    # the ground station's read makes progress: it goes before the stranger's refusals
    (to, first), *rest = replies
    assert to == GCS and first[2] == ftp.OP_ACK and first[7] == FILES["general.json"][:4]
    refused = [(a[2], a[7][:1]) for to, a in rest if a[4] != ftp.OP_RESET_SESSIONS]
    assert refused == [(ftp.OP_NAK, bytes([ftp.ERR_INVALID_SESSION]))] * 2


def test_sessions_are_bounded_and_expire() -> None:
    server = FtpServer(FILES)
    for system in range(1, 10):
        for seq in range(3):
            opened = request(ftp.OP_OPEN_FILE_RO, seq=seq, data=b"general.json")
            server.handle(opened, (system, 1), 0.0)
            answers(server)
    assert server.stats()["sessions"] == ftp.MAX_SESSIONS
    assert server.counters["no_session"] == 27 - ftp.MAX_SESSIONS
    server.handle(request(ftp.OP_NONE), GCS, ftp.SESSION_IDLE_S + 1)
    assert server.stats()["sessions"] == 0


def test_answers_stay_within_their_byte_rate() -> None:
    """A client asking as fast as it can: no 1-second window carries more than the rate (or one
    frame, the smallest unit that can go), and every byte still arrives."""
    rate = 600.0
    content = bytes(range(256)) * 20
    server = FtpServer({"big.bin": content}, bytes_per_s=rate)
    server.handle(request(ftp.OP_OPEN_FILE_RO, data=b"big.bin"), GCS, 0.0)
    sent: list[tuple[float, int]] = []
    got = b""
    for step in range(4000):  # 40 s of 10 ms ticks, bounded
        now = step * 0.01
        for _sender, payload in server.periodic(now):
            sent.append((now, ftp.frame_bytes(payload)))
            reply = parse(payload)
            if reply[4] == ftp.OP_BURST_READ_FILE and reply[2] == ftp.OP_ACK:
                got += reply[7]
                if reply[5]:  # burst complete: the client asks for the next one
                    next_offset = reply[6] + reply[3]
                    server.handle(
                        request(ftp.OP_BURST_READ_FILE, size=239, offset=next_offset), GCS, now
                    )
            elif reply[4] == ftp.OP_OPEN_FILE_RO:
                server.handle(request(ftp.OP_BURST_READ_FILE, size=239), GCS, now)
        if len(got) >= len(content):
            break
    assert got == content
    frame = ftp.frame_bytes(bytes(ftp.PAYLOAD_BYTES * [1]))
    for start, _ in sent:
        window = sum(size for t, size in sent if start <= t < start + 1.0)
        assert window <= max(rate, frame), (start, window)
    span = sent[-1][0] - sent[0][0]
    assert sum(size for _, size in sent) <= rate * span + 2 * frame


@settings(max_examples=300, deadline=None)
@given(
    requests=st.lists(
        st.tuples(
            st.one_of(
                st.binary(max_size=260),
                st.builds(
                    request,
                    st.integers(0, 255),
                    seq=st.integers(0, 0xFFFF),
                    session=st.integers(0, 255),
                    size=st.integers(0, 255),
                    offset=st.integers(0, 2**32 - 1),
                    data=st.one_of(
                        st.sampled_from([b"general.json", b"/parameters.json.xz", b"/"]),
                        st.binary(max_size=239),
                    ),
                ),
            ),
            st.tuples(st.integers(0, 255), st.integers(0, 255)),
            st.floats(0, 0.5),
        ),
        max_size=40,
    )
)
def test_hostile_requests_get_bounded_answers(
    requests: list[tuple[bytes, tuple[int, int], float]],
) -> None:
    server = FtpServer(FILES, bytes_per_s=2000)
    now = 0.0
    for payload, sender, dt in requests:
        now += dt
        server.handle(payload, sender, now)
        assert server.stats()["sessions"] <= ftp.MAX_SESSIONS
        assert server.stats()["queued"] <= ftp.MAX_QUEUED
        for _to, reply in server.periodic(now):
            assert len(reply) == ftp.PAYLOAD_BYTES
            _seq, _session, opcode, size, _req, _burst, offset, data = parse(reply)
            assert opcode in (ftp.OP_ACK, ftp.OP_NAK) and size <= ftp.MAX_DATA
            if opcode == ftp.OP_NAK:
                assert size == 1
            elif _req in (ftp.OP_READ_FILE, ftp.OP_BURST_READ_FILE):
                assert any(body[offset : offset + size] == data for body in FILES.values())


# ------------------------------------------------------------------------------ end to end


def test_a_real_ftp_client_reads_the_metadata_component_metadata_points_at(
    tmp_path: Path,
) -> None:
    from pymavlink.mavftp import MAVFTP

    port = free_udp_port()
    path = tmp_path / "rig.yaml"
    path.write_text(CONFIG.format(port=port))
    bridge = Bridge(load_config(path), config_path=path, log_dir=False).start()
    conn = open_connection(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190)
    try:
        for component in (140, 154):
            general, uri = _component_metadata(conn, component)
            assert uri == f"mftp://[;comp={component}]/general.json"
            client = MAVFTP(conn, 1, component)
            general_path = "/" + uri.split("]/", 1)[1]  # the file the message points at
            assert client.cmd_get([general_path, str(tmp_path / "general.json")]).error_code == 0
            result = client.process_ftp_reply("OpenFileRO", timeout=20)
            assert result.error_code == 0, result
            body = (tmp_path / "general.json").read_bytes()
            assert crc32(body) == general.file_crc
            meta = json.loads(body)
            jsonschema.validate(meta, schema("general"))
            (entry,) = meta["metadataTypes"]
            assert entry["type"] == 1 and entry["uri"].startswith(f"mftp://[;comp={component}]/")
            remote = "/" + entry["uri"].split("]/", 1)[1]
            local = tmp_path / "parameters.json.xz"
            client = MAVFTP(conn, 1, component)  # a new transfer, as a GCS's FTP manager does
            assert client.cmd_get([remote, str(local)]).error_code == 0
            assert client.process_ftp_reply("OpenFileRO", timeout=20).error_code == 0
            assert crc32(local.read_bytes()) == entry["fileCrc"]
            parameters = json.loads(lzma.decompress(local.read_bytes()))
            jsonschema.validate(parameters, schema("parameter"))
            # the metadata describes exactly what the component serves by PARAM_REQUEST_LIST
            assert bridge.parameters is not None
            served = bridge.parameters.names(component)
            assert [p["name"] for p in parameters["parameters"]] == served and served
        stats = bridge.mavlink.stats()["ftp"]
        assert stats["140"]["opened"] >= 2 and stats["154"]["opened"] >= 2
    finally:
        conn.close()
        bridge.stop()


def _component_metadata(conn: Any, component: int) -> tuple[Any, str]:
    """MAV_CMD_REQUEST_MESSAGE(397) to ``component``; the answer, decoded with the dialect
    generated from MAVLink's XML (pymavlink's bundled one does not know message 397)."""
    found: list[Any] = []

    def arrived() -> bool:
        conn.mav.command_long_send(1, component, 512, 0, 397, 0, 0, 0, 0, 0, 0)
        deadline = time.monotonic() + 0.5
        while time.monotonic() < deadline:
            msg = conn.recv_match(blocking=True, timeout=0.1)
            if msg is not None and msg.get_type() == "UNKNOWN_397":
                # pymavlink fills no header into an unknown message: the decoded one has it
                decoded = decode(msg.get_msgbuf())
                if decoded and decoded[0].get_srcComponent() == component:
                    found.extend(decoded)
                    return True
        return False

    assert wait_until(arrived, 10.0), "no COMPONENT_METADATA"
    (message,) = found
    uri = message.uri if isinstance(message.uri, str) else message.uri.decode()
    return message, uri.rstrip("\x00")


logging.getLogger("pymavlink").setLevel(logging.WARNING)


# ------------------------------------------------------------------------------ the core


def _core(**settings: Any) -> Any:
    from mavservo.mavlink.mavlink_core import MavlinkCore
    from mavservo.mavlink.settings import MavlinkSettings
    from tests.support.mavlink_doubles import RecordingBackend

    files = {140: {"general.json": b"{}"}}
    core = MavlinkCore(
        MavlinkSettings(system_id=1, link_budget_bytes_s=None, **settings),
        RecordingBackend(),
        boot_time=0.0,
        metadata_files=files,
    )
    return core


def _ftp_message(target_component: int) -> Any:
    from mavservo.mavlink.connection import mavlink2
    from tests.support.mavlink_doubles import wire

    payload = list(request(ftp.OP_OPEN_FILE_RO, data=b"general.json"))
    return wire(
        mavlink2.MAVLink_file_transfer_protocol_message(0, 1, target_component, payload), GCS
    )


def _ftp_out(core: Any, now: float) -> list[tuple[int, Any]]:
    """What one tick sends: its output and the answers due (FTP replies are answers)."""
    out = core.tick(now)
    return [*out, *((a.component_id, a.msg) for a in core.answers_due(now))]


def test_the_core_answers_the_addressed_component_only_never_a_broadcast() -> None:
    core = _core()
    assert core.on_message(_ftp_message(0), 0.0) == []  # broadcast: nobody answers
    assert [m for _cid, m in _ftp_out(core, 0.01) if m.get_type() == "FILE_TRANSFER_PROTOCOL"] == []
    core.on_message(_ftp_message(140), 0.02)
    replies = [
        (cid, m) for cid, m in _ftp_out(core, 0.03) if m.get_type() == "FILE_TRANSFER_PROTOCOL"
    ]
    assert [(cid, parse(bytes(m.payload))[2]) for cid, m in replies] == [(140, ftp.OP_ACK)]
    assert (replies[0][1].target_system, replies[0][1].target_component) == GCS


def test_on_a_signed_link_unsigned_ftp_gets_no_answer() -> None:
    from mavservo.mavlink.settings import SigningSettings

    core = _core(signing=SigningSettings(key=bytes(32), accept_unsigned=True))
    core.on_message(_ftp_message(140), 0.0)  # unsigned (wire() does not sign)
    assert [m for _cid, m in _ftp_out(core, 0.01) if m.get_type() == "FILE_TRANSFER_PROTOCOL"] == []
    assert core.counters["ftp_unsigned_refused"] == 1


def test_a_burst_ending_on_a_full_packet_gets_an_eof_at_its_offset() -> None:
    """A file of exactly two packets: the second is full and ends the burst, the client asks
    on from the end and must get EOF carrying that offset (pymavlink matches it by offset)."""
    content = bytes(range(239)) * 2
    server = FtpServer({"f.bin": content})
    server.handle(request(ftp.OP_OPEN_FILE_RO, data=b"f.bin"), GCS, 0.0)
    answers(server)
    server.handle(request(ftp.OP_BURST_READ_FILE, seq=10, size=239), GCS, 0.0)
    packets = answers(server)
    assert [(p[3], p[5]) for p in packets] == [(239, 0), (239, 1)]
    assert [p[0] for p in packets] == [11, 12]  # the burst's own advancing sequence
    server.handle(request(ftp.OP_BURST_READ_FILE, seq=13, size=239, offset=478), GCS, 0.0)
    ((seq, _s, opcode, _size, req, _b, offset, data),) = answers(server)
    assert (seq, opcode, req, offset, data) == (14, ftp.OP_NAK, 15, 478, bytes([ftp.ERR_EOF]))


def test_every_components_answers_share_one_byte_window() -> None:
    """The servo and a gimbal component answer on one link: both transfers together stay in
    the share, not twice it."""
    from mavservo.mavlink.metadata_service import MetadataService

    content = bytes(range(256)) * 8
    service = MetadataService(
        [140, 154], {140: {"a": content}, 154: {"a": content}}, bytes_per_s=600, boot_time=0.0
    )
    for cid in (140, 154):
        service.servers[cid].handle(request(ftp.OP_OPEN_FILE_RO, data=b"a"), GCS, 0.0)
    sent: list[tuple[float, int]] = []
    for step in range(1000):  # 10 s of 10 ms ticks
        now = step * 0.01
        for cid, msg in service.periodic(now):
            payload = bytes(msg.payload)
            sent.append((now, ftp.frame_bytes(payload)))
            reply = parse(payload)
            if reply[4] == ftp.OP_OPEN_FILE_RO or (reply[4] == ftp.OP_BURST_READ_FILE and reply[5]):
                offset = 0 if reply[4] == ftp.OP_OPEN_FILE_RO else reply[6] + reply[3]
                service.servers[cid].handle(
                    request(ftp.OP_BURST_READ_FILE, size=239, offset=offset), GCS, now
                )
    assert {cid for cid in (140, 154) if service.servers[cid].counters["burst_bytes"]} == {140, 154}
    frame = ftp.frame_bytes(bytes([1]) * ftp.PAYLOAD_BYTES)
    for start, _ in sent:
        assert sum(size for t, size in sent if start <= t < start + 1.0) <= max(600, frame)


def test_a_repeated_component_metadata_request_is_answered_again() -> None:
    """The answer was lost on the radio: the GCS asks again and must get the message, not only
    another ACK (the command retry rule applies to commands that act, not to requests)."""
    from tests.support.mavlink_doubles import command_long, wire

    core = _core()
    request_397 = wire(command_long((1, 140), 512, 397), GCS)
    for at in (0.0, 0.2):
        out = core.on_message(request_397, at)
        kinds = [m.get_type() for _cid, m in out]
        assert kinds == ["COMMAND_ACK", "COMPONENT_METADATA"], kinds
