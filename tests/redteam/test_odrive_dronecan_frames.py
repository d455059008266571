"""Red team of the ODrive CANSimple and DroneCAN families: hostile CAN frames and tables.

Each test is a finding (it failed before its fix) or a regression guard that can fail. Frames
are built by the ``dronecan`` package (an independent encoder) or packed by hand for ODrive's
CANSimple; the bridge's parts are the real ones (profiles, bus node, allocator, telemetry).
"""

from __future__ import annotations

import dataclasses
import math
import struct
import types
from typing import Any

import can
import dronecan
import pytest
from dronecan.transport import Frame, Transfer

from mavservo.config import ConfigError, load_config_text
from mavservo.mavlink.mavlink_core import MavlinkCore
from mavservo.mavlink.settings import MavlinkSettings
from mavservo.servos.dronecan import wire
from mavservo.servos.dronecan.alloc import (
    ALLOCATION_ANSWERS_PER_S,
    NEW_IDS_PER_MINUTE,
    AllocationServer,
)
from mavservo.servos.dronecan.node import GET_NODE_INFO_PER_S, BridgeNode, NodeOptions
from mavservo.servos.dronecan.profile import DroneCanServo
from mavservo.servos.odrive.profile import (
    CMD_ENCODER_ESTIMATES,
    CMD_HEARTBEAT,
    ODrive,
    arbitration_id,
)
from tests.mavlink.test_telemetry_unknown_values import ESC_FROM_1, roundtrip
from tests.support.mavlink_doubles import RecordingBackend

Allocation = dronecan.uavcan.protocol.dynamic_node_id.Allocation


def to_messages(transfer: Transfer) -> list[can.Message]:
    return [
        can.Message(arbitration_id=f.message_id, is_extended_id=True, data=bytes(f.bytes))
        for f in transfer.to_frames()
    ]


def get_node_info_request(source: int, destination: int, tid: int) -> can.Message:
    transfer = Transfer(
        transfer_id=tid & 0x1F,
        source_node_id=source,
        dest_node_id=destination,
        payload=dronecan.uavcan.protocol.GetNodeInfo.Request(),
        request_not_response=True,
        service_not_message=True,
        transfer_priority=16,
    )
    [msg] = to_messages(transfer)
    return msg


def responses(frames: list[can.Message]) -> int:
    """Whole GetNodeInfo responses among ``frames`` (one end-of-transfer frame each)."""
    return sum(
        1
        for m in frames
        if (fields := wire.service_fields(m)) is not None
        and not fields.request
        and m.data[-1] & 0x40
    )


def exchange(server: AllocationServer, uid: bytes, now: float, preferred: int = 0) -> int:
    """The three anonymous Allocation stages; the node id of the last answer (0: none)."""
    node_id = 0
    for start, length in ((0, 6), (6, 6), (12, 4)):
        allocation = Allocation(node_id=preferred, first_part_of_unique_id=start == 0)
        allocation.unique_id.from_bytes(uid[start : start + length])
        [msg] = to_messages(
            Transfer(transfer_id=0, source_node_id=0, payload=allocation, discriminator=7)
        )
        received = wire.Reassembler().push(msg, now)
        assert received is not None
        if not server.receive(received, now):
            return 0
        transfer = Transfer()
        transfer.from_frames([Frame(m.arbitration_id, bytes(m.data)) for m in server.due(now)])
        node_id = int(transfer.payload.node_id)
    return node_id


# ----------------------------------------------------------------------------- GetNodeInfo
def test_a_get_node_info_flood_is_answered_at_a_bounded_rate_and_counted() -> None:
    """Finding: every request was answered (one frame in, ~9 frames out): a stranger could fill
    the bus with the bridge's answers. Now a bounded number per second, the rest counted."""
    node = BridgeNode([DroneCanServo(11)], NodeOptions(node_id=100), (0, 1), 0.0)
    node.due(0.0, "ok")
    out: list[can.Message] = []
    for i in range(200):
        node.receive(get_node_info_request(1 + i % 120, 100, i), 1.0 + i * 0.001)
        out += node.due(1.0 + i * 0.001, "ok")
    answered = responses(out)
    assert 1 <= answered <= 8
    assert node.counters["get_node_info"] == answered
    assert node.counters["get_node_info_limited"] == 200 - answered
    # a tool asking once a second later is answered again
    node.receive(get_node_info_request(42, 100, 1), 3.0)
    assert responses(node.due(3.0, "ok")) == 1


# ------------------------------------------------------------------------------ allocation
UID_A = bytes(range(0x10, 0x20))
UID_B = bytes(range(0x30, 0x40))


def test_a_hostile_table_never_hands_out_the_bridges_or_a_servos_id() -> None:
    """Finding: the table (from the file next to the config) was trusted as is: an entry with
    the bridge's node id, a servo's, or one id for two unique ids was handed out again. A
    servo's id passes the options' validation (the file is merged before the servos are
    known): the node drops the entry and says so."""
    table = {UID_A: 100, UID_B: 20, bytes(16): 7, bytes([1] * 16): 7}
    server = AllocationServer(100, {}, {20}, 125, table)
    assert exchange(server, UID_A, 1.0) not in (0, 100, 20)
    assert exchange(server, UID_B, 2.0) not in (0, 100, 20)
    ids = [exchange(server, bytes(16), 3.0), exchange(server, bytes([1] * 16), 4.0)]
    assert len(set(ids)) == 2 and 0 not in ids
    options = NodeOptions(node_id=100, allocator=True, allocation_table={UID_B.hex(): 20})
    node = BridgeNode([DroneCanServo(20)], options, (0, 1), 0.0)
    assert exchange(node.allocator, UID_B, 1.0) not in (0, 20)
    [notice] = node.take_notices()
    assert "allocation table: 1 entries ignored" in notice and f"{UID_B.hex()}=20" in notice


def test_repeated_allocations_keep_memory_bounded() -> None:
    """Finding: every completed exchange was appended to a diagnostics list forever."""
    server = AllocationServer(100, {}, set(), 125)
    for i in range(300):
        assert exchange(server, UID_A, float(i)) == 125
    assert len(server.allocations) <= 64
    assert len(server.table) == 1


def test_an_allocation_flood_of_new_unique_ids_stops_at_the_free_ids() -> None:
    """Guard: strangers asking with ever new unique ids get a few ids a minute (issue 32 item 7:
    the pool is no longer theirs to exhaust), never the bridge's or a servo's id, and the
    table stays bounded by its cap."""
    server = AllocationServer(100, {UID_A: 20}, {21}, 125)
    handed = [exchange(server, i.to_bytes(16, "big"), float(i)) for i in range(1, 140)]
    given = [h for h in handed if h]
    minutes = math.ceil(139 / 60)
    assert 0 < len(given) <= NEW_IDS_PER_MINUTE * minutes
    assert not {20, 21, 100} & set(given)
    assert len(server.table) <= server.max_entries
    assert exchange(server, UID_A, 500.0) == 20  # the configured servo still gets its id


# ---------------------------------------------------------------------------- reassembly
def test_a_flood_of_unfinished_multi_frame_starts_keeps_the_reassembler_bounded() -> None:
    """Guard: start frames that never finish, from every source and transfer id."""
    node = BridgeNode([DroneCanServo(11)], NodeOptions(node_id=100), (0, 1), 0.0)
    servo = DroneCanServo(11)
    for i in range(20_000):
        start = bytes(7) + bytes([0x80 | (i & 0x1F)])
        service = 1 << 7 | 1 << 15 | 100 << 8 | (1 + i // 32 % 127)
        node.receive(can.Message(arbitration_id=service | i % 4 << 16, data=start), 1.0)
        status = wire.message_id(wire.DTID_ACTUATOR_STATUS, 11, i % 32)
        start = bytes(7) + bytes([0x80 | (i // 32 & 0x1F)])
        servo.decode(can.Message(arbitration_id=status, data=start), 1.0)
    for reassembler in (node._reassembler, servo._reassembler):
        assert len(reassembler._pending) <= 64
        assert reassembler.errors["expired"] > 0


def test_toggle_and_crc_errors_from_a_servo_are_counted_and_not_a_state() -> None:
    """Guard: a corrupted Status transfer is counted by reason and leaves the state alone."""
    servo = DroneCanServo(11)
    status = dronecan.uavcan.equipment.actuator.Status(
        actuator_id=1, position=0.5, force=0, speed=0, power_rating_pct=0
    )
    first, last = to_messages(Transfer(transfer_id=3, source_node_id=11, payload=status))
    bad_crc = bytearray(first.data)
    bad_crc[0] ^= 0xFF
    assert servo.decode(can.Message(arbitration_id=first.arbitration_id, data=bad_crc), 1.0)
    assert servo.decode(last, 1.0) is None
    bad_toggle = bytearray(last.data)
    bad_toggle[-1] ^= 0x20
    servo.decode(first, 2.0)
    assert (
        servo.decode(can.Message(arbitration_id=last.arbitration_id, data=bad_toggle), 2.0) is None
    )
    assert servo.errors["crc"] == 1 and servo.errors["toggle"] == 1
    state = servo.last_state
    assert state is None or math.isnan(state.position_deg)


def test_a_stranger_on_the_bridges_node_id_is_counted_and_reported() -> None:
    """Guard: another node claiming the bridge's node id."""
    node = BridgeNode([DroneCanServo(11)], NodeOptions(node_id=100), (0, 1), 0.0)
    status = wire.node_status(5, wire.HEALTH_OK, wire.MODE_OPERATIONAL)
    for t in range(5):
        for msg in to_messages(Transfer(transfer_id=t, source_node_id=100, payload=status)):
            node.receive(msg, float(t))
    assert node.counters["node_id_conflict"] == 5
    assert len(node.take_notices()) == 1


# ---------------------------------------------------------------------------------- ODrive
def odrive_push(node_id: int, command: int, data: bytes) -> can.Message:
    return can.Message(
        arbitration_id=arbitration_id(node_id, command), is_extended_id=False, data=data
    )


@pytest.mark.parametrize("turns", [math.nan, math.inf, -math.inf, 3.0e38, -3.0e38])
def test_hostile_encoder_estimates_reach_the_gcs_encodable(turns: float) -> None:
    """Finding: 3e38 turns became 1e41 deg, which float32 cannot carry: NAMED_VALUE_FLOAT
    failed to encode (dropped, with a traceback in the log). A huge reading now goes out as
    an infinity; NaN and infinities keep the last known position."""
    servo = ODrive(3, motor_turns_per_rev=0.5)
    servo.decode(odrive_push(3, CMD_ENCODER_ESTIMATES, struct.pack("<ff", 0.25, 0.0)), 1.0)
    state = servo.decode(
        odrive_push(3, CMD_ENCODER_ESTIMATES, struct.pack("<ff", turns, turns)), 2.0
    )
    assert state is not None
    if not math.isfinite(turns):
        assert state.position_deg == pytest.approx(180.0)
    backend = RecordingBackend()
    backend.states["aileron"] = state
    core = MavlinkCore(MavlinkSettings(system_id=1, telemetry=ESC_FROM_1), backend)
    for msg_id in (375, 11030, 251):
        assert core.telemetry.request(msg_id, 0.0)
    decoded = roundtrip([m for _, m in core.tick(0.0)])
    named: dict[str, Any] = {
        m.name: m.value for m in decoded if m.get_type() == "NAMED_VALUE_FLOAT"
    }
    assert "s1_pos" in named and "s1_vel" in named
    if math.isfinite(turns):
        assert named["s1_pos"] == math.copysign(math.inf, turns)


def test_an_odrive_heartbeat_from_another_servos_node_id_is_not_this_servos() -> None:
    """Guard: an ODrive's pushes are matched by node id; another node's never count here."""
    servo = ODrive(3)
    heartbeat = struct.pack("<IBBB", 0, 8, 0, 0) + b"\0"
    assert not servo.is_reply(odrive_push(4, CMD_HEARTBEAT, heartbeat))
    assert servo.decode(odrive_push(4, CMD_HEARTBEAT, heartbeat), 1.0) is None
    assert servo.axis_state is None


TABLE_CONFIG = """
mavlink: {url: "udpin:127.0.0.1:14550"}
can:
  buses:
    - name: bus0
      interface: virtual
      channel: rt
      node:
        dronecan:
          node_id: 100
          allocator: true
          allocation_table: TABLE
servos:
  - {name: a, profile: dronecan, can_id: 11, options: {actuator_id: 1}}
channels:
  - {servo: a, source: servo_output, channel: 1, input: {min: 1000, max: 2000},
     output_deg: [-45, 45]}
"""


@pytest.mark.parametrize(
    ("table", "text"),
    [
        ("{" + UID_A.hex() + ": 100}", "the bridge's own node id 100"),
        ("{" + UID_A.hex() + ": 7, " + UID_B.hex() + ": 7}", "node id 7 is in the table twice"),
    ],
)
def test_check_refuses_a_table_that_gives_one_id_twice(table: str, text: str) -> None:
    """Finding: ``check`` called these tables valid; now a config error with its line."""
    with pytest.raises(ConfigError) as info:
        load_config_text(TABLE_CONFIG.replace("TABLE", table), "rig.yaml")
    assert "rig.yaml:" in str(info.value) and text in str(info.value)


def anonymous_first_part(uid: bytes) -> wire.Received:
    allocation = Allocation(node_id=0, first_part_of_unique_id=True)
    allocation.unique_id.from_bytes(uid[:6])
    [msg] = to_messages(
        Transfer(transfer_id=0, source_node_id=0, payload=allocation, discriminator=7)
    )
    received = wire.Reassembler().push(msg, 0.0)
    assert received is not None
    return received


def test_an_allocation_request_flood_is_answered_at_a_bounded_rate() -> None:
    """Finding: every anonymous first part was answered (one frame in, one out, from a sender
    that needs no node id): the answers had no bound. Now at most ALLOCATION_ANSWERS_PER_S,
    the rest counted; a node asking after the flood is served."""
    server = AllocationServer(100, {}, set(), 125)
    answers = 0
    for i in range(500):
        if server.receive(anonymous_first_part(i.to_bytes(16, "big")), 1.0 + i * 0.001):
            answers += len(server.due(1.0 + i * 0.001))
    assert 1 <= answers <= ALLOCATION_ANSWERS_PER_S
    assert server.limited == 500 - answers
    assert exchange(server, UID_A, 10.0) == 125


def test_the_budget_counts_the_bounded_answers_of_the_bridges_node() -> None:
    """The bridge's answers (GetNodeInfo, allocation) are bounded, and the budget counts the
    bound: a flood cannot put more on the bus than ``check`` said."""
    plain = BridgeNode([DroneCanServo(11)], NodeOptions(node_id=100), (0, 1), 0.0)
    allocating = BridgeNode(
        [DroneCanServo(11)], NodeOptions(node_id=100, allocator=True), (0, 1), 0.0
    )
    asked = wire.Received(None, wire.DTID_GET_NODE_INFO, 42, 0, True, True, 100, "", 16)
    node_info = len(plain.node_info.response(asked, 0.0))
    assert node_info == plain.node_info_frames()
    rates = {round(rate, 6) for rate, _, _ in plain.bus_frames_per_second(1, 20.0)}
    assert GET_NODE_INFO_PER_S * node_info in rates
    total = sum(rate for rate, _, _ in allocating.bus_frames_per_second(1, 20.0))
    assert total == pytest.approx(
        sum(rate for rate, _, _ in plain.bus_frames_per_second(1, 20.0))
        + ALLOCATION_ANSWERS_PER_S * 3
    )


def test_floods_are_noticed_once_and_counted_in_the_nodes_stats() -> None:
    """Finding: the node's counts (limited answers, decode errors by reason, ignored allocation
    requests) reached neither the log nor the run summary. Now one notice per kind, and
    :meth:`BridgeNode.stats` (the summary's ``bus <name> node:`` line)."""
    node = BridgeNode([DroneCanServo(11)], NodeOptions(node_id=100, allocator=True), (0, 1), 0.0)
    for i in range(50):
        allocation = Allocation(node_id=0, first_part_of_unique_id=True)
        allocation.unique_id.from_bytes(i.to_bytes(6, "big"))
        for msg in to_messages(
            Transfer(transfer_id=i & 0x1F, source_node_id=0, payload=allocation, discriminator=i)
        ):
            node.receive(msg, 1.0)
        node.receive(get_node_info_request(42, 100, i), 1.0)
    node.receive(can.Message(arbitration_id=1 << 7 | 1 << 15 | 100 << 8 | 42, data=b"\x40"), 1.0)
    notices = node.take_notices()
    assert len(notices) == 2
    assert any("GetNodeInfo" in n for n in notices) and any("allocation" in n for n in notices)
    stats = node.stats()
    assert stats["allocation_limited"] == 50 - ALLOCATION_ANSWERS_PER_S
    assert stats["get_node_info_limited"] == 50 - GET_NODE_INFO_PER_S
    assert stats["rx_orphan"] == 1


def node_status_frame(source: int, uptime: int, health: int = wire.HEALTH_OK) -> can.Message:
    payload = wire.node_status(uptime, health, wire.MODE_OPERATIONAL)
    [msg] = to_messages(Transfer(transfer_id=uptime & 0x1F, source_node_id=source, payload=payload))
    return msg


def test_a_second_node_speaking_for_a_servo_is_counted_when_its_uptime_disagrees() -> None:
    """Finding: a stranger's NodeStatus with a servo's node id (a spoofed fault, or a dead
    servo kept alive) was taken like the servo's own, uncounted. CAN carries no sender proof,
    but two nodes on one id disagree about the uptime: every NodeStatus whose uptime went back
    is counted (``uptime_backwards``) and is not a state nor a sign of life. A restart costs
    one NodeStatus."""
    servo = DroneCanServo(11)
    assert servo.decode(node_status_frame(11, 500), 1.0) is not None
    spoofed = servo.decode(node_status_frame(11, 3, wire.HEALTH_ERROR), 1.5)
    assert spoofed is None  # the fault the stranger claims is not the servo's state
    assert servo.decode(node_status_frame(11, 501), 2.0) is not None
    assert servo.decode(node_status_frame(11, 4, wire.HEALTH_ERROR), 2.5) is None
    assert servo.errors["uptime_backwards"] == 2
    state = servo.decode(node_status_frame(11, 502), 3.0)
    assert state is not None and not state.faults
    # a restart: its first NodeStatus counted, then followed again
    assert servo.decode(node_status_frame(11, 0), 4.0) is None
    assert servo.decode(node_status_frame(11, 1), 5.0) is not None


def test_an_unasked_sdo_reply_is_no_state_and_a_shared_bus_keeps_the_families_apart() -> None:
    """Guard: a TxSdo (0x05) nobody asked for, from the axis' own node id, is not a reply; on
    a bus shared by both families with the same number (ODrive node 11, DroneCAN node 11),
    neither takes the other's frames (11-bit against 29-bit identifiers)."""
    odrive, dronecan_servo = ODrive(11), DroneCanServo(11)
    sdo = odrive_push(11, 0x05, struct.pack("<BHBf", 0, 7, 0, 1.0))
    assert not odrive.is_reply(sdo) and odrive.decode(sdo, 1.0) is None
    heartbeat = odrive_push(11, CMD_HEARTBEAT, struct.pack("<IBBB", 0, 8, 0, 0) + b"\0")
    assert odrive.is_reply(heartbeat) and not dronecan_servo.is_reply(heartbeat)
    for msg in [
        node_status_frame(11, 5),
        *to_messages(
            Transfer(
                source_node_id=11,
                payload=dronecan.uavcan.equipment.actuator.Status(actuator_id=1, position=0.1),
            )
        ),
    ]:
        assert dronecan_servo.is_reply(msg) and not odrive.is_reply(msg)
    assert odrive.last_state is None and odrive.axis_state is None


def test_a_status_for_another_actuator_from_the_servos_node_is_counted_not_taken() -> None:
    """Finding: a servo set to another actuator id than the config's (it ignores every command
    the GCS sees ACCEPTED) reported its Status unnoticed: each was a sign of life with nothing
    in it. Now counted (``other_actuator``; the scheduler's ``rejected``), for Status, Volz
    and HiMark alike."""
    servo = DroneCanServo(11, actuator_id=1)
    equipment = dronecan.uavcan.equipment.actuator
    payloads = [
        equipment.Status(actuator_id=3, position=0.5),
        dronecan.com.volz.servo.ActuatorStatus(actuator_id=3, actual_position=0.5),
        dronecan.com.himark.servo.ServoInfo(servo_id=3, pos_sensor=100),
    ]
    for tid, payload in enumerate(payloads):
        frames = to_messages(Transfer(transfer_id=tid, source_node_id=11, payload=payload))
        results = [servo.decode(msg, 1.0 + tid) for msg in frames]
        assert results[-1] is None
    assert servo.errors["other_actuator"] == 3
    state = servo.last_state
    assert state is None or math.isnan(state.position_deg)


ODRIVE_CONFIG = """
mavlink: {url: "udpin:127.0.0.1:14550"}
can:
  buses:
    - {name: bus0, interface: virtual, channel: rt-odrive}
servos:
  - name: a
    profile: odrive
    can_id: 1
    options:
      motor_turns_per_rev: RATIO
channels:
  - {servo: a, source: servo_output, channel: 1, input: {min: 1000, max: 2000},
     output_deg: [-45, 45]}
"""


@pytest.mark.parametrize("ratio", ["1e-300", "1e-40", "0.0009", "0", "-1", ".nan", ".inf", "1001"])
def test_an_odrive_gear_ratio_at_which_float32_turns_underflow_is_a_config_error(
    ratio: str,
) -> None:
    """Finding: ``motor_turns_per_rev: 1e-300`` was valid, and every Set_Input_Pos then
    carried 0.0 turns (float32 underflow): each command ACCEPTED and applied as 0 deg."""
    with pytest.raises(ConfigError) as info:
        load_config_text(ODRIVE_CONFIG.replace("RATIO", ratio), "rig.yaml")
    assert "rig.yaml:11:" in str(info.value) and "motor_turns_per_rev" in str(info.value)


def test_the_odrive_gear_ratio_bounds_still_command_exactly() -> None:
    """Guard: at both bounds a command survives float32 (within 0.01 deg)."""
    for ratio in ("0.001", "1000"):
        load_config_text(ODRIVE_CONFIG.replace("RATIO", ratio), "rig.yaml")
        servo = ODrive(1, motor_turns_per_rev=float(ratio))
        for angle in (0.01, 90.0, -179.99):
            sent = struct.unpack_from("<f", bytes(servo.position_command(angle).data))[0]
            assert servo.options.degrees(sent) == pytest.approx(angle, abs=0.01)


def test_a_huge_odrive_velocity_on_a_gimbal_axis_still_encodes_the_attitude_status() -> None:
    """Finding (with the telemetry one): 3e38 turns/s is 1e41 deg/s, whose radians float32
    cannot carry: GIMBAL_DEVICE_ATTITUDE_STATUS failed to encode (dropped, traceback logged)."""
    from tests.mavlink.test_gimbal_device import FollowingBackend, make_device

    servo = ODrive(3)
    state = servo.decode(
        odrive_push(3, CMD_ENCODER_ESTIMATES, struct.pack("<ff", 0.1, 3.0e38)), 1.0
    )
    assert state is not None

    def statuses(self: FollowingBackend) -> list[Any]:
        return [
            dataclasses.replace(s, state=state) if s.state is not None else s
            for s in FollowingBackend.servo_statuses(self)
        ]

    device, backend = make_device()
    backend.servo_statuses = types.MethodType(statuses, backend)  # type: ignore[method-assign]
    message = device.attitude_status(2.0)
    [decoded] = roundtrip([message])
    assert decoded.angular_velocity_y == math.inf
