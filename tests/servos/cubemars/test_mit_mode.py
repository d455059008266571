"""CubeMars AK MIT mode profile: vectors from the vendor's manual, faults, lifecycle, hostile
replies, and a cross-check against `TMotorCANControl` (PyPI).

Document: CubeMars "AK Series Actuator Driver Manual" V1.0.8, section 5.3 "MIT power mode
communication protocol" (pp. 48-49: special CAN codes, the receive and sending tables, the
module range table: AK80-9 +-12.5 rad, +-50 rad/s, +-18, kp 0..500, kd 0..5) and section 5.2.1
(error codes 1..6, shared with servo mode).
"""

from __future__ import annotations

import math

import can
import pytest
from hypothesis import given
from hypothesis import strategies as st

from mavservo.servos import NO_FAULT, Fault, get_profile
from mavservo.servos.cubemars.mit_mode import CubeMarsAKMit, CubeMarsMitOptions


def reply(hex_data: str, arbitration_id: int = 0) -> can.Message:
    return can.Message(
        arbitration_id=arbitration_id, is_extended_id=False, data=bytes.fromhex(hex_data)
    )


def test_registered_next_to_servo_mode() -> None:
    assert get_profile("cubemars-ak-mit") is CubeMarsAKMit
    assert get_profile("cubemars-ak").name == "cubemars-ak"


def test_command_vector_ak80_9() -> None:
    """0 deg, kp 20, kd 1 on an AK80-9: POS 0x7FFF, speed 0x7FF, KP 0x0A3, KD 0x333,
    current (torque) 0x7FF; standard frame on the motor id."""
    msg = CubeMarsAKMit(3).position_command(0.0)
    assert (msg.arbitration_id, msg.is_extended_id, len(msg.data)) == (3, False, 8)
    assert msg.data.hex() == "7fff7ff0a33337ff"


def test_special_codes_and_poll() -> None:
    servo = CubeMarsAKMit(3)
    assert [m.data.hex() for m in servo.startup_frames()] == ["fffffffffffffffc"]
    # "If you want to read the current state ... the command sent is ... 0XFC"
    assert [m.data.hex() for m in servo.telemetry_requests()] == ["fffffffffffffffc"]
    assert servo.set_zero_frame().data.hex() == "fffffffffffffffe"
    assert [m.data.hex() for m in servo.release_frames()] == ["fffffffffffffffd"]
    # released: polling with FC would re-enter motor mode, so no poll until the next start-up
    assert servo.telemetry_requests() == []
    servo.startup_frames()
    assert servo.telemetry_requests() != []


def test_reply_vector_sending_table() -> None:
    """D0 driver id 3, position 0xFFFF (+12.5 rad), speed 0 (-50 rad/s), current 0xFFF
    (+18), temperature 35 degC, error 0."""
    state = CubeMarsAKMit(3).decode(reply("03ffff000fff2300"), 2.0)
    assert state is not None
    assert state.position_deg == pytest.approx(math.degrees(12.5))
    assert state.velocity_dps == pytest.approx(math.degrees(-50.0))
    assert state.current_a == pytest.approx(18.0 / 0.819)
    assert state.temperature_c == 35.0
    assert state.faults == NO_FAULT


@pytest.mark.parametrize(
    ("code", "fault"),
    [
        (1, Fault.OVER_TEMPERATURE),
        (2, Fault.OVER_CURRENT),
        (3, Fault.OVER_VOLTAGE),
        (4, Fault.LOW_VOLTAGE),
        (5, Fault.ENCODER),
        (6, Fault.PHASE_IMBALANCE),
        (7, Fault.OTHER),
        (0xFF, Fault.OTHER),
    ],
)
def test_error_codes(code: int, fault: Fault) -> None:
    state = CubeMarsAKMit(3).decode(reply(f"037fff7ff7ff23{code:02x}"), 0.0)
    assert state is not None and state.faults == fault


def test_is_reply_checks_id_byte_and_master_id() -> None:
    servo = CubeMarsAKMit(3, CubeMarsMitOptions(master_id=0x10))
    assert servo.is_reply(reply("037fff7ff7ff2300", 0x10))
    assert not servo.is_reply(reply("047fff7ff7ff2300", 0x10))
    assert not servo.is_reply(reply("037fff7ff7ff2300", 0x00))
    assert servo.is_reply(reply("037fff7ff7ff", 0x10))  # DLC 6: the manual's reply table
    assert not servo.is_reply(reply("037fff7ff7", 0x10))


@pytest.mark.parametrize("angle", [math.degrees(12.5) + 0.1, math.nan, -math.inf])
def test_out_of_range_angles_are_refused(angle: float) -> None:
    with pytest.raises(ValueError):
        CubeMarsAKMit(1).position_command(angle)


def test_a_models_range_comes_from_its_options() -> None:
    ak10 = CubeMarsAKMit(1, CubeMarsMitOptions(p_max_rad=1.0))
    with pytest.raises(ValueError, match="outside"):
        ak10.position_command(90.0)
    assert CubeMarsAKMit(1).position_command(90.0).data.hex() != ""


@given(st.binary(max_size=8), st.integers(0, 0x7FF))
def test_hostile_frames_never_raise(data: bytes, arbitration_id: int) -> None:
    msg = can.Message(arbitration_id=arbitration_id, is_extended_id=False, data=data)
    state = CubeMarsAKMit(1).decode(msg, 0.0)
    assert state is None or math.isfinite(state.position_deg)


@given(st.floats(-math.degrees(12.4), math.degrees(12.4)))
def test_cross_check_against_tmotorcancontrol(angle: float) -> None:
    """TMotorCANControl lays out the same bits; it scales by 2**bits / span where the manual
    scales by (2**bits - 1) / span (see tests/servos/test_mit_packing.py), so the position may
    differ by one count and we follow the manual; the gains and the zero torque land on the same
    bits."""
    mit_can = pytest.importorskip("TMotorCANControl.mit_can")
    # object.__new__: the class's own __new__ opens can0 with sudo; we only want its codec
    manager = object.__new__(mit_can.CAN_Manager)
    manager.debug = False
    sent: list[list[int]] = []
    manager.send_MIT_message = lambda motor_id, data: sent.append(list(data))  # type: ignore[method-assign]
    manager.MIT_controller(1, "AK80-9", math.radians(angle), 0.0, 20.0, 1.0, 0.0)
    theirs = bytes(sent[0])
    ours = bytes(CubeMarsAKMit(1).position_command(angle).data)
    p_ours, p_theirs = ours[0] << 8 | ours[1], theirs[0] << 8 | theirs[1]
    assert abs(p_ours - p_theirs) <= 1
    kp_ours = (ours[3] & 0xF) << 8 | ours[4]
    kp_theirs = (theirs[3] & 0xF) << 8 | theirs[4]
    assert abs(kp_ours - kp_theirs) <= 1
    # their decoder reads our device-side replies as we do
    data = bytes(CubeMarsAKMit(1).position_command(angle).data)
    frame = bytes([1]) + data[:2] + bytes([0x7F, 0xF7, 0xFF, 30, 0])
    parsed = manager.parse_MIT_message(frame, "AK80-9")
    state = CubeMarsAKMit(1).decode(reply(frame.hex()), 0.0)
    assert state is not None
    assert state.position_deg == pytest.approx(math.degrees(parsed.position), abs=1e-6)
