"""Issue 32: no stranger reconfigures the aircraft. Each test replays a finding of the attack run
against a real bridge on UDP (127.0.0.1) with pymavlink peers, and fails on c3ae82c.

Findings covered here: 1 (the YAML is the envelope; only verified senders write), 6 (state
directory, overlay ownership and permissions, overflow, dangling symlink, float32 ranges,
param_type).
"""

from __future__ import annotations

import io
import os
import struct
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from mavservo.app.bridge import Bridge
from mavservo.app.check import check_main
from mavservo.config.loader import ConfigError
from mavservo.config.overlay import load_config_with_overlay, overlay_path
from mavservo.mavlink.connection import mavlink2
from tests.support.bridge import Peer
from tests.support.waiting import free_udp_port, wait_until

CONFIG = """\
mavlink:
  url: udpin:127.0.0.1:{port}
{extra}servos:
  - name: aileron
    profile: rmd-x
    can_id: 1
    limits_deg: [-30, 30]
  - name: throttle
    profile: rmd-x
    can_id: 3
    limits_deg: [0, 90]
    failsafe: {{action: position, position_deg: 0, timeout_s: 0.5}}
channels:
  - {{source: servo_output, channel: 1, servo: aileron}}
  - {{source: servo_output, channel: 3, servo: throttle, input: {{min: 1000, max: 2000}}}}
"""
OPEN = "  parameter_writers: anyone\n"
#: the ground station peer (255/190) as an allowed source: it may write
WRITER = "  allowed_sources: [{system: 255, component: 190}]\n"


def write_config(tmp_path: Path, port: int, extra: str = "") -> Path:
    path = tmp_path / "rig.yaml"
    path.write_text(CONFIG.format(port=port, extra=extra))
    return path


@contextmanager
def running(path: Path) -> Iterator[tuple[Bridge, Peer]]:
    """The bridge as ``mavservo run --config PATH`` builds it, and a peer at 255/190."""
    loaded = load_config_with_overlay(path)
    bridge = Bridge(
        loaded.config,
        config_path=path,
        log_dir=False,
        parameter_base=loaded.base,
        overlay=loaded.overlay,
    ).start()
    peer = Peer(int(str(loaded.config.mavlink.url).rsplit(":", 1)[1]))
    try:
        yield bridge, peer
    finally:
        peer.close()
        bridge.stop()


def answer(peer: Peer, start: int, name: str, kind: str = "PARAM_VALUE") -> Any:
    """The first ``kind`` message for ``name`` that arrived since ``start`` (None: none). A
    refused set gets PARAM_ERROR first, then the PARAM_VALUE in force (older clients)."""
    found: list[Any] = []

    def arrived() -> bool:
        found[:] = [m for m in peer.since(start) if m.get_type() == kind and m.param_id == name]
        return bool(found)

    return found[0] if wait_until(arrived, 3.0) else None


def set_param(
    peer: Peer, name: str, value: float, param_type: int = 9, kind: str = "PARAM_VALUE", **src: int
) -> Any:
    start = peer.count()
    peer.send(mavlink2.MAVLink_param_set_message(1, 140, name.encode(), value, param_type), **src)
    return answer(peer, start, name, kind)


# ------------------------------------------------------------------ 1: envelope, who may write


def test_a_stranger_on_an_unsigned_link_cannot_set_parameters(tmp_path: Path) -> None:
    with running(write_config(tmp_path, free_udp_port())) as (bridge, peer):
        reply = set_param(peer, "SRV1_MAX", 20.0, kind="PARAM_ERROR")
        assert reply is not None and reply.error == mavlink2.MAV_PARAM_ERROR_PERMISSION_DENIED
        assert bridge.parameters is not None and bridge.parameters.value("SRV1_MAX") == 30.0
        assert bridge.mavlink.stats()["parameters"]["set_not_permitted"] == 1
        # reading stays open: a ground station lists before it can sign anything
        start = peer.count()
        peer.send(mavlink2.MAVLink_param_request_read_message(1, 140, b"SRV1_MAX", -1))
        read = answer(peer, start, "SRV1_MAX")
        assert read is not None and read.param_value == 30.0
    assert not overlay_path(tmp_path / "rig.yaml").exists()


def test_no_parameter_leaves_the_yaml_envelope_even_for_a_permitted_writer(tmp_path: Path) -> None:
    with running(write_config(tmp_path, free_udp_port(), WRITER)) as (bridge, peer):
        for name, value in (("SRV1_MAX", 36000.0), ("SRV1_MIN", -31.0), ("SRV2_FS_POS", 91.0)):
            start = peer.count()
            reply = set_param(peer, name, value)
            assert reply is not None and reply.param_value != value, name  # the value in force
            error = answer(peer, start, name, "PARAM_ERROR")  # and why, before it
            assert (
                error is not None and error.error == mavlink2.MAV_PARAM_ERROR_VALUE_OUT_OF_RANGE
            ), name
            assert wait_until(lambda s=start: any("refused" in t for t in peer.statustexts(s)))
        narrowed = set_param(peer, "SRV1_MAX", 20.0)  # narrowing is allowed
        assert narrowed is not None and narrowed.param_value == 20.0
        # and back out to the file's value, never past it
        widened = set_param(peer, "SRV1_MAX", 30.0)
        assert widened is not None and widened.param_value == 30.0
        assert bridge.parameters is not None and bridge.parameters.value("SRV2_FS_POS") == 0.0


def test_an_overlay_past_the_envelope_is_a_file_line_error(tmp_path: Path) -> None:
    path = write_config(tmp_path, free_udp_port(), WRITER)
    overlay = overlay_path(path)
    overlay.write_text("SRV1_TRIM: 1\nSRV1_MAX: 36000\n")
    overlay.chmod(0o600)
    with pytest.raises(ConfigError) as caught:
        load_config_with_overlay(path)
    assert f"{overlay}:2" in str(caught.value)
    assert "config file" in str(caught.value)


@pytest.mark.parametrize(
    ("extra", "expected"),
    [
        ("", "read-only"),
        ("  allowed_sources: [{system: 255, component: 190}]\n", "allowed_sources 255/190"),
        ("OPEN", "anyone on the link"),
    ],
)
def test_check_prints_who_may_write(tmp_path: Path, extra: str, expected: str) -> None:
    extra = OPEN if extra == "OPEN" else extra
    out, err = io.StringIO(), io.StringIO()
    assert check_main([str(write_config(tmp_path, 14551, extra))], out, err) == 0, err.getvalue()
    (line,) = [x for x in out.getvalue().splitlines() if "parameters:" in x and "set" in x]
    assert expected in line


# ------------------------------------------------------------------ 6: persistence that persists


def test_float32_of_the_documented_minimum_is_accepted(tmp_path: Path) -> None:
    with running(write_config(tmp_path, free_udp_port(), WRITER)) as (bridge, peer):
        reply = set_param(peer, "SRV1_FS_TMO", 0.01)
        assert reply is not None and reply.get_type() == "PARAM_VALUE"
        assert abs(reply.param_value - 0.01) < 1e-6
        assert bridge.parameters is not None and bridge.parameters.value("SRV1_FS_TMO") == 0.01


def test_param_type_is_honoured(tmp_path: Path) -> None:
    """An integer type's value is read as the integer it carries: byte-wise (the MAVLink
    parameter protocol's encoding, QGroundControl) or C-cast (ArduPilot, MAVProxy)."""
    bytewise = struct.unpack("<f", struct.pack("<i", 1))[0]  # int32 1 in the float's bytes
    with running(write_config(tmp_path, free_udp_port(), WRITER)) as (bridge, peer):
        reply = set_param(peer, "SRV1_REV", bytewise, mavlink2.MAV_PARAM_TYPE_INT32)
        assert reply is not None and reply.get_type() == "PARAM_VALUE"
        assert bridge.parameters is not None and bridge.parameters.value("SRV1_REV") == 1.0
        reply = set_param(peer, "SRV1_REV", 0.0, mavlink2.MAV_PARAM_TYPE_UINT8)
        assert bridge.parameters.value("SRV1_REV") == 0.0
        reply = set_param(peer, "SRV1_TRIM", 1.0, 99, kind="PARAM_ERROR")  # no such type
        assert reply is not None and reply.error == 6  # MAV_PARAM_ERROR_TYPE_UNSUPPORTED
        assert bridge.parameters.value("SRV1_TRIM") == 0.0


def test_a_huge_integer_in_the_overlay_is_a_file_line_error(tmp_path: Path) -> None:
    path = write_config(tmp_path, 14551, WRITER)
    overlay = overlay_path(path)
    overlay.write_text("SRV1_TRIM: " + "9" * 400 + "\n")
    overlay.chmod(0o600)
    out, err = io.StringIO(), io.StringIO()
    assert check_main([str(path)], out, err) == 2
    assert f"{overlay}:1" in err.getvalue()
    assert "Traceback" not in err.getvalue()


def test_a_dangling_overlay_symlink_is_reported(tmp_path: Path) -> None:
    path = write_config(tmp_path, 14551, WRITER)
    overlay_path(path).symlink_to(tmp_path / "gone.params.yaml")
    with pytest.raises(ConfigError) as caught:
        load_config_with_overlay(path)
    assert "gone.params.yaml" in str(caught.value)


@pytest.mark.parametrize("mode", [0o666, 0o620])
def test_a_group_or_world_writable_overlay_is_refused_with_the_reason(
    tmp_path: Path, mode: int
) -> None:
    path = write_config(tmp_path, 14551, WRITER)
    overlay = overlay_path(path)
    overlay.write_text("SRV1_TRIM: 1\n")
    overlay.chmod(mode)
    with pytest.raises(ConfigError) as caught:
        load_config_with_overlay(path)
    assert "writable" in str(caught.value)


def test_state_lives_in_the_service_state_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Under systemd's StateDirectory= the overlay goes to $STATE_DIRECTORY, not next to a
    config that lives in a read-only credentials directory."""
    config_dir, state = tmp_path / "credentials", tmp_path / "state"
    config_dir.mkdir()
    state.mkdir()
    path = write_config(config_dir, free_udp_port(), WRITER)
    config_dir.chmod(0o500)
    monkeypatch.setenv("STATE_DIRECTORY", str(state))
    try:
        assert overlay_path(path) == state / "rig.params.yaml"
        with running(path) as (bridge, peer):
            reply = set_param(peer, "SRV1_TRIM", 2.0)
            assert reply is not None and reply.param_value == 2.0
            assert wait_until(lambda: (state / "rig.params.yaml").exists(), 3.0)
        assert "SRV1_TRIM: 2" in (state / "rig.params.yaml").read_text()
        assert load_config_with_overlay(path).overlay == {"SRV1_TRIM": 2.0}
    finally:
        config_dir.chmod(0o700)


def test_a_save_that_fails_is_reported_to_the_ground_station(tmp_path: Path) -> None:
    """The overlay cannot be written (here: a directory took its name after the start, which
    fails for root too): the value is in force, and the ground station is told, not only the
    log."""
    path = write_config(tmp_path, free_udp_port(), WRITER)
    with running(path) as (bridge, peer):
        peer.gcs_heartbeat()
        overlay_path(path).mkdir()
        start = peer.count()
        reply = set_param(peer, "SRV1_TRIM", 2.0)
        assert reply is not None and reply.param_value == 2.0  # in force until restart
        assert wait_until(lambda: any("not saved" in t for t in peer.statustexts(start)), 5.0), (
            peer.statustexts(start)
        )


@pytest.mark.skipif(os.geteuid() != 0, reason="giving a file to another user needs root")
def test_an_overlay_owned_by_another_user_is_refused(tmp_path: Path) -> None:
    path = write_config(tmp_path, 14551, WRITER)
    overlay = overlay_path(path)
    overlay.write_text("SRV1_TRIM: 1\n")
    overlay.chmod(0o600)
    os.chown(overlay, 4321, 4321)
    with pytest.raises(ConfigError) as caught:
        load_config_with_overlay(path)
    assert "owned by user 4321" in str(caught.value)
