"""ServoCommands alone: DO_SET_SERVO, DO_REPEAT_SERVO and DO_SET_ACTUATOR on a recording backend."""

from __future__ import annotations

import math

import pytest

from mavservo.mavlink.arbitration import CommandHold
from mavservo.mavlink.backend import Outcome
from mavservo.mavlink.servo_commands import (
    INT32_MAX,
    MAV_CMD_DO_REPEAT_SERVO,
    MAV_CMD_DO_SET_ACTUATOR,
    MAV_CMD_DO_SET_SERVO,
    ServoCommands,
)
from mavservo.mavlink.settings import MavlinkSettings
from tests.support.mavlink_doubles import RecordingBackend

NAN = math.nan


def make(**settings) -> tuple[ServoCommands, RecordingBackend, CommandHold]:
    backend, hold = RecordingBackend(), CommandHold(2.0)
    mav_settings = MavlinkSettings(url="udpin:127.0.0.1:0", **settings)
    return ServoCommands(backend, mav_settings, hold), backend, hold


def run(servo: ServoCommands, command: int, params, is_int: bool, now: float, broadcast: bool):
    """One command through the handler table, as the command handler dispatches it."""
    return servo.handlers[command](params, is_int, now, broadcast)


def params(*values: float) -> tuple[float, ...]:
    return tuple(float(v) for v in values) + (NAN,) * (7 - len(values))


def test_do_set_servo_applies_and_holds_the_channel_against_mirroring() -> None:
    servo, backend, hold = make()
    result = run(servo, MAV_CMD_DO_SET_SERVO, params(9, 1100), False, 1.0, broadcast=False)
    assert result is not None and result.ok
    assert backend.calls == [("servo", 9, 1100.0, "do_set_servo")]
    assert not hold.mirror_allowed(("servo", 9), 2.0)
    assert hold.mirror_allowed(("servo", 1), 2.0)


@pytest.mark.parametrize(
    ("values", "reason"),
    [
        ((9, 3000), "bad_param"),
        ((9, NAN), "bad_param"),
        ((4, 1500), "unmapped"),
        ((0.5, 1500), "bad_param"),
    ],
)
def test_a_bad_do_set_servo_is_denied_with_its_kind_and_never_applied(values, reason) -> None:
    servo, backend, _ = make()
    result = run(servo, MAV_CMD_DO_SET_SERVO, params(*values), False, 0.0, broadcast=False)
    assert result is not None and result.outcome is Outcome.DENIED
    assert result.reason.startswith(f"{reason}:")
    assert backend.calls == []


def test_a_broadcast_for_an_unmapped_channel_is_not_ours() -> None:
    servo, backend, _ = make()
    assert run(servo, MAV_CMD_DO_SET_SERVO, params(4, 1500), False, 0.0, broadcast=True) is None
    assert backend.calls == []


def test_a_repeat_alternates_with_the_trim_ends_on_it_and_stops() -> None:
    servo, backend, _ = make(channel_trims_us={9: 1400.0})
    cmd = params(9, 1900, 2, 1.0)  # two pulses, one second cycle
    assert run(servo, MAV_CMD_DO_REPEAT_SERVO, cmd, False, 0.0, broadcast=False).ok
    assert servo.repeating_channels() == {9}
    for t in (0.5, 1.0, 1.5, 2.0, 2.5):
        servo.tick(t)
    pwms = [call[2] for call in backend.calls]
    assert pwms == [1900.0, 1400.0, 1900.0, 1400.0]
    assert servo.repeating_channels() == set()


def test_a_repeat_faster_than_two_command_periods_is_refused() -> None:
    servo, backend, _ = make(command_period_s=0.05)
    cmd = params(9, 1900, 10, 0.05)
    result = run(servo, MAV_CMD_DO_REPEAT_SERVO, cmd, False, 0.0, broadcast=False)
    assert result is not None and result.reason.startswith("cycle_too_short:")
    assert backend.calls == []


def test_do_set_servo_and_cancel_all_stop_a_running_repeat() -> None:
    servo, backend, _ = make()
    run(servo, MAV_CMD_DO_REPEAT_SERVO, params(9, 1900, 5, 1.0), False, 0.0, broadcast=False)
    run(servo, MAV_CMD_DO_SET_SERVO, params(9, 1500), False, 0.1, broadcast=False)
    servo.tick(10.0)
    assert [call[2] for call in backend.calls] == [1900.0, 1500.0]
    run(servo, MAV_CMD_DO_REPEAT_SERVO, params(1, 1900, 5, 1.0), False, 0.0, broadcast=False)
    servo.cancel_all()
    assert servo.repeating_channels() == set()


def test_do_set_actuator_command_int_scales_x_and_leaves_int32_max_alone() -> None:
    servo, backend, _ = make()
    # COMMAND_INT: actuator 5 in x, scaled by 1e7; y = INT32_MAX is "leave actuator 6 alone"
    cmd = (NAN, NAN, NAN, NAN, 5_000_000.0, float(INT32_MAX), 0.0)
    assert run(servo, MAV_CMD_DO_SET_ACTUATOR, cmd, True, 0.0, broadcast=False).ok
    assert backend.calls == [("actuator", 5, 0.5, "do_set_actuator")]


def test_do_set_actuator_set_index_shifts_the_actuator_numbers() -> None:
    servo, backend, _ = make()
    # set 1 carries actuators 7..12: none mapped, so the value of actuator 1 is not applied
    result = run(
        servo, MAV_CMD_DO_SET_ACTUATOR, params(0.5, NAN, NAN, NAN, NAN, NAN, 1), False, 0.0, False
    )
    assert result is not None and result.reason.startswith("unmapped:")
    assert backend.calls == []
    result = run(
        servo, MAV_CMD_DO_SET_ACTUATOR, params(1.5, NAN, NAN, NAN, NAN, NAN, 0), False, 0.0, False
    )
    assert result is not None and result.reason.startswith("bad_param:")
    assert backend.calls == []
