"""Red team of the ODrive and DroneCAN families through a running bridge: hostile frames
handed to the scheduler as its receive thread would (the bus is shared with anyone), the GCS a
pymavlink peer over loopback UDP, the servos simulated behind the aa55 interface on the
adapter emulator's pty.
"""

from __future__ import annotations

import json
import math
import os
import struct
import time
import uuid
from pathlib import Path

import can
import dronecan
import pytest
from dronecan.transport import Transfer

from mavservo.app import node_state
from mavservo.app.bridge import Bridge
from mavservo.app.console import format_summary
from mavservo.app.report import ReportError, load_run
from mavservo.config import load_config
from mavservo.mavlink.connection import mavlink2
from mavservo.servos.dronecan import wire
from mavservo.servos.dronecan.node import GET_NODE_INFO_PER_S
from mavservo.servos.odrive.profile import CMD_ENCODER_ESTIMATES, arbitration_id
from tests.e2e.test_dronecan_through_bridge import CONFIG as DRONECAN_CONFIG
from tests.e2e.test_dronecan_through_bridge import status
from tests.e2e.test_odrive_through_bridge import CONFIG as ODRIVE_CONFIG
from tests.servos.dronecan.test_node_id_allocation import CONFIG as ALLOCATING
from tests.support.bridge import MAV_CMD_DO_SET_SERVO, MAV_RESULT_ACCEPTED, Peer, running, sim_servo
from tests.support.waiting import wait_until

pytestmark = pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")

WAIT_S = 5.0


def test_a_huge_encoder_estimate_reaches_the_gcs_as_an_infinity_not_an_encode_error() -> None:
    """Finding: a (spoofed or broken) ODrive encoder estimate of 3e38 turns made NAMED_VALUE_FLOAT
    fail to encode in the link: dropped, with a traceback in the log."""
    # the name within WAIT_S: a wider link than a radio's default 1,000 B/s decimation allows
    wide = "  link_budget_bytes_s: 20000\n"
    with running(ODRIVE_CONFIG, extra_mavlink=wide) as (bridge, port):
        peer = Peer(port)
        try:
            peer.send(mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))  # a GCS: answer me
            assert peer.command(MAV_CMD_DO_SET_SERVO, [1, 1600]) == MAV_RESULT_ACCEPTED
            scheduler = bridge.schedulers["bus0"]
            assert wait_until(lambda: bridge.backend is not None, WAIT_S)
            mark = peer.count()
            hostile = can.Message(
                arbitration_id=arbitration_id(1, CMD_ENCODER_ESTIMATES),
                is_extended_id=False,
                data=struct.pack("<ff", 3.0e38, -3.0e38),
            )

            def seen_inf() -> bool:
                scheduler.handle_frame(hostile, time.monotonic())
                return any(
                    m.get_type() == "NAMED_VALUE_FLOAT"
                    and m.name == "s1_pos"
                    and m.value == math.inf
                    for m in peer.since(mark)
                )

            assert wait_until(seen_inf, WAIT_S)
            assert bridge.mavlink is not None
            assert bridge.mavlink.link.counters["encode_errors"] == 0
        finally:
            peer.close()


def test_a_get_node_info_flood_is_bounded_and_commands_go_through() -> None:
    """A stranger floods the bridge's node with GetNodeInfo requests while the GCS commands:
    answers stay within GET_NODE_INFO_PER_S (the rest counted), every command is applied."""
    with running(DRONECAN_CONFIG) as (bridge, port):
        peer = Peer(port)
        try:
            scheduler = bridge.schedulers["bus0"]
            [node] = scheduler.nodes
            request = dronecan.uavcan.protocol.GetNodeInfo.Request()
            started = time.monotonic()
            for i, pwm in enumerate((1700, 1300, 1600)):
                for tid in range(100):
                    transfer = Transfer(
                        transfer_id=tid & 0x1F,
                        source_node_id=1 + (tid + 100 * i) % 120,
                        dest_node_id=100,
                        payload=request,
                        request_not_response=True,
                        service_not_message=True,
                    )
                    [frame] = transfer.to_frames()
                    msg = can.Message(
                        arbitration_id=frame.message_id, is_extended_id=True, data=frame.bytes
                    )
                    scheduler.handle_frame(msg, time.monotonic())
                assert peer.command(MAV_CMD_DO_SET_SERVO, [1, pwm]) == MAV_RESULT_ACCEPTED
                target = (pwm - 1500) / 500 * 45
                left = sim_servo(bridge, "left")
                assert wait_until(lambda a=target, s=left: abs(s.position_deg - a) < 0.3, WAIT_S)
            elapsed = time.monotonic() - started
            answered = node.counters["get_node_info"]
            assert 1 <= answered <= GET_NODE_INFO_PER_S * (math.ceil(elapsed) + 1)
            assert node.counters["get_node_info_limited"] == 300 - answered
            # counted where the operator sees it: the run summary, and one log line (a notice)
            [counts] = bridge.summary()["buses"]["bus0"]["nodes"]
            assert counts["get_node_info_limited"] == 300 - answered
            assert f"get_node_info_limited {300 - answered}" in format_summary(bridge.summary())
            assert any("faster than" in text for _, text in bridge.events)
        finally:
            peer.close()


@pytest.mark.parametrize(
    "text",
    [
        "[" * 100_000 + "]" * 100_000,  # finding: RecursionError, the bridge did not start
        json.dumps(
            {"bus0": {"dronecan": {"allocation_table": {f"{i:032x}": 7 for i in range(9)}}}}
        ),
        json.dumps({"bus0": {"dronecan": {"allocation_table": {f"{1:032x}": 100}}}}),
    ],
    ids=["deeply-nested", "one-id-nine-times", "bridge-id"],
)
def test_a_hostile_node_state_file_is_ignored_and_the_bridge_starts(
    tmp_path: Path, text: str, caplog: pytest.LogCaptureFixture
) -> None:
    channel = f"dronecan-hostile-{uuid.uuid4().hex}"
    path = tmp_path / "rig.yaml"
    path.write_text(ALLOCATING.replace("CHANNEL", channel).replace("LOGS", str(tmp_path / "runs")))
    (tmp_path / "rig.yaml.nodes.json").write_text(text)
    bridge = Bridge(load_config(path), config_path=path, log_dir=False).start()
    try:
        [node] = bridge.schedulers["bus0"].nodes
        assert node.persistent_state() == (0, {"allocation_table": {}})
    finally:
        bridge.stop()
    assert any(
        "node state" in r.getMessage() and "ignored" in r.getMessage() for r in caplog.records
    )


def test_unfinished_status_transfers_from_a_stranger_do_not_keep_a_silent_servo_online() -> None:
    """Guard: start frames of a Status transfer carrying the silent servo's node id (a stranger,
    or a broken node) are neither a reply nor a sign of life: the servo goes offline and the
    frames are counted as rejected. (A stranger sending whole, valid NodeStatus transfers with
    the servo's id is indistinguishable from the servo: CAN frames carry no sender proof.)"""
    with running(DRONECAN_CONFIG) as (bridge, port):
        peer = Peer(port)
        try:
            scheduler = bridge.schedulers["bus0"]
            assert wait_until(lambda: status(bridge, "left").online, WAIT_S)
            sim_servo(bridge, "left").faults.silent = True
            status_id = wire.message_id(wire.DTID_ACTUATOR_STATUS, 11, wire.PRIORITY_LOW)
            tid = 0

            def spoof_start() -> bool:
                nonlocal tid
                tid += 1
                start = bytes(7) + bytes([0x80 | (tid & 0x1F)])
                scheduler.handle_frame(
                    can.Message(arbitration_id=status_id, data=start), time.monotonic()
                )
                return not status(bridge, "left").online

            assert wait_until(spoof_start, 3 * WAIT_S)
            assert scheduler.metrics()["servos"]["left"]["frames"]["rejected"] > 0
        finally:
            peer.close()


@pytest.mark.parametrize(
    "header", ["[]", "[" * 100_000 + "]" * 100_000], ids=["not-a-mapping", "deeply-nested"]
)
def test_report_on_a_hostile_run_header_is_an_error_not_a_traceback(
    tmp_path: Path, header: str
) -> None:
    """Finding (next door: the run directory that ``report`` reads): a header that is JSON but
    not a mapping, or nested too deep for the decoder, raised AttributeError/RecursionError."""
    (tmp_path / "run.json").write_text(header)
    with pytest.raises(ReportError, match="run header"):
        load_run(tmp_path)


class _Scheduler:
    """What NodeStateKeeper reads of a scheduler."""

    name = "bus0"

    def node_states(self) -> list[tuple[str, tuple[int, dict[str, object]]]]:
        return [("dronecan", (1, {"allocation_table": {f"{1:032x}": 125}}))]


def test_the_table_file_symlinked_huge_or_a_fifo_is_never_followed_read_whole_or_hung(
    tmp_path: Path,
) -> None:
    """Guards: a symlink at the table's path is replaced, not written through (the file it
    names keeps its content); a file over 1 MiB and a FIFO are reported and ignored."""
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    state = tmp_path / "rig.yaml.nodes.json"
    state.symlink_to(victim)
    keeper = node_state.NodeStateKeeper(state, node_state.load(state))
    assert keeper.update([_Scheduler()])  # type: ignore[list-item]
    assert victim.read_text() == "keep me" and not state.is_symlink()
    assert json.loads(state.read_text())["bus0"]["dronecan"]["allocation_table"]
    big = tmp_path / "big.json"
    big.write_text('{"x": "' + "a" * (2 << 20) + '"}')
    assert node_state.load(big) == {}
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    assert node_state.load(fifo) == {}
