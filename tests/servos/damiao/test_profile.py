"""Damiao DM-J profile: byte-exact vectors from the vendor's documents, every status code,
the lifecycle frames, hostile replies, and a cross-check against `damiao-motor` (PyPI).

Documents: Damiao "DM-J4310-2EC" manual V1.0 (2022-10-14): "反馈帧" (feedback) table,
"MIT模式下控制帧" and the position-velocity table (0x100 + ID, float p_des, float v_des, low
byte first), the fault list (8 over-voltage ... E overload) and the protections; Damiao's own
driver routines (dmBots motor-control-routine): FF x7 FC/FD/FE/FB, the 0x7FF register frames
``[id lo, id hi, 0x33/0x55/0xAA/0xCC, RID, value LE]``, RID 9 TIMEOUT and 10 CTRL_MODE.
"""

from __future__ import annotations

import math
import struct

import can
import pytest
from hypothesis import given
from hypothesis import strategies as st

from mavservo.servos import NO_FAULT, Fault, get_profile
from mavservo.servos.damiao.profile import DamiaoDM, DamiaoOptions, fault_from_status


def frame(arbitration_id: int, hex_data: str) -> can.Message:
    return can.Message(
        arbitration_id=arbitration_id, is_extended_id=False, data=bytes.fromhex(hex_data)
    )


def test_registered_under_its_yaml_name() -> None:
    assert get_profile("damiao-dm") is DamiaoDM


def test_mit_command_vector() -> None:
    """0 deg on a DM-J4310 (+-12.5 rad, +-30 rad/s, +-10 N m), kp 20, kd 1: POS 0x7FFF,
    VEL 0x7FF, KP int(20 * 4095 / 500) = 0x0A3, KD int(1 * 4095 / 5) = 0x333, T 0x7FF."""
    msg = DamiaoDM(1).position_command(0.0)
    assert (msg.arbitration_id, msg.is_extended_id) == (0x001, False)
    assert msg.data.hex() == "7fff7ff0a33337ff"


def test_position_velocity_command_vector() -> None:
    """0x100 + ID; p_des then v_des as float32, low byte first: 1 rad = 00 00 80 3F,
    2 pi rad/s (the 360 deg/s default) = DB 0F C9 40."""
    servo = DamiaoDM(3, DamiaoOptions(mode="position-velocity"))
    msg = servo.position_command(math.degrees(1.0))
    assert msg.arbitration_id == 0x103
    assert msg.data.hex() == "0000803f" + "db0fc940"
    limited = servo.position_command(0.0, max_speed_dps=math.degrees(1.0))
    assert limited.data.hex() == "00000000" + "0000803f"


def test_speed_limits_saturate_at_the_velocity_range_and_never_reach_zero() -> None:
    servo = DamiaoDM(1, DamiaoOptions(mode="position-velocity", v_max_rad_s=10.0))
    fast = servo.position_command(0.0, max_speed_dps=1e9)
    assert struct.unpack("<ff", bytes(fast.data))[1] == pytest.approx(10.0)
    still = servo.position_command(0.0, max_speed_dps=0.0)
    assert struct.unpack("<ff", bytes(still.data))[1] > 0


def test_startup_frames_write_mode_and_timeout_then_clear_and_enable() -> None:
    servo = DamiaoDM(1, DamiaoOptions(comm_timeout_ms=200))
    frames = [(m.arbitration_id, m.data.hex()) for m in servo.startup_frames()]
    assert frames == [
        (0x7FF, "0100550a01000000"),  # CTRL_MODE (RID 10) = 1, MIT
        (0x7FF, "01005509a00f0000"),  # TIMEOUT (RID 9) = 200 ms * 20 = 4000 = 0x0FA0
        (0x001, "fffffffffffffffb"),  # clear error
        (0x001, "fffffffffffffffc"),  # enable
    ]
    pv = DamiaoDM(2, DamiaoOptions(mode="position-velocity", comm_timeout_ms=50))
    assert [m.data.hex() for m in pv.startup_frames()][:2] == [
        "0200550a02000000",
        "02005509e8030000",
    ]


def test_release_and_shutdown_disable_and_poll_is_the_refresh_request() -> None:
    servo = DamiaoDM(5)
    assert [m.data.hex() for m in servo.release_frames()] == ["fffffffffffffffd"]
    assert [m.data.hex() for m in servo.shutdown_frames()] == ["fffffffffffffffd"]
    assert servo.set_zero_frame().data.hex() == "fffffffffffffffe"
    (poll,) = servo.telemetry_requests()
    assert (poll.arbitration_id, poll.data.hex()) == (0x7FF, "0500cc0000000000")


def test_feedback_vector_from_the_feedback_table() -> None:
    """D0 = ID | ERR << 4: 0x11 = enabled, id 1; T_MOS 25, T_Rotor 40."""
    servo = DamiaoDM(1)
    state = servo.decode(frame(0x000, "11ffff000fff1928"), 1.5)
    assert state is not None
    assert state.position_deg == pytest.approx(math.degrees(12.5))
    assert state.velocity_dps == pytest.approx(math.degrees(-30.0))
    assert state.current_a == pytest.approx(10.0 / 0.945)
    assert state.temperature_c == 40.0
    assert state.faults == NO_FAULT
    assert state.timestamp == 1.5
    assert not servo.needs_startup()


@pytest.mark.parametrize(
    ("status", "fault"),
    [
        (0x8, Fault.OVER_VOLTAGE),
        (0x9, Fault.LOW_VOLTAGE),
        (0xA, Fault.OVER_CURRENT),
        (0xB, Fault.OVER_TEMPERATURE),
        (0xC, Fault.OVER_TEMPERATURE),
        (0xD, Fault.COMMUNICATION_LOST),
        (0xE, Fault.OVER_CURRENT),
        (0x2, Fault.OTHER),
        (0x7, Fault.OTHER),
        (0xF, Fault.OTHER),
    ],
)
def test_every_status_code_is_a_named_fault(status: int, fault: Fault) -> None:
    assert fault_from_status(status) == fault
    servo = DamiaoDM(4)
    state = servo.decode(frame(0, f"{status:x}4" + "7fff7ff7ff1919"), 0.0)
    assert state is not None and state.faults == fault


@pytest.mark.parametrize(("status", "due"), [(0x0, True), (0xD, True), (0x1, False), (0xA, False)])
def test_disabled_or_timed_out_motor_asks_for_startup_again(status: int, due: bool) -> None:
    """Disabled (0) and communication lost (D) ask for the start-up frames again; a hardware
    fault does not (enabling into an over-current would only trip it again): the motor is
    enabled again once it reports plain "disabled", i.e. after the condition ended."""
    servo = DamiaoDM(1)
    servo.decode(frame(0, f"{status:x}1" + "7fff7ff7ff1919"), 0.0)
    assert servo.needs_startup() is due
    servo.startup_frames()
    assert not servo.needs_startup()


def test_is_reply_checks_the_payload_not_just_the_shared_master_id() -> None:
    one, two = DamiaoDM(1), DamiaoDM(2)
    feedback_of_two = frame(0x000, "127fff7ff7ff1919")
    assert two.is_reply(feedback_of_two)
    assert not one.is_reply(feedback_of_two)
    assert one.decode(feedback_of_two, 0.0) is None
    # other master id, extended, remote, short: not ours
    assert not one.is_reply(frame(0x011, "117fff7ff7ff1919"))
    ext = can.Message(arbitration_id=0, is_extended_id=True, data=bytes.fromhex("117fff7ff7ff1919"))
    assert not one.is_reply(ext)
    assert not one.is_reply(
        can.Message(arbitration_id=0, is_extended_id=False, is_remote_frame=True, dlc=8)
    )
    assert not one.is_reply(frame(0, "117fff7ff7ff19"))


def test_register_answers_are_ours_keep_the_state_and_share_a_key_with_the_write() -> None:
    servo = DamiaoDM(1, DamiaoOptions(master_id=0x11))
    servo.decode(frame(0x11, "117fff7ff7ff1919"), 1.0)
    write = servo.startup_frames()[1]
    ack = frame(0x11, "01005509a00f0000")
    assert servo.is_reply(ack)
    state = servo.decode(ack, 2.0)
    assert state is not None and state.timestamp == 2.0
    assert state.position_deg == pytest.approx(math.degrees(-12.5 + 32767 * 25 / 65535))
    assert servo.exchange_key(write) == servo.exchange_key(ack) == ("register", 9)
    feedback = frame(0x11, "117fff7ff7ff1919")
    for request in (servo.telemetry_requests()[0], *servo.startup_frames()[2:]):
        assert servo.exchange_key(request) == servo.exchange_key(feedback) == "feedback"
    assert servo.exchange_key(servo.position_command(0.0)) == "feedback"
    assert not servo.needs_startup()  # a register echo (byte 0 = id) is not "disabled"


@pytest.mark.parametrize("angle", [math.degrees(12.5) + 0.01, -720.0, math.nan, math.inf])
def test_angles_outside_the_models_range_are_refused(angle: float) -> None:
    with pytest.raises(ValueError):
        DamiaoDM(1).position_command(angle)


def test_a_smaller_model_range_refuses_what_the_default_accepts() -> None:
    small = DamiaoDM(1, DamiaoOptions(p_max_rad=math.pi))
    DamiaoDM(1).position_command(200.0)
    with pytest.raises(ValueError, match="outside"):
        small.position_command(200.0)


def test_ids_and_options_are_bounded() -> None:
    with pytest.raises(ValueError):
        DamiaoDM(0)
    with pytest.raises(ValueError):
        DamiaoOptions(kd=0.0)
    with pytest.raises(ValueError):
        DamiaoOptions(comm_timeout_ms=0)
    with pytest.raises(ValueError):
        DamiaoOptions(unknown_key=1)  # type: ignore[call-arg]


@given(st.binary(min_size=0, max_size=8), st.integers(0, 0x7FF), st.booleans())
def test_hostile_frames_never_raise(data: bytes, arbitration_id: int, extended: bool) -> None:
    servo = DamiaoDM(1)
    msg = can.Message(arbitration_id=arbitration_id, is_extended_id=extended, data=data)
    state = servo.decode(msg, 0.0)
    assert state is None or math.isfinite(state.position_deg)


# -- cross-check against damiao-motor (PyPI), an independent driver; used in tests only ------


@pytest.fixture
def virtual_pair():
    """Two ends of a python-can virtual bus: the library sends on one, we read the other."""
    channel = f"damiao-xcheck-{id(object())}"
    tx = can.Bus(interface="virtual", channel=channel)
    rx = can.Bus(interface="virtual", channel=channel)
    yield tx, rx
    tx.shutdown()
    rx.shutdown()


@given(st.floats(-math.degrees(12.5), math.degrees(12.5)))
def test_cross_check_mit_command_against_damiao_motor(angle: float) -> None:
    motor_module = pytest.importorskip("damiao_motor.core.motor")
    library = motor_module.DaMiaoMotor(1, 0, bus=None, motor_type="4310")
    ours = DamiaoDM(1).position_command(angle)
    assert bytes(ours.data) == library.encode_cmd_msg(math.radians(angle), 0.0, 0.0, 20.0, 1.0)


@given(st.integers(1, 15), st.integers(0, 0xF), st.binary(min_size=7, max_size=7))
def test_cross_check_feedback_decoder_against_damiao_motor(
    can_id: int, status: int, rest: bytes
) -> None:
    motor_module = pytest.importorskip("damiao_motor.core.motor")
    data = bytes([status << 4 | can_id]) + rest
    if data[1] <= 0x0F and data[2] in (0x33, 0x55, 0xAA):
        return  # a register answer's shape, decoded differently by design
    library = motor_module.DaMiaoMotor(can_id, 0, bus=None, motor_type="4310")
    theirs = library.decode_sensor_feedback(data)
    state = DamiaoDM(can_id).decode(frame(0, data.hex()), 0.0)
    assert state is not None
    assert theirs["status_code"] == status
    assert state.position_deg == pytest.approx(math.degrees(theirs["pos"]))
    assert state.velocity_dps == pytest.approx(math.degrees(theirs["vel"]))
    assert state.current_a * 0.945 == pytest.approx(theirs["torq"])
    assert state.temperature_c == max(theirs["t_mos"], theirs["t_rotor"])


def test_cross_check_lifecycle_and_registers_against_damiao_motor(virtual_pair) -> None:  # type: ignore[no-untyped-def]
    motor_module = pytest.importorskip("damiao_motor.core.motor")
    tx, rx = virtual_pair
    library = motor_module.DaMiaoMotor(1, 0, bus=tx, motor_type="4310")
    library.send_raw(library.encode_clear_error_msg())
    library.send_raw(library.encode_enable_msg())
    library.set_can_timeout(200)
    library.write_register(10, 1)
    library.send_raw(library.encode_disable_msg())
    sent = [rx.recv(timeout=1.0) for _ in range(5)]
    assert all(m is not None for m in sent)
    theirs = {(m.arbitration_id, bytes(m.data)) for m in sent if m is not None}
    servo = DamiaoDM(1, DamiaoOptions(comm_timeout_ms=200))
    ours = {(m.arbitration_id, bytes(m.data)) for m in servo.startup_frames()}
    ours |= {(m.arbitration_id, bytes(m.data)) for m in servo.release_frames()}
    assert ours == theirs


COLLIDING = """
mavlink: {url: sim}
can:
  buses:
    - {name: bus0, interface: aa55, channel: sim}
servos:
  - {name: a, profile: damiao-dm, can_id: 1, limits_deg: [-90, 90]}
  - {name: b, profile: damiao-dm, can_id: 17, limits_deg: [-90, 90]B_OPTIONS}
  - {name: c, profile: cubemars-ak-mit, can_id: 33, limits_deg: [-90, 90]C_OPTIONS}
channels: []
"""


def test_check_reports_replies_that_share_a_master_id_and_an_id_nibble() -> None:
    """Byte 0 carries only the id's low four bits: ids 1 and 17 on one master id cannot be
    told apart, nor a CubeMars MIT driver 33 (byte 0 = 0x21) from Damiao 1."""
    from mavservo.config import ConfigError, load_config_text

    text = COLLIDING.replace("B_OPTIONS", "").replace("C_OPTIONS", "")
    with pytest.raises(ConfigError) as info:
        load_config_text(text, "rig.yaml")
    message = str(info.value)
    assert "servo 'b' (damiao-dm id 17) collides" in message
    assert "data[0]=0x01/0x0F" in message
    # one master id per motor separates them
    fixed = text.replace(
        "[-90, 90]}\n  - {name: c", "[-90, 90], options: {master_id: 16}}\n  - {name: c"
    )
    fixed = fixed.replace(
        "can_id: 33, limits_deg: [-90, 90]}",
        "can_id: 33, limits_deg: [-90, 90], options: {master_id: 32}}",
    )
    assert len(load_config_text(fixed, "rig.yaml").servos) == 3


def test_feedback_overtaking_register_writes_is_not_credited_to_them() -> None:
    """The start-up's register writes go on 0x7FF, the lowest priority: on the bus the
    clear-error queued after them wins arbitration and its feedback arrives first. That
    feedback must answer the clear-error, not the oldest outstanding register write."""
    from dataclasses import dataclass

    from mavservo.scheduling.reply_matching import ReplyMatcher

    @dataclass
    class Expected:
        t_tx: float
        key: object

    servo = DamiaoDM(1)
    startup = servo.startup_frames()
    expected = [Expected(0.001 * i, servo.exchange_key(m)) for i, m in enumerate(startup)]
    feedback = frame(0x000, "017fff7ff7ff1919")  # status 0: the answer to the clear-error
    picked = ReplyMatcher().pick(expected, 0.005, servo.exchange_key(feedback))
    assert picked == 2  # the clear-error (FF x7 FB), not the CTRL_MODE write at index 0
    echo = frame(0x000, "0100550a01000000")
    assert ReplyMatcher().pick(expected, 0.006, servo.exchange_key(echo)) == 0
