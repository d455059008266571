"""CubeMars AK MIT mode: replies of DLC 6 (the manual's MIT reply table: position, speed,
current; issue 27 finding 3) are this driver's answers, decoded and kept online."""

from __future__ import annotations

import time

import can
import pytest

from mavservo.servos import CubeMarsAKMit, Fault
from mavservo.sim.servo import SimServo
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


def _reply(hexdata: str) -> can.Message:
    return can.Message(arbitration_id=0x00, is_extended_id=False, data=bytes.fromhex(hexdata))


def test_a_six_byte_reply_is_decoded() -> None:
    profile = CubeMarsAKMit(1)
    # mid-range position, speed and current: 0 rad, 0 rad/s, 0 N m on an AK80-9's ranges
    state = profile.decode(_reply("01 7F FF 7F F7 FF"), 0.0)
    assert state is not None
    assert state.position_deg == pytest.approx(0.0, abs=profile.resolution_deg)
    assert abs(state.velocity_dps) < 2.0 and abs(state.current_a) < 0.01
    assert state.faults == Fault(0)


def test_a_six_byte_reply_keeps_the_last_temperature_and_fault() -> None:
    profile = CubeMarsAKMit(1)
    profile.decode(_reply("01 7F FF 7F F7 FF 2D 01"), 0.0)  # 45 degC, error 1: over-temperature
    state = profile.decode(_reply("01 7F FF 7F F7 FF"), 0.1)
    assert state is not None
    assert state.temperature_c == 45.0 and state.faults == Fault.OVER_TEMPERATURE


def test_other_lengths_and_other_drivers_are_not_replies() -> None:
    profile = CubeMarsAKMit(1)
    for data in ("01 7F FF 7F F7", "01 7F FF 7F F7 FF 2D", "02 7F FF 7F F7 FF"):
        assert profile.decode(_reply(data), 0.0) is None


def test_the_simulated_six_byte_driver_answers_in_six_bytes() -> None:
    profile = CubeMarsAKMit(1, reply_bytes=6)
    servo = SimServo("cubemars-ak-mit", 1, options=profile.options)
    [(_, answer)] = servo.receive(profile.startup_frames()[0], 0.0)
    assert len(answer.data) == 6
    assert profile.decode(answer, 0.0) is not None


SHORT = """
  telemetry: {named_value_float_hz: 10, esc_telemetry_hz: 0, actuator_output_status_hz: 0}
servos:
  - {name: knee, profile: cubemars-ak-mit, can_id: 1, limits_deg: [-90, 90], telemetry_hz: 10,
     options: {reply_bytes: 6}}
channels:
  - {servo: knee, source: servo_output, channel: 1, input: {min: 1000, max: 2000},
     output_deg: [-90, 90]}
scheduler: {reply_timeout_s: 0.5}
"""


def test_a_six_byte_driver_is_online_and_follows_through_the_bridge() -> None:
    with running(SHORT) as (bridge, port):
        peer = Peer(port)
        try:
            assert peer.command(MAV_CMD_DO_SET_SERVO, [1, 1750]) == MAV_RESULT_ACCEPTED
            knee = sim_servo(bridge, "knee")
            # at rest on the target, then a reply decoded after that: the state compared is
            # the resting servo's (a snapshot while it still moved raced the 10 Hz telemetry)
            assert wait_until(
                lambda: abs(knee.position_deg - 45.0) < 0.5 and abs(knee.velocity_dps) < 0.1, 8
            ), (knee.position_deg, knee.velocity_dps)
            assert wait_until(lambda: status(bridge, "knee").online, 3)
            at_rest = time.monotonic()  # the scheduler's clock, which stamps decoded states
            assert wait_until(lambda: status(bridge, "knee").state.timestamp > at_rest, 3)
            state = status(bridge, "knee").state
            assert state.position_deg == pytest.approx(knee.position_deg, abs=0.5)
        finally:
            peer.close()
        summary = bridge.stop()
    assert summary["servos"]["knee"]["frames"]["rejected"] == 0
