"""The simulated RMD-X answers MyActuator's model and software-date reads as the document's
examples show them (Servo Motor Control Protocol V4.2, 2024.05: 2.32.4 and 2.29.4), and a read
changes nothing: the motor stays off and unmoved."""

from __future__ import annotations

import can

from mavservo.sim.servo import SimServo


def _ask(servo: SimServo, command: int, now: float) -> list[bytes]:
    request = can.Message(
        arbitration_id=0x141, is_extended_id=False, data=bytes([command]) + bytes(7)
    )
    replies = servo.receive(request, now)
    assert all(msg.arbitration_id == 0x241 and not msg.is_extended_id for _, msg in replies)
    return [bytes(msg.data) for _, msg in replies]


def test_the_model_and_software_date_reads_answer_as_the_document_shows() -> None:
    servo = SimServo("rmd-x", 1)
    servo.disable(0.0)
    # 2.32.4: 0x241 B5 58 38 53 32 56 31 30 ("X8S2V10")
    assert _ask(servo, 0xB5, 0.01) == [bytes.fromhex("B5 58 38 53 32 56 31 30")]
    # 2.29.4: 0x241 B2 00 00 00 2E 89 34 01 (0x0134892E = 20220206)
    assert _ask(servo, 0xB2, 0.02) == [bytes.fromhex("B2 00 00 00 2E 89 34 01")]
    assert not servo.enabled and servo.commands == 0
