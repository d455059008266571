"""RMD-X models with a holding brake (issue 27 finding 5): brake release (0x77) before the first
command, brake lock (0x78) on release and shutdown; the simulated brake model does not move
while its brake holds."""

from __future__ import annotations

import can
import pytest

from mavservo.servos import RmdX
from mavservo.sim.servo import SimServo


def _commands(frames: list[can.Message]) -> list[int]:
    return [frame.data[0] for frame in frames]


def test_a_brake_model_releases_its_brake_at_start_up_and_locks_it_on_release() -> None:
    profile = RmdX(1, brake=True, comm_timeout_ms=500)
    assert _commands(profile.startup_frames()) == [0xB3, 0x77]
    assert _commands(profile.release_frames()) == [0x80, 0x78]
    assert _commands(profile.shutdown_frames()) == [0x78]
    for frame in profile.startup_frames() + profile.release_frames():
        assert (frame.arbitration_id, len(frame.data)) == (0x141, 8)


def test_without_a_brake_no_brake_frame_goes_out() -> None:
    profile = RmdX(1)
    assert _commands(profile.startup_frames()) == [0xB3]
    assert _commands(profile.release_frames()) == [0x80]
    assert profile.shutdown_frames() == []


def test_brake_echoes_are_alive_replies() -> None:
    profile = RmdX(1, brake=True)
    for command in (0x77, 0x78):
        echo = can.Message(
            arbitration_id=0x241, is_extended_id=False, data=bytes([command]) + bytes(7)
        )
        assert profile.decode(echo, 0.0) is not None
        assert profile.exchange_key(echo) == command


def _settle(servo: SimServo, start: float) -> float:
    for step in range(1, 31):  # bounded: 3 s of simulated time
        servo.advance(start + step * 0.1)
    return start + 3.0


def test_the_simulated_brake_model_moves_only_with_its_brake_released() -> None:
    profile = RmdX(1, brake=True)
    servo = SimServo("rmd-x", 1, options=profile.options)
    servo.receive(profile.position_command(45.0, 360), 0.0)
    now = _settle(servo, 0.0)
    assert servo.position_deg == pytest.approx(0.0, abs=0.01)  # the brake holds it
    for frame in profile.startup_frames():
        servo.receive(frame, now)
    servo.receive(profile.position_command(45.0, 360), now + 0.01)
    now = _settle(servo, now + 0.01)
    assert servo.position_deg == pytest.approx(45.0, abs=0.05)
    for frame in profile.release_frames():
        servo.receive(frame, now)
    servo.receive(profile.position_command(-45.0, 360), now + 0.01)
    _settle(servo, now + 0.01)
    assert servo.position_deg == pytest.approx(45.0, abs=0.5)  # locked again: it stays
