"""ODrive CANSimple profile (firmware 0.6): byte-exact vectors from ODrive's CAN protocol
documentation, every documented axis error bit, the lifecycle frames, hostile frames, and
cross-checks against ODrive's own DBC file read with cantools and against ``odrive-can``
(PyPI), both used only here.

Documents: ODrive "CAN Protocol" (``can_id = node_id << 5 | cmd_id``, e.g. node 1, Set_Input_Pos
0x0C -> 0x2C; all multi-byte values little-endian; the heartbeat a node sends every 100 ms by
default, as in the documented candump ``001 [8] 00 00 00 00 01 00 00 00``: node 0, no error,
IDLE); ODrive's DBC ``odrive-cansimple-0.6.10.dbc`` (message layouts and lengths, the
Set_Input_Pos feed-forward scale 0.001, the axis error and state value tables), which the
``odrive-can`` wheel ships and the tests load from the installed package, never a copy.
"""

from __future__ import annotations

import functools
import math
import struct

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mavservo.servos import NO_FAULT, Fault, get_profile
from mavservo.servos.odrive.profile import (
    ERROR_FAULTS,
    ODrive,
    ODriveOptions,
    fault_from_error,
)


def frame(arbitration_id: int, hex_data: str) -> can.Message:
    return can.Message(
        arbitration_id=arbitration_id, is_extended_id=False, data=bytes.fromhex(hex_data)
    )


def dbc():  # type: ignore[no-untyped-def]
    """ODrive's DBC for firmware 0.6.10, as the installed ``odrive-can`` wheel ships it."""
    utils = pytest.importorskip("odrive_can.utils")
    return _load_dbc(utils)


@functools.cache
def _load_dbc(utils):  # type: ignore[no-untyped-def]
    return utils.get_dbc("odrive-cansimple-0.6.10")


def test_registered_under_its_yaml_name() -> None:
    assert get_profile("odrive") is ODrive


def test_set_input_pos_vector() -> None:
    """Node 1, Set_Input_Pos (0x0C): 0x01 << 5 | 0x0C = 0x2C (the protocol page's example);
    1.0 turn = float32 00 00 80 3F, both feed-forwards 0."""
    msg = ODrive(1).position_command(180.0)
    assert (msg.arbitration_id, msg.is_extended_id) == (0x2C, False)
    assert msg.data.hex() == "0000003f" + "0000" + "0000"  # 0.5 turn
    geared = ODrive(1, motor_turns_per_rev=2.0).position_command(180.0)
    assert geared.data.hex() == "0000803f00000000"  # 1 motor turn through a 1:2 gear


def test_startup_frames_clear_errors_position_control_limits_closed_loop() -> None:
    servo = ODrive(1)
    frames = [(m.arbitration_id, m.data.hex()) for m in servo.startup_frames()]
    assert frames == [
        (0x38, "00"),  # Clear_Errors, identify 0
        (0x2B, "03000000" + "01000000"),  # POSITION_CONTROL, PASSTHROUGH
        (0x2F, "00000040" + "00002041"),  # Set_Limits 2.0 turn/s, 10.0 A
        (0x27, "08000000" + "00000000"),  # Set_Axis_State CLOSED_LOOP_CONTROL
    ]
    trap = ODrive(2, input_mode="trap-traj", traj_accel_turns_s2=4.0)
    assert [(m.arbitration_id, m.data.hex()) for m in trap.startup_frames()][1:5] == [
        (0x4B, "03000000" + "05000000"),  # TRAP_TRAJ
        (0x4F, "00000040" + "00002041"),
        (0x51, "00000040" + "00000000"),  # Set_Traj_Vel_Limit 2.0 turn/s
        (0x52, "00008040" + "00008040"),  # Set_Traj_Accel_Limits 4.0, 4.0 turn/s^2
    ]


def test_watchdog_written_only_with_both_endpoint_ids() -> None:
    """RxSdo (0x04): opcode 1 write, endpoint id u16, reserved, value; ids are per firmware."""
    servo = ODrive(3, watchdog_timeout_s=0.5, watchdog_timeout_endpoint=200,
                   enable_watchdog_endpoint=201)  # fmt: skip
    first, second = servo.startup_frames()[:2]
    assert (first.arbitration_id, first.data.hex()) == (0x64, "01c800000000003f")  # 0.5 s
    assert (second.arbitration_id, second.data.hex()) == (0x64, "01c9000001000000")  # True
    off = ODrive(3, watchdog_timeout_s=0.0, watchdog_timeout_endpoint=200,
                 enable_watchdog_endpoint=201)  # fmt: skip
    assert off.startup_frames()[0].data.hex() == "01c9000000000000"  # disabled, no timeout
    assert all(m.arbitration_id != 0x64 for m in ODrive(3).startup_frames())
    with pytest.raises(ValueError, match="go together"):
        ODriveOptions(watchdog_timeout_endpoint=200)
    with pytest.raises(ValueError, match="must differ"):
        ODriveOptions(watchdog_timeout_endpoint=200, enable_watchdog_endpoint=200)


def test_release_and_shutdown_set_idle() -> None:
    servo = ODrive(4)
    assert [(m.arbitration_id, m.data.hex()) for m in servo.release_frames()] == [
        (0x87, "0100000000000000")
    ]
    assert [m.data.hex() for m in servo.shutdown_frames()] == ["0100000000000000"]
    assert servo.telemetry_requests() == []


def test_heartbeat_from_the_documented_candump_asks_for_startup() -> None:
    """``001 [8] 00 00 00 00 01 00 00 00``: node 0, no error, IDLE."""
    servo = ODrive(0)
    state = servo.decode(frame(0x001, "0000000001000000"), 2.0)
    assert state is not None and state.faults == NO_FAULT and state.timestamp == 2.0
    assert servo.axis_state == 1 and servo.needs_startup()
    servo.startup_frames()
    assert not servo.needs_startup()
    servo.decode(frame(0x001, "0000000008000100"), 2.1)  # closed loop, trajectory done
    assert not servo.needs_startup() and servo.trajectory_done


def test_watchdog_expiry_is_communication_lost_and_asks_for_startup() -> None:
    servo = ODrive(5)
    state = servo.decode(frame(0xA1, "0000000101030000"), 1.0)
    assert state is not None and state.faults == Fault.COMMUNICATION_LOST
    assert servo.needs_startup()


def test_encoder_estimates_in_output_degrees() -> None:
    servo = ODrive(2, motor_turns_per_rev=8.0)
    state = servo.decode(frame(0x49, "0000803f" + "000000c0"), 0.5)  # 1 turn, -2 turn/s
    assert state is not None
    assert state.position_deg == pytest.approx(45.0)
    assert state.velocity_dps == pytest.approx(-90.0)


def test_iq_temperature_bus_and_error_messages() -> None:
    servo = ODrive(1)
    servo.decode(frame(0x34, struct.pack("<ff", 1.0, 2.5).hex()), 0.0)  # Get_Iq
    servo.decode(frame(0x35, struct.pack("<ff", 41.0, math.nan).hex()), 0.0)  # no motor NTC
    state = servo.decode(frame(0x37, struct.pack("<ff", 24.0, 0.5).hex()), 0.0)
    assert state is not None
    assert (state.current_a, state.temperature_c, state.voltage_v) == (2.5, 41.0, 24.0)
    state = servo.decode(frame(0x23, struct.pack("<II", 0x20, 0x1000).hex()), 0.0)
    assert state is not None and state.faults == Fault.DRIVER | Fault.OVER_CURRENT


@pytest.mark.parametrize(("bit", "fault"), sorted(ERROR_FAULTS.items()))
def test_every_documented_error_bit_is_a_named_fault(bit: int, fault: Fault) -> None:
    assert fault_from_error(bit) == fault
    servo = ODrive(1)
    state = servo.decode(frame(0x21, struct.pack("<IBBBx", bit, 1, 0, 0).hex()), 0.0)
    assert state is not None and state.faults == fault


def test_unknown_error_bits_are_other_and_not_calibrated_is_uncalibrated() -> None:
    assert fault_from_error(0x80) == Fault.OTHER
    assert fault_from_error(0x80000000 | 0x100) == Fault.OTHER | Fault.OVER_VOLTAGE
    servo = ODrive(1)
    state = servo.decode(frame(0x21, "00000000" + "010e0000"), 0.0)  # IDLE, NOT_CALIBRATED
    assert state is not None and state.faults == Fault.UNCALIBRATED


def test_is_reply_takes_only_this_nodes_pushes() -> None:
    servo = ODrive(1)
    assert servo.is_reply(frame(0x29, "00" * 8))
    assert not servo.is_reply(frame(0x49, "00" * 8))  # node 2
    assert not servo.is_reply(frame(0x2C, "00" * 8))  # our own Set_Input_Pos
    assert not servo.is_reply(frame(0x29, "00" * 7))
    remote = can.Message(arbitration_id=0x29, is_extended_id=False, is_remote_frame=True)
    assert not servo.is_reply(remote)
    ext = can.Message(arbitration_id=0x29, is_extended_id=True, data=bytes(8))
    assert not servo.is_reply(ext)


def test_non_finite_floats_keep_the_last_value() -> None:
    servo = ODrive(1)
    servo.decode(frame(0x29, struct.pack("<ff", 0.25, 0.0).hex()), 0.0)
    state = servo.decode(frame(0x29, struct.pack("<ff", math.nan, math.inf).hex()), 0.1)
    assert state is not None and state.position_deg == 90.0 and state.velocity_dps == 0.0


@pytest.mark.parametrize("angle", [-180.01, 180.01, math.nan, math.inf])
def test_angles_outside_the_servos_range_are_refused(angle: float) -> None:
    with pytest.raises(ValueError):
        ODrive(1).position_command(angle)


def test_the_range_and_ids_come_from_the_options() -> None:
    servo = ODrive(1, min_position_deg=-10.0, max_position_deg=720.0)
    servo.position_command(719.0)
    with pytest.raises(ValueError):
        servo.position_command(-11.0)
    with pytest.raises(ValueError):
        ODriveOptions(min_position_deg=10.0, max_position_deg=10.0)
    with pytest.raises(ValueError, match="must contain 0"):
        ODriveOptions(min_position_deg=10.0, max_position_deg=20.0)
    ODrive(0), ODrive(62)
    with pytest.raises(ValueError):
        ODrive(63)  # 0x3F: the unaddressed node id of firmware 0.6
    with pytest.raises(ValueError):
        ODriveOptions(velocity_limit_turns_s=0.0)


def test_identifiers_claim_the_whole_node_block() -> None:
    ids = ODrive(10).identifiers()
    rmd_request = can.Message(arbitration_id=0x141, is_extended_id=False, data=bytes(8))
    assert any(i.direction == "to_servo" and i.matches(rmd_request) for i in ids)
    outside = can.Message(arbitration_id=0x160, is_extended_id=False, data=bytes(8))
    assert not any(i.matches(outside) for i in ids)


def test_check_reports_another_familys_frames_in_an_odrive_node_block() -> None:
    from mavservo.config import ConfigError, load_config_text

    text = """
mavlink: {url: sim}
can:
  buses:
    - {name: bus0, interface: aa55, channel: sim}
servos:
  - {name: rmd, profile: rmd-x, can_id: 1, limits_deg: [-90, 90]}
  - {name: od, profile: odrive, can_id: NODE, limits_deg: [-90, 90]}
channels: []
"""
    with pytest.raises(ConfigError) as info:
        load_config_text(text.replace("NODE", "10"), "rig.yaml")  # 0x140..0x15F: 0x141
    assert "'od'" in str(info.value) and "'rmd'" in str(info.value)
    assert len(load_config_text(text.replace("NODE", "11"), "rig.yaml").servos) == 2


def test_budget_counts_the_heartbeat_and_auxiliary_messages() -> None:
    assert ODrive(1).unsolicited_hz() == pytest.approx(10.0)
    assert ODrive(1, heartbeat_ms=50, aux_rate_ms=100).unsolicited_hz() == pytest.approx(50.0)


@settings(deadline=None)  # cantools and a loaded machine: timing is not judged here
@given(
    st.binary(min_size=0, max_size=8),
    st.integers(0, 0x7FF),
    st.booleans(),
)
def test_hostile_frames_never_raise(data: bytes, arbitration_id: int, extended: bool) -> None:
    servo = ODrive(arbitration_id >> 5 if arbitration_id >> 5 <= 62 else 1)
    msg = can.Message(arbitration_id=arbitration_id, is_extended_id=extended, data=data)
    state = servo.decode(msg, 0.0)
    assert (state is None) == (not servo.is_reply(msg))
    servo.needs_startup()


# -- ODrive's DBC (read with cantools) --------------------------------------------------------


@settings(deadline=None)  # cantools and a loaded machine: timing is not judged here
@given(st.floats(-180.0, 180.0), st.sampled_from([1.0, 8.0, 50.0]), st.integers(0, 7))
def test_set_input_pos_against_the_dbc(angle: float, ratio: float, node: int) -> None:
    message = dbc().get_message_by_frame_id(node << 5 | 0x0C)
    ours = ODrive(node, motor_turns_per_rev=ratio).position_command(angle)
    assert message.name == f"Axis{node}_Set_Input_Pos" and ours.arbitration_id == message.frame_id
    decoded = message.decode(bytes(ours.data))
    turns = struct.unpack("<f", struct.pack("<f", angle / 360 * ratio))[0]
    assert decoded == {"Input_Pos": turns, "Vel_FF": 0.0, "Torque_FF": 0.0}
    theirs = message.encode({"Input_Pos": turns, "Vel_FF": 0.0, "Torque_FF": 0.0})
    assert theirs == bytes(ours.data)


@pytest.mark.parametrize("mode", ["passthrough", "pos-filter", "trap-traj"])
def test_lifecycle_frames_against_the_dbc(mode: str) -> None:
    db = dbc()
    servo = ODrive(3, input_mode=mode, watchdog_timeout_endpoint=7, enable_watchdog_endpoint=8)
    names = []
    for msg in servo.startup_frames() + servo.release_frames():
        message = db.get_message_by_frame_id(msg.arbitration_id)
        assert len(msg.data) == message.length, message.name
        values = message.decode(bytes(msg.data), decode_choices=False)
        assert message.encode(values) == bytes(msg.data), message.name
        names.append((message.name.split("_", 1)[1], values))
    expected_mode = {"passthrough": 1, "pos-filter": 3, "trap-traj": 5}[mode]
    assert ("Set_Controller_Mode", {"Control_Mode": 3, "Input_Mode": expected_mode}) in names
    assert names[-2] == ("Set_Axis_State", {"Axis_Requested_State": 8})
    assert names[-1] == ("Set_Axis_State", {"Axis_Requested_State": 1})
    assert ("Clear_Errors", {"Identify": 0}) in names
    sdo = [values for name, values in names if name == "RxSdo"]
    assert [(v["Opcode"], v["Endpoint_ID"]) for v in sdo] == [(1, 7), (1, 8)]


@settings(deadline=None)  # cantools and a loaded machine: timing is not judged here
@given(
    st.integers(0, 0xFFFFFFFF),
    st.sampled_from([0, 1, 8, 11]),
    st.integers(0, 16),
    st.integers(0, 1),
    st.floats(-1e4, 1e4, width=32),
    st.floats(-1e3, 1e3, width=32),
)
def test_pushes_encoded_by_the_dbc_decode_the_same(
    error: int, state: int, result: int, done: int, pos: float, vel: float
) -> None:
    db = dbc()
    servo = ODrive(1)
    heartbeat = db.get_message_by_name("Axis1_Heartbeat").encode(
        {
            "Axis_Error": error,
            "Axis_State": state,
            "Procedure_Result": result,
            "Trajectory_Done_Flag": done,
        }  # fmt: skip
    )
    decoded = servo.decode(frame(0x21, heartbeat.hex()), 0.0)
    assert decoded is not None
    expected = fault_from_error(error) | (Fault.UNCALIBRATED if result == 14 else NO_FAULT)
    assert decoded.faults == expected
    assert (servo.axis_state, servo.procedure_result) == (state, result)
    assert servo.trajectory_done == bool(done)
    assert servo.needs_startup() == (state == 1)
    estimates = db.get_message_by_name("Axis1_Get_Encoder_Estimates").encode(
        {"Pos_Estimate": pos, "Vel_Estimate": vel}
    )
    decoded = servo.decode(frame(0x29, estimates.hex()), 0.0)
    assert decoded is not None
    assert decoded.position_deg == pytest.approx(pos * 360.0)
    assert decoded.velocity_dps == pytest.approx(vel * 360.0)


def test_every_documented_error_bit_is_in_the_dbc_value_table() -> None:
    """The DBC (0.6.10) names every bit mapped here except REQUESTED_CURRENT_TOO_HIGH
    (0x20000), which ODrive added in 0.6.11 (``odrive.enums.ODriveError``)."""
    signal = dbc().get_message_by_name("Axis0_Heartbeat").get_signal_by_name("Axis_Error")
    documented = {int(value) for value in signal.choices if int(value)}
    assert set(ERROR_FAULTS) - documented == {0x20000}
    assert documented <= set(ERROR_FAULTS)


# -- odrive-can (PyPI) ------------------------------------------------------------------------


@pytest.fixture
def virtual_pair():  # type: ignore[no-untyped-def]
    """Two ends of a python-can virtual bus: the library sends on one, we read the other."""
    channel = f"odrive-xcheck-{id(object())}"
    tx = can.Bus(interface="virtual", channel=channel)
    rx = can.Bus(interface="virtual", channel=channel)
    yield tx, rx
    tx.shutdown()
    rx.shutdown()


def test_cross_check_frames_against_odrive_can(virtual_pair) -> None:  # type: ignore[no-untyped-def]
    odrive_module = pytest.importorskip("odrive_can.odrive")
    tx, rx = virtual_pair
    library = odrive_module.ODriveCAN(axis_id=3, can_bus=tx)
    library.clear_errors()
    library.set_controller_mode("POSITION_CONTROL", "TRAP_TRAJ")
    library.set_limits(8.0, 12.0)
    library.set_traj_vel_limit(8.0)
    library.set_traj_accel_limits(40.0, 40.0)
    library.set_axis_state_no_wait("CLOSED_LOOP_CONTROL")
    library.set_input_pos(0.75)
    library.set_axis_state_no_wait("IDLE")
    theirs = [rx.recv(timeout=1.0) for _ in range(8)]
    assert all(m is not None for m in theirs)
    servo = ODrive(
        3,
        input_mode="trap-traj",
        velocity_limit_turns_s=8.0,
        current_limit_a=12.0,
        traj_accel_turns_s2=40.0,
        motor_turns_per_rev=3.0,
    )
    ours = [*servo.startup_frames(), servo.position_command(90.0), *servo.release_frames()]
    assert [(m.arbitration_id, bytes(m.data)) for m in ours] == [
        (m.arbitration_id, bytes(m.data)) for m in theirs if m is not None
    ]


def test_cross_check_our_devices_pushes_with_odrive_can() -> None:
    odrive_module = pytest.importorskip("odrive_can.odrive")
    from mavservo.sim.servo import SimServo

    servo = ODrive(2)
    sim = SimServo("odrive", 2, seed=1, reply_latency_s=0.0)
    for msg in servo.startup_frames():
        sim.receive(msg, 0.0)
    sim.receive(servo.position_command(45.0), 0.0)
    sim.poll(0.3)
    pushes = [reply for _, reply in sim.poll(0.4)]  # inside the 0.5 s watchdog
    names = {}
    for msg in pushes:
        decoded = odrive_module.CanMsg(msg)
        names[decoded.name] = decoded.data
    assert names["Heartbeat"]["Axis_State"] == "CLOSED_LOOP_CONTROL"
    assert names["Heartbeat"]["Axis_Error"] == "NONE"
    assert names["Get_Encoder_Estimates"]["Pos_Estimate"] == pytest.approx(0.125, abs=1e-3)


def test_bad_options_in_a_config_are_refused_with_file_and_line() -> None:
    from mavservo.config import ConfigError, load_config_text

    text = """mavlink: {url: sim}
can:
  buses:
    - {name: bus0, interface: aa55, channel: sim}
servos:
  - name: od
    profile: odrive
    can_id: 1
    limits_deg: [-90, 90]
    options: {watchdog_timeout_endpoint: 200, node: 3}
channels: []
"""
    with pytest.raises(ConfigError) as info:
        load_config_text(text, "rig.yaml")
    assert "rig.yaml:10" in str(info.value)
