"""``logging.can_frames: all`` (issue 29): the CAN logs hold every frame the adapter delivered,
a foreign node's included, and python-can's LogReader reads them back; ``servos`` keeps only
the configured servos' frames, as before."""

from __future__ import annotations

import time
import uuid
from collections import Counter
from pathlib import Path

import can
import pytest

from mavservo.app.bridge import Bridge, free_udp_port
from mavservo.config import load_config_text
from mavservo.records.runlog import can_log_files
from mavservo.sim.canbus import FOREIGN
from mavservo.sim.servo import SimServo
from mavservo.sim.virtual import VirtualServoBus
from tests.support.bridge import bridge_config
from tests.support.waiting import wait_until

#: The foreign node's frames: standard, extended and remote, none a servo's id.
FOREIGN_FRAMES = (
    [
        can.Message(arbitration_id=0x300 + k, data=bytes([k] * (k % 9)), is_extended_id=False)
        for k in range(8)
    ]
    + [
        can.Message(arbitration_id=0x1ABCDE00 + k, data=bytes(8), is_extended_id=True)
        for k in range(4)
    ]
    + [can.Message(arbitration_id=0x123, is_remote_frame=True, dlc=2, is_extended_id=False)]
)


def _read_back(run_dir: Path, fmt: str) -> list[can.Message]:
    """Every frame of the run's ``fmt`` CAN log, through python-can's own LogReader."""
    out: list[can.Message] = []
    options = {"relative_timestamp": False} if fmt == "asc" else {}
    for path in can_log_files(run_dir, fmt):
        with can.LogReader(path, **options) as reader:
            out += list(reader)
    return out


def _key(msg: can.Message) -> tuple[int, bool, bool, bytes]:
    data = b"" if msg.is_remote_frame else bytes(msg.data)
    return (msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame, data)


def _run_with_foreign_node(tmp_path: Path, can_frames: str) -> tuple[Path, Counter, int]:
    """A bridge on the AA-55 emulator with one RMD-X, while a foreign node sends
    ~2,600 frames/s for 1 s; the run directory, what the node sent, the replies received."""
    config = bridge_config(
        "servos:\n  - {name: s1, profile: rmd-x, can_id: 1}\n"
        f"logging: {{can_frames: {can_frames}}}\n",
        free_udp_port(),
    )
    bridge = Bridge(config, log_dir=tmp_path)
    bridge.start()
    sent: Counter = Counter()
    try:
        emulator = bridge.emulators["bus0"]
        assert wait_until(lambda: bridge.status_rows()[0]["online"], 10.0)
        deadline = time.monotonic() + 1.0
        for _ in range(400):  # a burst of 13 every 5 ms: ~2,600 frames/s
            if time.monotonic() > deadline:
                break
            with emulator._lock:
                now = emulator.clock()
                for msg in FOREIGN_FRAMES:
                    emulator.canbus.submit(msg, now, FOREIGN)
                    sent[_key(msg)] += 1
            time.sleep(0.005)
        time.sleep(0.3)  # the last burst reaches the host
    finally:
        summary = bridge.stop()
    assert bridge.run_dir is not None
    return bridge.run_dir, sent, summary["servos"]["s1"]["frames"]["received"]


def test_all_frames_logged_with_a_foreign_node_and_read_back(tmp_path: Path) -> None:
    run_dir, sent, received = _run_with_foreign_node(tmp_path, "all")
    assert sum(sent.values()) > 1000
    for fmt in ("asc", "blf"):
        frames = _read_back(run_dir, fmt)
        rx = Counter(_key(m) for m in frames if m.is_rx)
        foreign = {k: rx[k] for k in sent}
        assert foreign == dict(sent), fmt  # every foreign frame, exactly once
        servo_replies = sum(n for (arb, ext, _, _), n in rx.items() if arb == 0x241 and not ext)
        assert servo_replies >= received > 0, fmt  # and every reply the scheduler decoded
        assert any(not m.is_rx and m.arbitration_id == 0x141 for m in frames), fmt


def test_servos_keeps_only_the_servos_frames(tmp_path: Path) -> None:
    run_dir, sent, received = _run_with_foreign_node(tmp_path, "servos")
    frames = _read_back(run_dir, "asc")
    assert not {_key(m) for m in frames} & set(sent)
    assert sum(1 for m in frames if m.is_rx and m.arbitration_id == 0x241) >= received > 0


def test_error_frames_and_unmatched_frames_of_a_python_can_bus_are_logged(
    tmp_path: Path,
) -> None:
    """On a python-can bus that reports error frames (here ``virtual``), they are logged too."""
    channel = f"errors-{uuid.uuid4().hex}"
    config = load_config_text(
        f"mavlink: {{url: 'udpin:127.0.0.1:{free_udp_port()}'}}\n"
        f"can: {{buses: [{{name: bus0, interface: virtual, channel: {channel}}}]}}\n"
        "servos:\n  - {name: s1, profile: rmd-x, can_id: 1}\n",
        "<virtual>",
    )
    with VirtualServoBus([SimServo("rmd-x", 1)], channel=channel):
        bridge = Bridge(config, log_dir=tmp_path)
        bridge.start()
        other = can.Bus(interface="virtual", channel=channel)
        try:
            assert wait_until(lambda: bridge.status_rows()[0]["online"], 10.0)
            other.send(
                can.Message(
                    is_error_frame=True,
                    arbitration_id=0x20000004,
                    dlc=8,
                    data=bytes([0, 0x10, 0, 0, 0, 0, 0, 0]),
                )
            )
            other.send(can.Message(arbitration_id=0x241, data=b"\x55"))  # no reply a profile takes
            time.sleep(0.3)
        finally:
            other.shutdown()
            bridge.stop()
    assert bridge.run_dir is not None
    for fmt in ("asc", "blf"):
        frames = _read_back(bridge.run_dir, fmt)
        assert any(m.is_error_frame for m in frames), fmt
        assert any(m.arbitration_id == 0x241 and bytes(m.data) == b"\x55" for m in frames), fmt


@pytest.mark.parametrize("value", ["everything", 3])
def test_can_frames_takes_all_or_servos(value: object) -> None:
    from mavservo.config import ConfigError

    with pytest.raises(ConfigError, match="can_frames"):
        load_config_text(
            "servos:\n  - {name: s1, profile: rmd-x, can_id: 1}\n"
            f"logging: {{can_frames: {value}}}\n",
            "x",
        )
