"""DroneCAN profile, wire helpers and the bridge's bus node, against the ``dronecan`` package.

Frames the tests feed in are built by the package itself (its ``Transfer`` and message classes),
not by the project's helpers, and frames the project builds are decoded by the package: the
package is the independent implementation (it parses the published DSDL). Hostile input
(truncated, reordered, corrupted transfers, unknown types) is counted and never raises.
"""

from __future__ import annotations

import math

import can
import dronecan
import pytest
from dronecan.transport import Frame, Transfer
from hypothesis import given, settings
from hypothesis import strategies as st

from mavservo.config import ConfigError, load_config_text
from mavservo.scheduling.schedule_core import ScheduleCore, ServoSpec, TimingConfig
from mavservo.servos.base import Fault
from mavservo.servos.dronecan import wire
from mavservo.servos.dronecan.node import BridgeNode, NodeOptions, frames_for_commands
from mavservo.servos.dronecan.profile import DroneCanServo

actuator = dronecan.uavcan.equipment.actuator


def library_frames(payload, source: int, tid: int = 0, **kw) -> list[can.Message]:  # type: ignore[no-untyped-def]
    transfer = Transfer(transfer_id=tid, source_node_id=source, payload=payload, **kw)
    return [
        can.Message(arbitration_id=f.message_id, is_extended_id=True, data=bytes(f.bytes))
        for f in transfer.to_frames()
    ]


def library_decode(frames: list[can.Message]):  # type: ignore[no-untyped-def]
    transfer = Transfer()
    transfer.from_frames([Frame(m.arbitration_id, bytes(m.data)) for m in frames])
    return transfer


def status_payload(actuator_id: int = 1, position: float = 0.5, speed: float = 0.25):  # type: ignore[no-untyped-def]
    return actuator.Status(
        actuator_id=actuator_id, position=position, force=math.nan, speed=speed, power_rating_pct=50
    )


def test_data_type_ids_are_the_packages() -> None:
    assert actuator.ArrayCommand.default_dtid == wire.DTID_ARRAY_COMMAND
    assert actuator.Status.default_dtid == wire.DTID_ACTUATOR_STATUS
    assert dronecan.uavcan.protocol.NodeStatus.default_dtid == wire.DTID_NODE_STATUS
    assert dronecan.uavcan.protocol.GetNodeInfo.default_dtid == wire.DTID_GET_NODE_INFO
    assert dronecan.uavcan.protocol.dynamic_node_id.Allocation.default_dtid == wire.DTID_ALLOCATION
    assert dronecan.com.volz.servo.ActuatorStatus.default_dtid == wire.DTID_VOLZ_STATUS
    assert dronecan.com.himark.servo.ServoInfo.default_dtid == wire.DTID_HIMARK_INFO
    status = dronecan.uavcan.protocol.NodeStatus()
    assert (status.HEALTH_OK, status.HEALTH_WARNING, status.HEALTH_ERROR) == (0, 1, 2)
    assert (status.MODE_OPERATIONAL, status.MODE_OFFLINE) == (0, 7)


@pytest.mark.parametrize(
    ("options", "kind", "value"),
    [
        ({}, 1, math.radians(30.0)),
        ({"command": "unitless", "unitless_min_deg": -60, "unitless_max_deg": 60}, 0, 0.5),
        ({"command": "unitless", "unitless_min_deg": 0, "unitless_max_deg": 90}, 0, -1 / 3),
    ],
)
def test_position_command_decodes_with_the_package(options: dict, kind: int, value: float) -> None:
    profile = DroneCanServo(7, actuator_id=4, **options)
    msg = profile.position_command(30.0, 90.0)
    transfer = library_decode([msg])
    assert transfer.data_type_id == wire.DTID_ARRAY_COMMAND
    [command] = transfer.payload.commands
    assert (command.actuator_id, command.command_type) == (4, kind)
    assert command.command_value == pytest.approx(value, abs=1e-3)


def test_unitless_angles_outside_the_range_are_refused_not_clamped() -> None:
    profile = DroneCanServo(7, command="unitless", unitless_min_deg=-30, unitless_max_deg=30)
    with pytest.raises(ValueError):
        profile.position_command(31.0)
    with pytest.raises(ValueError):
        profile.position_command(math.nan)


@pytest.mark.parametrize("count", [1, 2, 4, 8, 15, 16, 31, 40])
def test_node_packs_commands_into_transfers_of_at_most_15(count: int) -> None:
    servos = [DroneCanServo(1 + i, actuator_id=i) for i in range(count)]
    node = BridgeNode(servos, NodeOptions(node_id=100), (0, 1), 0.0)
    frames = node.pack([s.position_command(float(i)) for i, s in enumerate(servos)])
    assert len(frames) == frames_for_commands(count)
    # split into transfers at end-of-transfer bits; the package reassembles each (CRC included)
    transfers, current = [], []
    for msg in frames:
        current.append(msg)
        if msg.data[-1] & 0x40:
            transfers.append(library_decode(current))
            current = []
    assert not current
    assert len(transfers) == -(-count // 15)
    assert [t.transfer_id for t in transfers] == list(range(len(transfers)))
    commands = [c for t in transfers for c in t.payload.commands]
    assert [c.actuator_id for c in commands] == list(range(count))
    for i, c in enumerate(commands):
        assert c.command_value == pytest.approx(math.radians(i), rel=1e-3, abs=1e-3)
    assert all(t.source_node_id == 100 for t in transfers)


def test_status_transfer_becomes_the_servos_state_and_its_first_frame_a_sign_of_life() -> None:
    profile = DroneCanServo(5, actuator_id=2)
    first, second = library_frames(status_payload(2, 0.5, -1.0), 5, priority := 16)  # noqa: F841
    assert profile.is_reply(first) and profile.is_reply(second)
    partial = profile.decode(first, 1.0)
    assert partial is not None and math.isnan(partial.position_deg)
    state = profile.decode(second, 1.001)
    assert state is not None
    assert state.position_deg == pytest.approx(math.degrees(0.5), abs=0.05)
    assert state.velocity_dps == pytest.approx(math.degrees(-1.0), abs=0.05)
    # another actuator's status, or another node's, changes nothing
    other = library_frames(status_payload(3, 1.0), 5, 1)
    for msg in other:
        profile.decode(msg, 1.1)
    assert profile.last_state is not None
    assert profile.last_state.position_deg == pytest.approx(math.degrees(0.5), abs=0.05)
    assert not profile.is_reply(library_frames(status_payload(2), 6)[0])


def test_volz_and_himark_status() -> None:
    volz = DroneCanServo(9, actuator_id=1)
    payload = dronecan.com.volz.servo.ActuatorStatus(
        actuator_id=1,
        actual_position=-0.25,
        current=40,
        voltage=60,
        motor_pwm=10,
        motor_temperature=80,
    )
    state = None
    for msg in library_frames(payload, 9):
        state = volz.decode(msg, 2.0)
    assert state is not None
    assert state.position_deg == pytest.approx(math.degrees(-0.25), abs=0.05)
    assert state.current_a == pytest.approx(1.0)
    assert state.voltage_v == pytest.approx(12.0)
    assert state.temperature_c == pytest.approx(30.0)
    himark = DroneCanServo(10, actuator_id=2)
    info = dronecan.com.himark.servo.ServoInfo(
        servo_id=2,
        pwm_input=1500,
        pos_cmd=1000,
        pos_sensor=-1234,
        voltage=1210,
        current=150,
        pcb_temp=350,
        motor_temp=400,
        error_status=1,
    )
    for msg in library_frames(info, 10):
        state = himark.decode(msg, 2.0)
    assert state is not None
    assert state.position_deg == pytest.approx(-12.34)
    assert state.voltage_v == pytest.approx(12.1)
    assert state.current_a == pytest.approx(1.5)
    assert state.temperature_c == pytest.approx(40.0)
    assert Fault.OTHER in state.faults


@pytest.mark.parametrize(
    ("health", "mode", "fault"),
    [
        (0, 0, False),
        (0, 1, False),
        (1, 0, True),
        (2, 0, True),
        (3, 0, True),
        (0, 2, True),
        (0, 3, True),
        (0, 7, True),
    ],
)
def test_node_status_health_and_mode_become_faults(health: int, mode: int, fault: bool) -> None:
    profile = DroneCanServo(5)
    status = dronecan.uavcan.protocol.NodeStatus(uptime_sec=3, health=health, mode=mode)
    [msg] = library_frames(status, 5)
    state = profile.decode(msg, 1.0)
    assert state is not None
    assert (Fault.OTHER in state.faults) == fault


def test_a_dronecan_servo_is_offline_after_three_silent_heartbeats() -> None:
    timing = TimingConfig(reply_timeout_s=0.05)
    core = ScheduleCore([ServoSpec("s", DroneCanServo(5), telemetry_hz=50)], timing, 0.0)
    assert core.push_silence_limit_s("s") == pytest.approx(3 * 1.0 + 0.05)


# ------------------------------------------------------------------------------ hostile input
def test_bad_transfers_are_counted_by_reason_and_never_raise() -> None:
    profile = DroneCanServo(5, actuator_id=1)
    first, second = library_frames(status_payload(), 5, 3)
    bad_crc = bytearray(first.data)
    bad_crc[0] ^= 0xFF
    profile.decode(can.Message(arbitration_id=first.arbitration_id, data=bad_crc), 0.0)
    assert profile.decode(second, 0.0) is None
    assert profile.errors["crc"] == 1
    # a second frame alone: no start
    assert profile.decode(second, 0.1) is None
    assert profile.errors["orphan"] == 1
    # toggle bit wrong on the continuation
    toggled = bytearray(second.data)
    toggled[-1] ^= 0x20
    profile.decode(first, 0.2)
    assert (
        profile.decode(can.Message(arbitration_id=second.arbitration_id, data=toggled), 0.2) is None
    )
    assert profile.errors["toggle"] == 1
    # truncated: a single-frame NodeStatus with 2 payload bytes
    ns_id = wire.message_id(wire.DTID_NODE_STATUS, 5, 24)
    profile.decode(can.Message(arbitration_id=ns_id, data=bytes([1, 2, 0xC0])), 0.3)
    # an empty frame
    assert profile.decode(can.Message(arbitration_id=ns_id, data=b""), 0.3) is None
    assert profile.errors["empty"] == 1
    # a transfer whose continuation never comes expires
    profile.decode(first, 0.4)
    profile.decode(first, 5.0)
    assert profile.errors["expired"] >= 1 or profile.errors["sequence"] >= 1


def test_unknown_data_types_are_counted_by_the_reassembler() -> None:
    reassembler = wire.Reassembler()
    msg = can.Message(arbitration_id=wire.message_id(999, 5), data=bytes([1, 2, 3, 0xC0]))
    assert reassembler.push(msg, 0.0) is None
    assert reassembler.errors["unknown_type"] == 1


frame_ids = st.one_of(
    st.sampled_from(
        [
            wire.DTID_NODE_STATUS,
            wire.DTID_ACTUATOR_STATUS,
            wire.DTID_VOLZ_STATUS,
            wire.DTID_HIMARK_INFO,
            999,
            1010,
        ]
    ).map(lambda d: wire.message_id(d, 5, 16)),
    st.integers(0, 0x1FFFFFFF),
)


@settings(max_examples=400, deadline=None)
@given(st.lists(st.tuples(frame_ids, st.binary(min_size=0, max_size=8)), max_size=30))
def test_fuzz_frames_never_raise_in_profile_or_node(frames: list[tuple[int, bytes]]) -> None:
    profile = DroneCanServo(5, actuator_id=1)
    node = BridgeNode([profile], NodeOptions(node_id=100, allocator=True), (0, 1), 0.0)
    for i, (arb, data) in enumerate(frames):
        msg = can.Message(arbitration_id=arb, is_extended_id=True, data=data)
        state = profile.decode(msg, i * 0.01)
        assert state is None or profile.is_reply(msg)
        node.receive(msg, i * 0.01)
    node.due(1.0, "ok")


@settings(max_examples=200, deadline=None)
@given(st.lists(st.sampled_from(range(6)), min_size=1, max_size=12), st.integers(0, 31))
def test_fuzz_reordered_and_dropped_frames_of_real_transfers(order: list[int], tid: int) -> None:
    """Frames of a real multi-frame Status in any order, repeated or missing: a state comes
    only from a complete, in-order transfer, and it is the right one."""
    profile = DroneCanServo(5, actuator_id=1)
    frames = library_frames(status_payload(1, 0.75), 5, tid) * 3
    for i in order:
        state = profile.decode(frames[i], 0.0)
        if state is not None and not math.isnan(state.position_deg):
            assert state.position_deg == pytest.approx(math.degrees(0.75), abs=0.05)


# ------------------------------------------------------------------------------- the bus node
def test_node_answers_get_node_info_and_reports_health() -> None:
    servos = [DroneCanServo(11), DroneCanServo(12, actuator_id=2)]
    node = BridgeNode(servos, NodeOptions(node_id=100, name="org.example.bridge"), (3, 4), 10.0)
    [status] = node.due(12.5, "warning")
    decoded = library_decode([status])
    assert decoded.source_node_id == 100
    assert (decoded.payload.health, decoded.payload.mode, decoded.payload.uptime_sec) == (1, 0, 2)
    assert node.due(12.6, "ok") == []  # 1 Hz
    assert node.next_due() == pytest.approx(13.5)
    request = Transfer(
        transfer_id=7,
        source_node_id=42,
        dest_node_id=100,
        payload=dronecan.uavcan.protocol.GetNodeInfo.Request(),
        request_not_response=True,
        service_not_message=True,
        transfer_priority=20,
    )
    [frame] = request.to_frames()
    asked = can.Message(
        arbitration_id=frame.message_id, is_extended_id=True, data=bytes(frame.bytes)
    )
    assert node.receive(asked, 12.7)
    response = library_decode(node.due(12.7, "ok"))
    assert response.service_not_message and not response.request_not_response
    assert (response.dest_node_id, response.transfer_id) == (42, 7)
    assert response.transfer_priority == 20  # the request's
    assert response.payload.name.decode() == "org.example.bridge"
    assert (response.payload.software_version.major, response.payload.software_version.minor) == (
        3,
        4,
    )
    # a request for another node is not ours
    other = can.Message(
        arbitration_id=frame.message_id & ~(0x7F << 8) | (99 << 8), data=bytes(frame.bytes)
    )
    assert not node.receive(other, 12.8)


def test_node_reports_another_array_command_sender_once() -> None:
    node = BridgeNode([DroneCanServo(11)], NodeOptions(node_id=100), (0, 1), 0.0)
    foreign = library_frames(
        wire.array_command([(1, 1, 0.1), (2, 1, 0.2)]), 10, 0, transfer_priority=8
    )
    for t in range(3):
        for msg in foreign:
            node.receive(msg, float(t))
    [notice] = node.take_notices()
    assert "node 10" in notice and "actuators 1 (the bridge's)" in notice
    assert node.take_notices() == []
    assert node.foreign_masters == {10}
    # another controller for other actuators is reported too, as such
    for msg in library_frames(wire.array_command([(7, 1, 0.1)]), 12, 0):
        node.receive(msg, 4.0)
    [notice] = node.take_notices()
    assert "node 12" in notice and "actuators 7 (not the bridge's)" in notice


def test_node_refuses_its_id_on_a_servo_and_duplicate_actuators() -> None:
    with pytest.raises(ValueError, match="node id 11"):
        BridgeNode([DroneCanServo(11)], NodeOptions(node_id=11), (0, 1), 0.0)
    with pytest.raises(ValueError, match="actuator id 1"):
        BridgeNode([DroneCanServo(11), DroneCanServo(12)], NodeOptions(), (0, 1), 0.0)


CONFIG = """
mavlink: {url: sim}
can:
  buses:
    - name: bus0
      node: {dronecan: {node_id: NODE}}
servos:
  - {name: a, profile: dronecan, can_id: 11, options: {actuator_id: 1}}
  - name: b
    profile: dronecan
    can_id: ID_B
    options: {actuator_id: ACT_B}
channels: []
"""


@pytest.mark.parametrize(
    ("node", "id_b", "act_b", "line", "text"),
    [
        (100, 12, 1, 12, "actuator id 1 is already used"),
        (12, 12, 2, 6, "node id 12 is also a servo's node id"),
        (100, 128, 2, 11, "ids are 1..127, got 128"),
        (100, 12, 256, 12, "less than or equal to 255"),
        (0, 12, 2, 6, "node_id"),
    ],
)
def test_check_errors_carry_file_and_line(
    node: int, id_b: int, act_b: int, line: int, text: str
) -> None:
    source = CONFIG.replace("NODE", str(node)).replace("ID_B", str(id_b))
    source = source.replace("ACT_B", str(act_b))
    with pytest.raises(ConfigError) as info:
        load_config_text(source, "rig.yaml")
    message = str(info.value)
    assert f"rig.yaml:{line}:" in message, message
    assert text in message


def test_two_actuators_of_one_node_id_are_no_collision_but_one_actuator_twice_is() -> None:
    """A node with several outputs (an AP_Periph board): servos on one node id, each on its
    own actuator id, load; the same actuator id twice is refused (one command for both)."""
    source = CONFIG.replace("NODE", "100").replace("ID_B", "11").replace("ACT_B", "2")
    config = load_config_text(source, "rig.yaml")
    assert [s.can_id for s in config.servos] == [11, 11]
    with pytest.raises(ConfigError, match="actuator id 1 is already used"):
        load_config_text(source.replace("actuator_id: 2", "actuator_id: 1"), "rig.yaml")


def test_servos_of_one_node_take_their_own_status_and_share_its_node_status() -> None:
    """Two servos on node 11: actuator 2's Status is servo b's alone (a's counts nothing),
    the node's NodeStatus keeps both alive, an actuator nobody has is counted."""
    a, b = DroneCanServo(11, actuator_id=1), DroneCanServo(11, actuator_id=2)
    BridgeNode([a, b], NodeOptions(), (0, 1), 0.0)
    frames = library_frames(status_payload(actuator_id=2, position=0.5), 11, 0)
    for msg in frames:
        assert a.is_reply(msg) and b.is_reply(msg)
        a.decode(msg, 0.1)
        state_b = b.decode(msg, 0.1)
    assert state_b is not None and state_b.position_deg == pytest.approx(math.degrees(0.5), abs=0.1)
    assert a.errors["other_actuator"] == 0 and a.actuator_reported_at is None
    assert b.actuator_reported_at == 0.1
    [heartbeat] = library_frames(dronecan.uavcan.protocol.NodeStatus(uptime_sec=1), 11, 1)
    assert a.decode(heartbeat, 0.2) is not None and b.decode(heartbeat, 0.2) is not None
    assert a.is_liveness_only(heartbeat) and not a.is_liveness_only(frames[-1])
    for msg in library_frames(status_payload(actuator_id=7), 11, 2):
        a.decode(msg, 0.3)
    assert a.errors["other_actuator"] == 1


def test_budget_counts_packed_transfers_status_frames_and_every_nodes_heartbeat() -> None:
    """check and the scheduler count the same: 4 servos at 20 Hz in one 3-frame ArrayCommand
    transfer per slot, two frames per Status at 10 Hz each, NodeStatus from 4 servo nodes and
    the bridge; the bridge's GetNodeInfo answers at their bound (4 a second, 9 frames each);
    every frame 29-bit, counted at 8 bytes."""
    from mavservo.config import bus_loads, load_config
    from mavservo.config.views import servo_specs, timing_config
    from mavservo.scheduling.busload import frame_bits

    config = load_config("config/dronecan.yaml")
    frames_per_s = 20 * 3 + 4 * 10 * 2 + 5 * 1 + 4 * 9
    expected = frames_per_s * frame_bits(True, 8) / 1_000_000
    [load] = bus_loads(config)
    assert load.load == pytest.approx(expected)
    bus = config.can.buses[0]
    # the scheduler's own start-up budget: the same figure
    with can.Bus(interface="virtual", channel="dronecan-budget") as vbus:
        from mavservo.scheduling.runner import Scheduler

        scheduler = Scheduler(
            vbus,
            servo_specs(config, bus.name),
            timing_config(config, bus),
            node_options=bus.node_options(),
        )
        assert scheduler.worst_case_load == pytest.approx(expected)


def test_a_simulated_node_with_a_motor_fault_reports_warning_health_which_is_a_fault() -> None:
    from mavservo.config.simulation import Faults
    from mavservo.sim.servo import SimServo

    sim = SimServo("dronecan", 5, faults=Faults(over_temperature=True), reply_latency_s=0.0)
    profile = DroneCanServo(5)
    sim.poll(0.0)
    states = [profile.decode(msg, 0.1) for _, msg in sim.poll(0.1)]
    assert states[-1] is not None and Fault.OTHER in states[-1].faults
    assert profile.node_health == wire.HEALTH_WARNING
    sim.faults.over_temperature = False
    for step in range(2, 40):  # the next NodeStatus, a second later
        for _, msg in sim.poll(step * 0.05):
            profile.decode(msg, step * 0.05)
    assert profile.node_health == wire.HEALTH_OK
    assert profile.last_state is not None and not profile.last_state.faults


def test_another_node_on_the_bridges_id_is_reported_once() -> None:
    node = BridgeNode([DroneCanServo(11)], NodeOptions(node_id=100), (0, 1), 0.0)
    status = dronecan.uavcan.protocol.NodeStatus(uptime_sec=1, health=0, mode=0)
    for tid in range(3):
        [msg] = library_frames(status, 100, tid)
        node.receive(msg, float(tid))
    [notice] = node.take_notices()
    assert "bridge's node id 100" in notice
    assert node.counters["node_id_conflict"] == 3


@settings(max_examples=100, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from(["position", "unitless", "pwm"]),
            st.floats(min_value=-360, max_value=360, allow_nan=False),
        ),
        min_size=1,
        max_size=40,
    ),
    st.integers(0, 200),
)
def test_packed_commands_round_trip_through_the_package(
    commands: list[tuple[str, float]], first_actuator: int
) -> None:
    """Any servos and angles: the package reads back every actuator id, type and value (as
    float16 carries it), in transfers of at most 15, with valid CRCs and toggles."""
    servos = [
        DroneCanServo(
            1 + i,
            actuator_id=(first_actuator + i) % 256,
            command=kind,
            unitless_min_deg=-360,
            unitless_max_deg=360,
        )
        for i, (kind, _) in enumerate(commands)
    ]
    node = BridgeNode(servos, NodeOptions(node_id=127), (0, 1), 0.0)
    frames = node.pack([s.position_command(a) for s, (_, a) in zip(servos, commands, strict=True)])
    decoded, current = [], []
    for msg in frames:
        current.append(msg)
        if msg.data[-1] & 0x40:
            transfer = library_decode(current)
            assert len(transfer.payload.commands) <= 15
            decoded += list(transfer.payload.commands)
            current = []
    assert len(decoded) == len(servos)
    for servo, (kind, angle), got in zip(servos, commands, decoded, strict=True):
        assert got.actuator_id == servo.options.actuator_id
        value = {
            "position": math.radians(angle),
            "unitless": angle / 360,
            "pwm": float(round(1500 + angle / 360 * 500)),  # 1000..2000 us over +-360 deg
        }[kind]
        assert got.command_type == {"position": 1, "unitless": 0, "pwm": 4}[kind]
        assert got.command_value == pytest.approx(wire.float16(value), abs=1e-9)
        if kind == "pwm":  # whole microseconds, exact in float16 below 2048
            assert got.command_value == value


@settings(max_examples=100, deadline=None)
@given(
    st.floats(min_value=-6.0, max_value=6.0, allow_nan=False),
    st.one_of(st.just(math.nan), st.floats(min_value=-100, max_value=100)),
    st.integers(0, 31),
)
def test_any_status_from_the_package_decodes_to_its_float16_values(
    position: float, speed: float, tid: int
) -> None:
    profile = DroneCanServo(9, actuator_id=4)
    state = None
    for msg in library_frames(status_payload(4, position, speed), 9, tid):
        state = profile.decode(msg, 1.0)
    assert state is not None
    assert state.position_deg == pytest.approx(math.degrees(wire.float16(position)), abs=1e-6)
    if math.isnan(speed):
        assert math.isnan(state.velocity_dps)
    else:
        assert state.velocity_dps == pytest.approx(math.degrees(wire.float16(speed)), abs=1e-6)


def test_check_warns_about_actuator_id_0_unless_the_firmware_numbers_from_0() -> None:
    from mavservo.config.semantic import advisories

    source = CONFIG.replace("NODE", "100").replace("ID_B", "12").replace("ACT_B", "0")
    [warning] = [
        text
        for _, text in advisories(load_config_text(source, "rig.yaml"))
        if "actuator_id 0" in text
    ]
    assert "PX4 numbers actuators from 0" in warning
    px4 = source.replace("actuator_id: 0", "actuator_id: 0, firmware: px4")
    assert not [t for _, t in advisories(load_config_text(px4, "rig.yaml")) if "actuator_id 0" in t]
    with pytest.raises(ConfigError, match="numbers actuators from 1"):
        load_config_text(
            source.replace("actuator_id: 0", "actuator_id: 0, firmware: ardupilot, command: pwm"),
            "rig.yaml",
        )
    with pytest.raises(ConfigError, match="unitless and pwm commands only"):
        load_config_text(source.replace("actuator_id: 0", "firmware: ardupilot"), "rig.yaml")


def test_ardupilot_preset_scales_unitless_by_45_degrees_and_pwm_over_the_range() -> None:
    """AP_Periph reports ``radians(norm * 45)``: with the preset a command of 30 deg is the
    norm 2/3, which reads back as 30 deg; PWM maps the same range onto pwm_min..max us."""
    servo = DroneCanServo(20, firmware="ardupilot", command="unitless")
    actuator_id, kind, value = servo.command_tuple(30.0)
    assert (actuator_id, kind) == (1, wire.COMMAND_TYPE_UNITLESS)
    assert math.degrees(math.radians(value * 45)) == pytest.approx(30.0)
    pwm = DroneCanServo(20, firmware="ardupilot", command="pwm", pwm_min_us=1100, pwm_max_us=1900)
    assert pwm.command_tuple(-45.0)[1:] == (wire.COMMAND_TYPE_PWM, 1100.0)
    assert pwm.command_tuple(0.0)[2] == 1500.0 and pwm.command_tuple(45.0)[2] == 1900.0
    with pytest.raises(ValueError):
        pwm.command_tuple(50.0)  # outside the range: refused, never clamped
    generic = DroneCanServo(20, command="unitless")
    assert generic.command_tuple(30.0)[2] == pytest.approx(1 / 3)  # +-90 deg: reads half on AP


def test_get_node_info_carries_a_unique_id_of_machine_and_bus_and_the_package_version() -> None:
    """The answer's unique id is the one derived from the machine and the bus (stable across
    restarts, different for another bus or machine), or the option; the version is mavservo's."""
    import mavservo
    from mavservo.scheduling.bus_nodes import node_unique_id, software_version

    uid = node_unique_id("bus0", b"machine-a")
    assert uid == node_unique_id("bus0", b"machine-a") and len(uid) == 16 and any(uid)
    assert uid != node_unique_id("bus1", b"machine-a") != node_unique_id("bus0", b"machine-b")
    assert node_unique_id("bus0") == node_unique_id("bus0")  # this machine's id, stable
    major, minor, *_ = mavservo.__version__.split(".")
    assert software_version() == (int(major), int(minor))
    for options, expected in (
        (NodeOptions(), uid),
        (NodeOptions(unique_id="ab" * 16), b"\xab" * 16),
    ):
        node = DroneCanServo.bus_node([DroneCanServo(11)], options, software_version(), 0.0, uid)
        request = Transfer(
            transfer_id=1,
            source_node_id=42,
            dest_node_id=100,
            payload=dronecan.uavcan.protocol.GetNodeInfo.Request(),
            request_not_response=True,
            service_not_message=True,
        )
        [frame] = request.to_frames()
        asked = can.Message(arbitration_id=frame.message_id, is_extended_id=True, data=frame.bytes)
        assert node.receive(asked, 1.0)
        response = library_decode([m for m in node.due(1.0, "ok") if m.arbitration_id & 0x80])
        assert bytes(response.payload.hardware_version.unique_id) == expected
        version = response.payload.software_version
        assert (version.major, version.minor) == software_version()


def safety_states(frames: list[can.Message]) -> list[int]:
    return [
        int(library_decode([m]).payload.status)
        for m in frames
        if (m.arbitration_id >> 8) & 0xFFFF == wire.DTID_SAFETY_STATE
    ]


def test_safety_state_every_500_ms_on_at_failsafe_and_at_stop() -> None:
    """The bus's SafetyState as ArduPilot's flight controller sends it, decoded by the package:
    SAFETY_OFF every 500 ms; SAFETY_ON at once when every command of a slot is a failsafe one
    (``failsafe_and_stop``), OFF again when commands are not; SAFETY_ON once at stop."""
    servos = [DroneCanServo(20, firmware="ardupilot", command="pwm", actuator_id=n) for n in (1, 2)]
    options = NodeOptions(safety_state="safety_off", safety_on="failsafe_and_stop")
    node = BridgeNode(servos, options, (0, 1), 0.0)
    sent = [safety_states(node.due(t / 10, "ok")) for t in range(11)]
    assert sent == [[255], [], [], [], [], [255], [], [], [], [], [255]]
    commands = [s.position_command(0.0) for s in servos]
    node.pack(commands, in_failsafe=True)
    assert safety_states(node.due(1.05, "ok")) == [0]  # at once
    node.pack(commands, in_failsafe=False)
    assert safety_states(node.due(1.1, "ok")) == [255]
    assert safety_states(servos[0].shutdown_frames()) == [0]
    assert servos[1].shutdown_frames() == []  # once for the node
    quiet = BridgeNode([DroneCanServo(20)], NodeOptions(), (0, 1), 0.0)
    assert safety_states(quiet.due(0.0, "ok")) == [] and not quiet.take_notices()
    [warning] = BridgeNode(
        [DroneCanServo(20, firmware="ardupilot", command="unitless")], NodeOptions(), (0, 1), 0.0
    ).take_notices()
    assert "SAFETY_OFF" in warning and "will not move" in warning


@settings(max_examples=50, deadline=None)
@given(st.permutations(range(4)), st.integers(0, 31))
def test_interleaved_status_transfers_of_one_node_reach_each_servo(
    order: list[int], tid: int
) -> None:
    """Two actuators of node 11 report at once, their frames interleaved in any order that
    keeps each transfer's own order: each servo takes its own Status (a sibling's is skipped
    without reassembly), nothing is counted as an error."""
    a, b = DroneCanServo(11, actuator_id=1), DroneCanServo(11, actuator_id=2)
    BridgeNode([a, b], NodeOptions(), (0, 1), 0.0)
    first = library_frames(status_payload(actuator_id=1, position=0.25), 11, tid)
    second = library_frames(status_payload(actuator_id=2, position=-0.5), 11, (tid + 1) % 32)
    queues = [list(first), list(second)]
    frames = [queues[i % 2].pop(0) for i in order if queues[i % 2]]
    frames += queues[0] + queues[1]
    for msg in frames:
        a.decode(msg, 1.0)
        b.decode(msg, 1.0)
    assert a.last_state is not None and b.last_state is not None
    assert a.last_state.position_deg == pytest.approx(math.degrees(0.25), abs=0.1)
    assert b.last_state.position_deg == pytest.approx(math.degrees(-0.5), abs=0.1)
    assert not a.errors and not b.errors


def test_a_nodes_notices_reach_the_bridge_with_no_frame_on_the_bus() -> None:
    """The safety-state warning is raised at start: it must not wait for a received frame
    (a bus whose nodes are all dead would never tell)."""
    from mavservo.scheduling.runner import Scheduler

    servo = DroneCanServo(20, firmware="ardupilot", command="pwm")
    with can.Bus(interface="virtual", channel="dronecan-notices-quiet") as vbus:
        scheduler = Scheduler(
            vbus, [ServoSpec("s1", servo)], TimingConfig(), node_options={"dronecan": NodeOptions()}
        )
        [notice] = scheduler.take_notices()
        assert "SAFETY_OFF" in notice and "will not move" in notice
        assert scheduler.take_notices() == []
