"""The simulated LK motor against LK's document: its state machine (off after 0x80 until 0x88,
stopped after 0x81), and a wrong scale caught by the reference vectors (which
tests/servos/test_reference_vectors.py runs against the profile and this device alike)."""

from __future__ import annotations

import can
import pytest

from mavservo.servos.lk import sim as lk_sim
from mavservo.sim.servo import SimServo
from tests.support.vectors import checked, load, simulator_mismatches

VECTORS = checked("lk", "simulator")


def _frame(hexdata: str, arb_id: int = 0x141) -> can.Message:
    return can.Message(arbitration_id=arb_id, is_extended_id=False, data=bytes.fromhex(hexdata))


def test_a_simulator_scaling_iq_as_0_01_a_fails_the_vectors(monkeypatch) -> None:
    monkeypatch.setitem(lk_sim._AMPS_AT_2048, "MF", 2048 * 0.01)
    document = load("lk")
    failures = [m for _, v in VECTORS for m in simulator_mismatches(document, v)]
    assert any("9C on an MF motor" in failure for failure in failures), failures


A4_TO_90 = "A4 00 68 01 28 23 00 00"  # 90.00 deg at 360 dps


def _settle(servo: SimServo, start: float) -> float:
    for step in range(1, 41):  # bounded: 4 s of simulated time
        servo.advance(start + step * 0.1)
    return start + 4.0


def test_an_lk_motor_off_answers_but_does_not_move_until_motor_on() -> None:
    servo = SimServo("lk", 1)
    assert [bytes(r.data) for _, r in servo.receive(_frame("80" + "00" * 7), 0.0)] == [
        bytes.fromhex("80" + "00" * 7)
    ]
    replies = servo.receive(_frame(A4_TO_90), 0.1)
    assert len(replies) == 1 and replies[0][1].data[0] == 0xA4  # it answers ...
    now = _settle(servo, 0.1)
    assert servo.position_deg == pytest.approx(0.0, abs=0.01)  # ... and stays put
    servo.receive(_frame("88" + "00" * 7), now)
    servo.receive(_frame(A4_TO_90), now + 0.01)
    _settle(servo, now + 0.01)
    assert servo.position_deg == pytest.approx(90.0, abs=0.05)


def test_an_lk_motor_stopped_holds_until_run() -> None:
    servo = SimServo("lk", 2)
    servo.receive(_frame("81" + "00" * 7, 0x142), 0.0)
    servo.receive(_frame(A4_TO_90, 0x142), 0.1)
    now = _settle(servo, 0.1)
    assert servo.position_deg == pytest.approx(0.0, abs=0.01)
    servo.receive(_frame("88" + "00" * 7, 0x142), now)
    servo.receive(_frame(A4_TO_90, 0x142), now + 0.01)
    _settle(servo, now + 0.01)
    assert servo.position_deg == pytest.approx(90.0, abs=0.05)


def test_an_lk_motor_reports_its_state_byte() -> None:
    servo = SimServo("lk", 1)
    [(_, on)] = servo.receive(_frame("9A" + "00" * 7), 0.0)
    servo.receive(_frame("80" + "00" * 7), 0.1)
    [(_, off)] = servo.receive(_frame("9A" + "00" * 7), 0.2)
    assert (on.data[6], off.data[6]) == (0x00, 0x10)


def test_an_lk_motor_ignores_other_ids_and_short_frames() -> None:
    servo = SimServo("lk", 1)
    assert servo.receive(_frame("9C" + "00" * 7, 0x142), 0.0) == []
    assert servo.receive(_frame("9C 00 00", 0x141), 0.0) == []
    assert servo.receive(_frame("A1" + "00" * 7), 0.0) == []  # torque control: not simulated
