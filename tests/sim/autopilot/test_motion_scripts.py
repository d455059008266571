"""Pure parts of the SITL simulator: profiles, scripts, DO_REPEAT_SERVO, retries, quaternions."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mavservo.config.autopilot_script import (
    Dropout,
    GimbalTarget,
    RepeatServo,
    SetActuator,
    SetServo,
    parse_event,
    parse_script,
    repeat_servo_value,
)
from mavservo.mavlink.quaternion import euler_to_quaternion, quaternion_to_euler
from mavservo.sim.autopilot.command_tracker import CommandTracker
from mavservo.sim.autopilot.motion_scripts import (
    N_CHANNELS,
    PROFILES,
    RandomWalkProfile,
    StaircaseProfile,
    SweepProfile,
    get_profile,
)

times = st.floats(min_value=0.0, max_value=600.0, allow_nan=False)
#: no per-example deadline: the simulator's profiles are pure, but on a loaded shared machine
#: an example hit hypothesis' default 200 ms twice (timing is not what these tests judge)
no_deadline = settings(deadline=None)


@pytest.mark.parametrize("name", sorted(PROFILES))
@no_deadline
@given(t=times)
def test_profiles_are_deterministic_and_in_ardupilot_ranges(name: str, t: float) -> None:
    a, b = get_profile(name), get_profile(name)
    frame = a.pwm(t)
    assert frame == b.pwm(t) == a.pwm(t)
    assert len(frame) == N_CHANNELS
    for channel in (1, 2, 4):
        assert 1100 <= frame[channel - 1] <= 1900
    assert 1000 <= frame[2] <= 2000
    assert all(v == 0 for v in frame[4:])  # undriven outputs read 0 = no pulse, as ArduPilot


def test_unknown_profile_is_rejected_with_the_choices() -> None:
    with pytest.raises(ValueError, match="sweep"):
        get_profile("zigzag")


def test_sweep_covers_full_ranges_and_servo4_mirrors_servo1() -> None:
    sweep = SweepProfile()
    frames = [sweep.pwm(i * 0.01) for i in range(int(sweep.period_s / 0.01))]
    assert min(f[0] for f in frames) <= 1102 and max(f[0] for f in frames) >= 1898
    assert min(f[2] for f in frames) <= 1002 and max(f[2] for f in frames) >= 1998
    for f in frames:
        assert abs((f[0] - 1500) + (f[3] - 1500)) <= 1  # mirror, up to rounding
    assert sweep.pwm(1.234) == sweep.pwm(1.234 + sweep.period_s)


def test_staircase_climbs_monotonically_then_returns_to_neutral() -> None:
    stairs = StaircaseProfile(steps=8, hold_s=2.0)
    levels = [stairs.pwm(i * stairs.hold_s + 1.0)[0] for i in range(stairs.steps + 1)]
    assert levels[0] == 1100 and levels[-1] == 1900
    assert all(b > a for a, b in zip(levels, levels[1:], strict=False))
    assert stairs.pwm(stairs.period_s - 0.5)[:4] == (1500, 1500, 1000, 1500)
    # each level is held for the whole step: settling time for the servo
    assert stairs.pwm(2.0)[0] == stairs.pwm(3.999)[0]


@no_deadline
@given(seed=st.integers(0, 2**32 - 1), t1=times, t2=times)
def test_random_walk_same_seed_same_walk_in_any_order(seed: int, t1: float, t2: float) -> None:
    forward, backward = RandomWalkProfile(seed=seed), RandomWalkProfile(seed=seed)
    a1, a2 = forward.pwm(t1), forward.pwm(t2)
    b2, b1 = backward.pwm(t2), backward.pwm(t1)
    assert (a1, a2) == (b1, b2)


def test_random_walk_seeds_differ_and_steps_are_bounded() -> None:
    one, two = RandomWalkProfile(seed=1), RandomWalkProfile(seed=2)
    assert [one.pwm(i * 0.25) for i in range(40)] != [two.pwm(i * 0.25) for i in range(40)]
    for i in range(1, 200):
        prev, cur = one.pwm((i - 1) * 0.25), one.pwm(i * 0.25)
        assert all(abs(a - b) <= one.max_step_us for a, b in zip(prev, cur, strict=True))


def test_repeat_servo_follows_ardupilot_timeline_from_the_recording() -> None:
    # plane-servos.tlog: DO_REPEAT_SERVO(9, 1900, 3, 2.0 s) -> 1900,1500 x3 at 1 s, ends on trim
    action = RepeatServo(channel=9, pwm=1900, count=3, cycle_s=2.0)
    seen = [repeat_servo_value(action, t + 0.5)[0] for t in range(7)]
    assert seen == [1900, 1500, 1900, 1500, 1900, 1500, 1500]
    assert repeat_servo_value(action, 5.9) == (1500, False)
    assert repeat_servo_value(action, 6.0) == (1500, True)


def test_script_parses_yaml_shape_and_hands_out_each_event_once() -> None:
    script = parse_script(
        [
            {"at": 3.0, "dropout": {"seconds": 1.5}},
            {"at": 1.0, "do_set_servo": {"channel": 9, "pwm": 1100}},
            {"at": 2.0, "do_repeat_servo": {"channel": 9, "pwm": 1900, "count": 2, "cycle_s": 1}},
            {"at": 2.5, "do_set_actuator": {"values": [0.5, None], "set_index": 1}},
            {"at": 4.0, "gimbal": {"pitch": -30, "yaw": 45, "flags": 16}},
        ]
    )
    assert script.due(0.5) == []
    first = script.due(2.0)
    assert [e.action for e in first] == [SetServo(9, 1100), RepeatServo(9, 1900, 2, 1.0)]
    assert script.due(2.0) == []
    rest = [e.action for e in script.due(10.0)]
    assert isinstance(rest[0], SetActuator) and rest[0].set_index == 1
    assert rest[0].values[0] == 0.5 and all(math.isnan(v) for v in rest[0].values[1:])
    assert rest[1:] == [Dropout(1.5), GimbalTarget(0.0, -30.0, 45.0, 16)]
    assert script.finished


@pytest.mark.parametrize(
    "bad",
    [
        {"do_set_servo": {"channel": 1, "pwm": 1500}},
        {"at": 1, "do_set_servo": {"channel": 1}},
        {"at": 1, "teleport": {}},
        {"at": 1, "dropout": {"seconds": 1}, "gimbal": {}},
    ],
)
def test_bad_script_events_raise_value_error(bad: dict) -> None:
    with pytest.raises(ValueError):
        parse_event(bad)


def test_command_tracker_retries_same_content_half_a_second_apart_up_to_four_times() -> None:
    tracker = CommandTracker(retry_interval_s=0.5, max_attempts=4)
    record = tracker.submit(183, (9, 1100, 0, 0, 0, 0, 0), 1, 0, now=10.0)
    sends = []
    for step in range(60):  # 3 s in 50 ms ticks
        now = 10.0 + step * 0.05
        sends += [(now, r.params) for r in tracker.due(now)]
    assert len(sends) == 4 and record.gave_up and record.result is None
    assert {p for _, p in sends} == {(9, 1100, 0, 0, 0, 0, 0)}
    gaps = [b[0] - a[0] for a, b in zip(sends, sends[1:], strict=False)]
    assert all(g == pytest.approx(0.5, abs=0.051) for g in gaps)


def test_command_tracker_matches_acks_by_command_and_source() -> None:
    tracker = CommandTracker()
    record = tracker.submit(187, (0.5, *(math.nan,) * 5, 1), 1, 140, now=0.0)
    assert tracker.due(0.0) == [record]
    assert tracker.on_ack(187, 0, (1, 141), (1, 1), 0.1) is None  # wrong component
    assert tracker.on_ack(183, 0, (1, 140), (1, 1), 0.1) is None  # wrong command
    assert tracker.on_ack(187, 5, (1, 140), (1, 1), 0.2) is record  # IN_PROGRESS: no retries
    assert tracker.due(5.0) == [] and not record.done
    assert tracker.on_ack(187, 0, (1, 140), (1, 1), 0.3) is record
    assert record.result == 0 and record.ack_from == (1, 140) and record.attempts == 1
    assert len(tracker.acks) == 4 and tracker.idle


angles = st.floats(min_value=-179.0, max_value=179.0)


@no_deadline
@given(roll=angles, pitch=st.floats(min_value=-89.0, max_value=89.0), yaw=angles)
def test_quaternion_round_trip(roll: float, pitch: float, yaw: float) -> None:
    q = euler_to_quaternion(roll, pitch, yaw)
    assert math.fsum(c * c for c in q) == pytest.approx(1.0)
    back = quaternion_to_euler(q)
    assert back == pytest.approx((roll, pitch, yaw), abs=1e-6)


def test_quaternion_matches_ardupilot_pitch_down_from_the_recording() -> None:
    # plane-gimbal.tlog: pitch -90 went out as q = [0.7071, 0, -0.7071, 0]
    assert euler_to_quaternion(0, -90, 0) == pytest.approx((0.70711, 0, -0.70711, 0), abs=1e-4)
