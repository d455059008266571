"""Red-team findings on the DroneCAN node and profile (review of issues 28 and 32 item 7): each
test failed on main 00d11a1 and passes with its fix."""

from __future__ import annotations

import can
from dronecan.transport import Frame, Transfer
from hypothesis import given, settings
from hypothesis import strategies as st

from mavservo.servos.dronecan import DroneCanServo


def library_decode(frames: list[can.Message]):  # type: ignore[no-untyped-def]
    """The ``dronecan`` package's own reassembly and decoding (independent of the profile's)."""
    transfer = Transfer()
    transfer.from_frames([Frame(m.arbitration_id, bytes(m.data)) for m in frames])
    return transfer


@settings(max_examples=300, deadline=None)
@given(
    st.integers(500, 2499).flatmap(
        lambda low: st.tuples(st.just(low), st.integers(low + 1, 2500), st.floats(0.0, 1.0))
    )
)
def test_a_pwm_command_on_the_wire_stays_within_the_channels_pulse_range(
    case: tuple[int, int, float],
) -> None:
    """float16 steps by 2 us above 2048 us: 2499 us used to go out as 2500, past pwm_max_us."""
    low, high, fraction = case
    profile = DroneCanServo(
        20, firmware="ardupilot", actuator_id=1, command="pwm", pwm_min_us=low, pwm_max_us=high
    )
    angle = profile.min_angle_deg + fraction * (profile.max_angle_deg - profile.min_angle_deg)
    [command] = library_decode([profile.position_command(angle)]).payload.commands
    value = float(command.command_value)
    assert low <= value <= high
    assert low <= int(value + 0.5) <= high  # what AP_Periph makes of it (rc_out.cpp)


def test_the_pwm_limit_itself_is_sent_inside_the_limit() -> None:
    profile = DroneCanServo(
        20, firmware="ardupilot", actuator_id=1, command="pwm", pwm_min_us=1000, pwm_max_us=2499
    )
    [command] = library_decode([profile.position_command(45.0)]).payload.commands
    assert float(command.command_value) == 2498.0
