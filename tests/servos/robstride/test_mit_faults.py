"""Robstride MIT protocol: fault reports (issue 27 finding 2) and the position range per model
(finding 6), over the real reply bytes and through the bridge."""

from __future__ import annotations

import math

import can
import pytest

from mavservo.servos import Fault
from mavservo.servos.robstride.profile import MODELS, Robstride
from tests.support.bridge import (
    MAV_CMD_DO_SET_SERVO,
    MAV_RESULT_ACCEPTED,
    Peer,
    running,
    sim_servo,
    status,
)
from tests.support.waiting import wait_until

pytestmark = pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")


def _reply(hexdata: str, host: int = 0xFD) -> can.Message:
    return can.Message(arbitration_id=host, is_extended_id=False, data=bytes.fromhex(hexdata))


def test_a_fault_report_is_a_fault_not_a_state() -> None:
    profile = Robstride(1, protocol="mit")
    state = profile.decode(_reply("01 01 00 00 00 00 00 00"), 0.0)
    assert state is not None
    assert state.faults == Fault.OVER_TEMPERATURE  # was no fault at -714.6 deg, -2521 dps
    assert math.isnan(state.position_deg) and math.isnan(state.velocity_dps)


@pytest.mark.parametrize(
    ("word", "faults"),
    [
        (0x4000, Fault.STALL),  # bit 14 overload
        (0x0080, Fault.UNCALIBRATED),
        (0x0008, Fault.ENCODER),
        (0x0004, Fault.LOW_VOLTAGE),
        (0x0002, Fault.DRIVER),
        (0x0001, Fault.OVER_TEMPERATURE),
        (0x0010, Fault.OTHER),  # undocumented: reported, never hidden
        (0x4005, Fault.STALL | Fault.LOW_VOLTAGE | Fault.OVER_TEMPERATURE),
    ],
)
def test_every_documented_fault_bit(word: int, faults: Fault) -> None:
    data = bytes([1]) + word.to_bytes(2, "little") + bytes(5)
    state = Robstride(1, protocol="mit").decode(_reply(data.hex()), 0.0)
    assert state is not None and state.faults == faults


def test_a_state_report_after_the_fault_clears_it() -> None:
    profile = Robstride(1, protocol="mit")
    profile.decode(_reply("01 04 00 00 00 00 00 00"), 0.0)
    state = profile.decode(_reply("01 7F FF 7F F7 FF 00 FA"), 0.1)  # mid-range, 25.0 degC
    assert state is not None and state.faults == Fault(0)
    assert state.position_deg == pytest.approx(0.0, abs=profile.resolution_deg)


def test_the_simulated_motor_sends_fault_reports_while_faulted() -> None:
    from mavservo.sim.servo import SimServo

    profile = Robstride(1, protocol="mit")
    servo = SimServo("robstride", 1, options=profile.options)
    for frame in profile.startup_frames():
        servo.receive(frame, 0.0)
    servo.faults.over_temperature = True
    [(_, report)] = servo.receive(profile.position_command(10.0), 0.1)
    assert bytes(report.data) == bytes.fromhex("01 01 00 00 00 00 00 00")
    state = profile.decode(report, 0.1)
    assert state is not None and state.faults == Fault.OVER_TEMPERATURE


@pytest.mark.parametrize("model", sorted(MODELS))
def test_every_model_maps_the_manuals_position_range(model: str) -> None:
    profile = Robstride(1, protocol="mit", model=model)
    assert profile.ranges.position_rad.high == pytest.approx(12.57)
    assert profile.max_angle_deg == pytest.approx(math.degrees(12.57))


def test_the_sample_programs_range_is_an_option() -> None:
    manual = Robstride(1, protocol="mit")
    sample = Robstride(1, protocol="mit", mit_position_max_rad=12.5)
    angle = math.degrees(12.0)
    assert manual.position_command(angle).data != sample.position_command(angle).data
    # 12.0 rad on a +-12.5 map: (12 + 12.5) / 25 x 65535 = 64224.3 counts (0xFAE0)
    assert bytes(sample.position_command(angle).data[0:2]) == bytes.fromhex("FAE0")


FAULTED = """
  telemetry: {named_value_float_hz: 10, esc_telemetry_hz: 0, actuator_output_status_hz: 0}
servos:
  - {name: joint, profile: robstride, can_id: 1, limits_deg: [-90, 90], telemetry_hz: 20,
     options: {protocol: mit}}
channels:
  - {servo: joint, source: servo_output, channel: 1, output_deg: [-90, 90]}
scheduler: {reply_timeout_s: 0.5}
"""


def test_a_mit_fault_report_reaches_statustext_and_telemetry() -> None:
    with running(FAULTED) as (bridge, port):
        peer = Peer(port)
        try:
            assert peer.command(MAV_CMD_DO_SET_SERVO, [1, 1600]) == MAV_RESULT_ACCEPTED
            assert wait_until(lambda: status(bridge, "joint").online, 5)
            mark = peer.count()
            sim_servo(bridge, "joint").faults.over_temperature = True
            assert wait_until(
                lambda: any("joint fault over_temperature" in t for t in peer.statustexts(mark)),
                5,
            ), peer.statustexts(mark)
            bit = float(Fault.OVER_TEMPERATURE.value)
            assert wait_until(
                lambda: any(
                    m.get_type() == "NAMED_VALUE_FLOAT"
                    and m.name == "s1_flt"
                    and int(m.value) & int(bit)
                    for m in peer.since(mark)
                ),
                5,
            )
            assert Fault.OVER_TEMPERATURE in status(bridge, "joint").state.faults
        finally:
            peer.close()
        bridge.stop()
