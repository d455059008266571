"""The simulated Damiao and CubeMars-MIT devices behind the real SimServo physics, driven by the
profiles' own frames: lifecycle (a disabled motor does not move), the Damiao motor's own
communication timeout (it stops and reports status D until cleared), faults in the families'
own codes, and the profile decoding what the device says.
"""

from __future__ import annotations

import math

import can
import pytest

from mavservo.config.simulation import Faults
from mavservo.servos import Fault
from mavservo.servos.cubemars.mit_mode import CubeMarsAKMit, CubeMarsMitOptions
from mavservo.servos.damiao.profile import DamiaoDM, DamiaoOptions
from mavservo.sim.servo import SimServo


def exchange(servo: SimServo, msg: can.Message, now: float) -> list[can.Message]:
    return [reply for _, reply in servo.receive(msg, now)]


def send_all(servo: SimServo, frames: list[can.Message], now: float) -> list[can.Message]:
    return [reply for msg in frames for reply in exchange(servo, msg, now)]


def settle(servo: SimServo, profile, angle: float, start: float, seconds: float = 3.0) -> float:  # type: ignore[no-untyped-def]
    """Command ``angle`` every 20 ms for ``seconds`` (well inside any timeout); the end time."""
    now = start
    while now < start + seconds:
        exchange(servo, profile.position_command(angle), now)
        now += 0.02
    return now


@pytest.mark.parametrize("mode", ["mit", "position-velocity"])
def test_damiao_moves_only_after_the_startup_sequence(mode: str) -> None:
    options = DamiaoOptions(mode=mode, comm_timeout_ms=200)
    profile = DamiaoDM(1, options)
    servo = SimServo("damiao-dm", 1, options=options)
    # powered up disabled: commands are answered (status 0) but do not move it
    (reply,) = exchange(servo, profile.position_command(30.0), 0.0)
    assert profile.decode(reply, 0.0) is not None and profile.needs_startup()
    settle(servo, profile, 30.0, 0.0, 1.0)
    assert abs(servo.position_deg) < 1e-6
    replies = send_all(servo, profile.startup_frames(), 1.0)
    assert len(replies) == 4
    states = [profile.decode(r, 1.0) for r in replies]
    assert all(s is not None for s in states)
    assert not profile.needs_startup()
    assert servo.enabled
    settle(servo, profile, 30.0, 1.0)
    assert servo.position_deg == pytest.approx(30.0, abs=profile.resolution_deg)
    state = profile.decode(exchange(servo, profile.telemetry_requests()[0], 4.0)[0], 4.0)
    assert state is not None
    assert state.position_deg == pytest.approx(servo.position_deg, abs=profile.resolution_deg)
    assert state.faults == Fault(0)


def test_damiao_stops_by_itself_when_the_host_falls_silent_and_needs_clear_then_enable() -> None:
    options = DamiaoOptions(comm_timeout_ms=100)
    profile = DamiaoDM(2, options)
    servo = SimServo("damiao-dm", 2, options=options)
    send_all(servo, profile.startup_frames(), 0.0)
    now = settle(servo, profile, 20.0, 0.0, 1.0)
    assert servo.enabled
    servo.poll(now + 0.05)  # the motor's own timer, inside the timeout: still enabled
    assert servo.enabled
    servo.poll(now + 0.2)  # 200 ms without a frame: it leaves the enabled state
    assert not servo.enabled
    (reply,) = exchange(servo, profile.telemetry_requests()[0], now + 0.25)
    state = profile.decode(reply, now + 0.25)
    assert state is not None and Fault.COMMUNICATION_LOST in state.faults
    assert profile.needs_startup()
    # enabling without clearing first is refused by the motor, as the real one does
    exchange(servo, can.Message(arbitration_id=2, is_extended_id=False,
                                data=b"\xff" * 7 + b"\xfc"), now + 0.26)  # fmt: skip
    assert not servo.enabled
    replies = send_all(servo, profile.startup_frames(), now + 0.3)
    assert servo.enabled
    state = profile.decode(replies[-1], now + 0.3)
    assert state is not None and state.faults == Fault(0)


def test_damiao_ignores_commands_of_the_other_mode() -> None:
    """A motor left in MIT mode does not obey position-velocity frames until CTRL_MODE says so
    (the start-up writes it)."""
    options = DamiaoOptions(mode="position-velocity")
    profile = DamiaoDM(3, options)
    servo = SimServo("damiao-dm", 3, options=options)
    enable = profile.startup_frames()[2:]  # clear + enable, without the mode write
    send_all(servo, enable, 0.0)
    settle(servo, profile, 45.0, 0.0, 1.0)
    assert abs(servo.position_deg) < 1e-6
    send_all(servo, profile.startup_frames(), 1.0)
    settle(servo, profile, 45.0, 1.0, 2.0)
    assert servo.position_deg == pytest.approx(45.0, abs=0.05)


def test_damiao_fault_status_and_the_motor_leaving_enabled() -> None:
    options = DamiaoOptions()
    profile = DamiaoDM(4, options)
    servo = SimServo("damiao-dm", 4, faults=Faults(over_current=True), options=options)
    replies = send_all(servo, profile.startup_frames(), 0.0)
    state = profile.decode(replies[-1], 0.0)
    assert state is not None and state.faults == Fault.OVER_CURRENT
    assert not servo.enabled
    servo.faults.over_current = False
    state = profile.decode(exchange(servo, profile.telemetry_requests()[0], 0.1)[0], 0.1)
    assert state is not None and state.faults == Fault(0)
    assert profile.needs_startup()  # now merely disabled: the bridge enables it again


def test_damiao_register_reads_answer_with_the_written_value() -> None:
    profile = DamiaoDM(5, DamiaoOptions(comm_timeout_ms=123))
    servo = SimServo("damiao-dm", 5, options=profile.options)
    send_all(servo, profile.startup_frames(), 0.0)
    (answer,) = exchange(servo, profile.register_frame(0x33, 9), 0.01)
    assert answer.data.hex() == "050033" + "09" + (123 * 20).to_bytes(4, "little").hex()
    assert profile.is_reply(answer)


def test_cubemars_mit_lifecycle_and_zero_mute() -> None:
    options = CubeMarsMitOptions()
    profile = CubeMarsAKMit(3, options)
    servo = SimServo("cubemars-ak-mit", 3, options=options)
    # out of motor mode: commands are ignored and unanswered
    assert exchange(servo, profile.position_command(10.0), 0.0) == []
    (reply,) = send_all(servo, profile.startup_frames(), 0.1)
    assert profile.decode(reply, 0.1) is not None
    settle(servo, profile, 10.0, 0.1)
    assert servo.position_deg == pytest.approx(10.0, abs=profile.resolution_deg)
    assert exchange(servo, profile.set_zero_frame(), 3.5) == []  # muted for about a second
    assert abs(servo.position_deg) < 1e-9
    assert exchange(servo, profile.telemetry_requests()[0], 4.0) == []
    assert len(exchange(servo, profile.telemetry_requests()[0], 4.6)) == 1
    send_all(servo, profile.release_frames(), 5.0)
    assert not servo.enabled


def test_cubemars_mit_fault_codes_reach_the_profile() -> None:
    profile = CubeMarsAKMit(1)
    servo = SimServo("cubemars-ak-mit", 1, faults=Faults(over_temperature=True))
    (reply,) = send_all(servo, profile.startup_frames(), 0.0)
    state = profile.decode(reply, 0.0)
    assert state is not None and state.faults == Fault.OVER_TEMPERATURE
    assert math.isfinite(state.temperature_c)


def test_cubemars_mit_own_timeout_stops_the_motor_until_the_next_command() -> None:
    options = CubeMarsMitOptions(comm_timeout_ms=100)
    profile = CubeMarsAKMit(2, options)
    servo = SimServo("cubemars-ak-mit", 2, options=options)
    send_all(servo, profile.startup_frames(), 0.0)
    now = settle(servo, profile, 15.0, 0.0, 1.0)
    servo.poll(now + 0.05)
    assert servo.enabled
    servo.poll(now + 0.2)  # 200 ms quiet: torque off, still in motor mode
    assert not servo.enabled
    assert len(exchange(servo, profile.position_command(15.0), now + 0.3)) == 1
    assert servo.enabled
    # without a timeout option (as shipped) it never stops by itself
    quiet = SimServo("cubemars-ak-mit", 3)
    send_all(quiet, CubeMarsAKMit(3).startup_frames(), 0.0)
    quiet.poll(100.0)
    assert quiet.enabled
