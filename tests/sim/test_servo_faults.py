"""The simulated servo's mechanical faults (issue 33), in simulated time: what the health checks
are tested against must behave like the thing it stands for."""

from __future__ import annotations

import pytest

from mavservo.config.simulation import Faults, Physics
from mavservo.servos import RmdX
from mavservo.sim.servo import SimServo


def servo(**faults: object) -> SimServo:
    motor = SimServo("rmd-x", 1, Physics(current_noise_a=0.0), Faults(**faults))  # type: ignore[arg-type]
    motor.advance(0.0)
    return motor


def test_an_obstruction_stops_the_output_there_at_stall_current_and_lets_it_back() -> None:
    motor = servo(jammed_at_deg=10.0)
    motor.command_position(30.0, 360.0, 0.0)
    motor.advance(1.0)
    assert motor.position_deg == 10.0 and motor.velocity_dps == 0.0
    assert motor.blocked
    assert motor.current_a == pytest.approx(motor.physics.stall_current_a)
    assert motor.measured_current_a() < motor.physics.over_current_a  # it reports no fault
    assert not motor.active_faults
    motor.command_position(-20.0, 360.0, 1.0)  # away from the obstruction: free
    motor.advance(2.0)
    assert motor.position_deg == pytest.approx(-20.0, abs=0.01)
    assert not motor.blocked
    motor.command_position(40.0, 360.0, 2.0)  # from below again: stops at 10
    motor.advance(3.0)
    assert motor.position_deg == 10.0
    motor.faults.jammed_at_deg = None  # the obstruction is gone
    motor.advance(4.0)
    assert motor.position_deg == pytest.approx(40.0, abs=0.01)


def test_an_obstruction_from_above_blocks_downward_motion() -> None:
    motor = servo()
    motor.command_position(30.0, 360.0, 0.0)
    motor.advance(1.0)
    motor.faults.jammed_at_deg = 0.0
    motor.command_position(-30.0, 360.0, 1.0)
    motor.advance(2.0)
    assert motor.position_deg == 0.0
    assert motor.current_a == pytest.approx(-motor.physics.stall_current_a)


def test_a_slipping_coupling_turns_the_motor_and_not_the_output() -> None:
    motor = servo(slipping=True)
    motor.command_position(30.0, 360.0, 0.0)
    motor.advance(1.0)
    assert motor.position_deg == 0.0
    assert abs(motor.velocity_dps) == pytest.approx(360.0)  # the loop never reaches its target
    assert motor.motor_position_deg > 300.0
    assert motor.current_a > 0.0
    motor.faults.slipping = False
    motor.advance(2.0)
    assert motor.position_deg == pytest.approx(30.0, abs=0.01)


def test_a_supply_sag_is_what_the_servo_reports() -> None:
    """An RMD-X reads its supply with 9A (every 10th poll by default): the sag comes back."""
    motor = servo(supply_v=18.0)
    profile = RmdX(1)
    volts = []
    for k in range(1, 25):
        for request in profile.telemetry_requests():
            for _, reply in motor.receive(request, 0.01 * k):
                state = profile.decode(reply, 0.01 * k)
                if state is not None and state.voltage_v is not None:
                    volts.append(state.voltage_v)
        profile.poll_sent()
    assert volts and set(volts) == {18.0}
    motor.faults.supply_v = None
    assert motor.voltage_v == motor.physics.voltage_v
