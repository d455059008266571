"""The LK-Tech profile against LK's document (reference vectors), an independent LK driver
(pylkmotor) and its own lifecycle: motor on (0x88) before the first command after an off."""

from __future__ import annotations

import math

import can
import pytest
from hypothesis import given
from hypothesis import strategies as st

from mavservo.servos import Fault, LkTech, RmdX
from mavservo.servos.lk import profile as lk_module
from tests.support.vectors import checked, load, profile_mismatches


def _frame(hexdata: str, arb_id: int = 0x141) -> can.Message:
    return can.Message(arbitration_id=arb_id, is_extended_id=False, data=bytes.fromhex(hexdata))


def test_a_decoder_reading_iq_as_0_01_a_fails_the_vectors(monkeypatch) -> None:
    """The old reading (iq x 0.01 A) against the file tests/servos/test_reference_vectors.py runs:
    caught."""
    monkeypatch.setitem(lk_module.IQ_FULL_SCALE_A, "MF", 2048 * 0.01)
    document = load("lk")
    failures = [m for _, v in checked("lk", "profile") for m in profile_mismatches(document, v)]
    assert any("current_a = 20.48" in failure for failure in failures), failures


def test_old_decoder_readings_are_gone() -> None:
    """What the issue measured at c3ae82c, now read as LK's document says."""
    profile = LkTech(1)
    state = profile.decode(_frame("9C 32 00 08 5A 00 00 20"), 0.0)
    assert state is not None
    assert state.current_a == pytest.approx(16.5)  # was 20.48
    assert state.position_deg == pytest.approx(180.0)  # was 8192
    state = profile.decode(_frame("92 28 23 00 00 00 00 00"), 0.0)
    assert state is not None and state.position_deg == pytest.approx(90.0)  # was 0.0
    state = profile.decode(_frame("9A 28 60 09 00 00 10 00"), 0.0)
    assert state is not None
    assert state.voltage_v == pytest.approx(24.0)  # was 0.0 or 15.0
    assert state.faults == Fault(0)  # motor off was OVER_CURRENT
    state = profile.decode(_frame("9A 28 08 07 00 00 00 01"), 0.0)
    assert state is not None and state.faults == Fault.LOW_VOLTAGE  # was OVERSPEED


def test_motor_on_goes_out_at_start_up_and_again_after_a_9a_says_off() -> None:
    profile = LkTech(4)
    [frame] = profile.startup_frames()
    assert (frame.arbitration_id, bytes(frame.data)) == (0x144, bytes.fromhex("88" + "00" * 7))
    assert not profile.needs_startup()
    profile.decode(_frame("9A 28 60 09 00 00 10 00", 0x144), 0.0)
    assert profile.needs_startup()
    profile.decode(_frame("88 00 00 00 00 00 00 00", 0x144), 0.1)
    assert not profile.needs_startup()
    profile.decode(_frame("9A 28 60 09 00 00 10 00", 0x144), 0.2)
    profile.decode(_frame("9A 28 60 09 00 00 00 00", 0x144), 0.3)
    assert not profile.needs_startup()
    [off] = profile.release_frames()
    assert bytes(off.data) == bytes.fromhex("80" + "00" * 7)


def test_clear_errors_goes_before_motor_on_only_when_asked() -> None:
    assert [f.data[0] for f in LkTech(1, clear_errors_on_start=True).startup_frames()] == [
        0x9B,
        0x88,
    ]
    assert [f.data[0] for f in LkTech(1).startup_frames()] == [0x88]


def test_polls_read_the_multi_turn_angle_first_then_interleave() -> None:
    profile = LkTech(2, fault_poll_every=4, multi_turn_poll_every=3)
    commands = []
    for _ in range(8):
        commands.append(profile.telemetry_requests()[0].data[0])
        profile.poll_sent()
    assert commands == [0x92, 0x9C, 0x92, 0x9A, 0x9C, 0x92, 0x9C, 0x9A]


def test_encoder_counts_unwrap_against_the_multi_turn_angle() -> None:
    profile = LkTech(1)  # 14-bit encoder
    profile.decode(_frame("92 B8 88 00 00 00 00 00"), 0.0)  # 350.00 deg
    state = profile.decode(_frame("9C 19 00 00 00 00 38 00"), 0.1)  # count 56: 1.23 deg
    assert state is not None
    assert state.position_deg == pytest.approx(360 + 56 * 360 / 16384)
    profile.decode(_frame("92 F0 D8 FF FF FF FF FF"), 0.2)  # -100.00 deg
    state = profile.decode(_frame("9C 19 00 00 00 00 00 39"), 0.3)  # count 14592: 320.6 deg
    assert state is not None
    assert state.position_deg == pytest.approx(14592 * 360 / 16384 - 360)


def test_lk_refuses_v4_replies_and_rmd_x_refuses_lk_replies() -> None:
    assert LkTech(1).decode(_frame("9C 32 00 08 5A 00 00 20", 0x241), 0.0) is None
    assert RmdX(1).decode(_frame("9C 32 00 08 5A 00 00 20", 0x141), 0.0) is None
    assert LkTech(1).decode(_frame("9C 32 00 08", 0x141), 0.0) is None  # short: not a reply


def test_the_options_refuse_unknown_models_and_encoders() -> None:
    for bad in ({"model": "MX"}, {"encoder_bits": 18}, {"status_1": "v3"}):
        with pytest.raises(ValueError):
            LkTech(1, **bad)


# -- an independent implementation: pylkmotor (PyPI), its parsers and its sent frames --------


def _pylk():
    module = pytest.importorskip("pylkmotor.LKMotor")
    return module.LKMotor.__new__(module.LKMotor)  # its parsers need no bus


@given(
    temperature=st.integers(-128, 127),
    iq=st.integers(-2048, 2048),
    speed=st.integers(-32768, 32767),
    count=st.integers(0, 16383),
    model=st.sampled_from(["MF", "MG"]),
)
def test_pylkmotor_reads_closed_loop_replies_alike(temperature, iq, speed, count, model) -> None:
    theirs = _pylk()
    data = bytes([0x9C, temperature & 0xFF])
    data += iq.to_bytes(2, "little", signed=True) + speed.to_bytes(2, "little", signed=True)
    data += count.to_bytes(2, "little")
    their_temp, their_iq, their_speed, their_count = theirs._parse_response_2(list(data))
    state = LkTech(1, model=model).decode(_frame(data.hex()), 0.0)
    assert state is not None
    amps_per_count = {"MF": 33 / 4096, "MG": 66 / 4096}[model]  # pylkmotor's unit table
    assert state.temperature_c == their_temp
    assert state.current_a == pytest.approx(their_iq * amps_per_count)
    assert state.velocity_dps == their_speed
    assert state.position_deg % 360 == pytest.approx(their_count * 360 / 16384)


@given(hundredths=st.integers(-(2**55), 2**55 - 1))
def test_pylkmotor_reads_the_multi_turn_angle_alike(hundredths) -> None:
    theirs = _pylk()
    data = bytes([0x92]) + hundredths.to_bytes(7, "little", signed=True)
    state = LkTech(1).decode(_frame(data.hex()), 0.0)
    assert state is not None
    assert state.position_deg == pytest.approx(theirs._byte_to_decimal(list(data[1:8])) / 100)


@given(
    temperature=st.integers(-128, 127),
    centivolts=st.integers(0, 0x7FFF),  # pylkmotor reads the voltage signed
    off=st.booleans(),
    error=st.integers(0, 255),
)
def test_pylkmotor_reads_status_1_alike(temperature, centivolts, off, error) -> None:
    theirs = _pylk()
    data = bytes([0x9A, temperature & 0xFF]) + centivolts.to_bytes(2, "little")
    data += bytes([0, 0, 0x10 if off else 0x00, error])
    their_temp, their_volts, _, their_state, their_error = theirs._parse_response_1(list(data))
    profile = LkTech(1)
    state = profile.decode(_frame(data.hex()), 0.0)
    assert state is not None and state.voltage_v is not None
    assert state.temperature_c == their_temp
    assert state.voltage_v == pytest.approx(their_volts)
    assert profile.motor_off == (their_state == 0x10)
    assert (state.faults == Fault(0)) == (their_error == 0)
    assert (Fault.LOW_VOLTAGE in state.faults) == bool(their_error & 0x01)
    assert (Fault.STALL in state.faults) == bool(their_error & 0x40)


@given(
    hundredths=st.integers(-(2**31) + 1, 2**31 - 1),
    speed=st.integers(1, 65535),
)
def test_pylkmotor_sends_the_same_position_command(hundredths, speed) -> None:
    module = pytest.importorskip("pylkmotor.LKMotor")
    channel = "pylk-cross-check"
    theirs = module.LKMotor(bus_interface="virtual", bus_channel=channel, motor_id=5)
    with can.Bus(interface="virtual", channel=channel) as wire:
        try:
            theirs._send_command(
                0xA4,
                [0x00] + theirs._decimal_to_byte(speed, 2) + theirs._decimal_to_byte(hundredths, 4),
            )
            sent = wire.recv(timeout=1.0)
        finally:
            theirs.bus.shutdown()
    ours = LkTech(5).position_command(hundredths / 100, speed)
    assert sent is not None
    assert (sent.arbitration_id, bytes(sent.data)) == (ours.arbitration_id, bytes(ours.data))


def test_temperature_and_nan_fields_stay_unknown_until_reported() -> None:
    state = LkTech(1).decode(_frame("92 28 23 00 00 00 00 00"), 0.0)
    assert state is not None
    assert math.isnan(state.current_a) and math.isnan(state.temperature_c)
