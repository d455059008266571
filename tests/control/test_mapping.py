"""Channel mapping math: examples from the recorded plane, rejections, and properties."""

from __future__ import annotations

import math

import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from mavservo.config import default_config_path, load_config
from mavservo.control.mapping import (
    PWM_VALID_US,
    ChannelMap,
    Rejected,
    RejectReason,
    Target,
    channel_maps,
    clamp,
    slew_limit,
)


def pwm_map(**overrides) -> ChannelMap:
    values = dict(
        kind="pwm",
        input_min=1100.0,
        input_trim=1500.0,
        input_max=1900.0,
        output_deg=(-30.0, 30.0),
        limits_deg=(-180.0, 180.0),
    )
    values.update(overrides)
    return ChannelMap(**values)


def angle(channel_map: ChannelMap, value: float) -> float:
    target = channel_map.to_angle(value)
    assert isinstance(target, Target), target
    return target.angle_deg


# --------------------------------------------------------------------------------- examples


def test_recorded_aileron_outputs_land_on_range_and_centre():
    # plane-servos.tlog: servo1 moves 1100..1900 around 1500 in 160 us steps.
    channel_map = pwm_map()
    outputs = [1100, 1260, 1420, 1500, 1580, 1740, 1900]
    angles = [angle(channel_map, pwm) for pwm in outputs]
    assert angles[0] == -30 and angles[3] == 0 and angles[-1] == 30
    steps = [b - a for a, b in zip(angles, angles[1:], strict=False)]
    assert all(step > 0 for step in steps)
    assert steps[1] == pytest.approx(steps[4])  # symmetric range: equal steps both sides


def test_asymmetric_trim_is_piecewise_so_trim_hits_the_centre():
    channel_map = pwm_map(input_trim=1400.0, trim_deg=5.0)
    assert angle(channel_map, 1400) == pytest.approx(5.0)
    assert angle(channel_map, 1100) == pytest.approx(-30.0)
    assert angle(channel_map, 1900) == pytest.approx(30.0)
    # halfway on each side lands halfway between the centre and that end
    assert angle(channel_map, 1250) == pytest.approx((-30 + 5) / 2)
    assert angle(channel_map, 1650) == pytest.approx((30 + 5) / 2)


def test_reverse_swaps_the_ends_and_keeps_the_centre():
    channel_map = pwm_map(reverse=True, trim_deg=2.0)
    assert angle(channel_map, 1100) == pytest.approx(30.0)
    assert angle(channel_map, 1900) == pytest.approx(-30.0)
    assert angle(channel_map, 1500) == pytest.approx(2.0)


def test_valid_pwm_beyond_the_input_range_saturates():
    channel_map = pwm_map()
    assert angle(channel_map, 2000) == angle(channel_map, 1900)
    assert angle(channel_map, 900) == angle(channel_map, 1100)


def test_soft_limits_clamp_and_say_so():
    channel_map = pwm_map(output_deg=(-60.0, 60.0), limits_deg=(-20.0, 45.0))
    high = channel_map.to_angle(1900)
    assert isinstance(high, Target) and high.clamped
    assert high.angle_deg == 45.0 and high.requested_deg == 60.0
    inside = channel_map.to_angle(1550)
    assert isinstance(inside, Target) and not inside.clamped


def test_normalized_input_maps_the_actuator_range():
    channel_map = ChannelMap(
        kind="normalized",
        input_min=-1.0,
        input_trim=0.0,
        input_max=1.0,
        output_deg=(0.0, 40.0),
        limits_deg=(0.0, 40.0),
    )
    assert angle(channel_map, -1.0) == 0.0
    assert angle(channel_map, 0.0) == 20.0
    assert angle(channel_map, 1.0) == 40.0


@pytest.mark.parametrize(
    ("value", "reason"),
    [
        (math.nan, RejectReason.NOT_FINITE),
        (math.inf, RejectReason.NOT_FINITE),
        (-math.inf, RejectReason.NOT_FINITE),
        (0.0, RejectReason.NO_PULSE),
        (PWM_VALID_US[0] - 1, RejectReason.OUT_OF_RANGE),
        (PWM_VALID_US[1] + 1, RejectReason.OUT_OF_RANGE),
        (65535.0, RejectReason.OUT_OF_RANGE),
    ],
)
def test_bad_pwm_is_a_typed_rejection_not_a_position(value: float, reason: RejectReason):
    result = pwm_map().to_angle(value)
    assert isinstance(result, Rejected)
    assert result.reason is reason
    assert result.detail
    assert result.ignore_silently == (reason is RejectReason.NO_PULSE)


@pytest.mark.parametrize("value", [math.nan, 1.5, -1.01])
def test_bad_normalized_values_are_rejected(value: float):
    channel_map = ChannelMap(
        kind="normalized",
        input_min=-1.0,
        input_trim=0.0,
        input_max=1.0,
        output_deg=(-10.0, 10.0),
        limits_deg=(-10.0, 10.0),
    )
    assert isinstance(channel_map.to_angle(value), Rejected)


def test_inverse_gives_normalized_and_pwm_for_display():
    channel_map = pwm_map(reverse=True)
    assert channel_map.angle_to_normalized(30.0) == pytest.approx(-1.0)
    assert channel_map.angle_to_input(30.0) == pytest.approx(1100.0)
    assert channel_map.angle_to_input(0.0) == pytest.approx(1500.0)
    assert channel_map.angle_to_normalized(90.0) == pytest.approx(-1.0)  # saturates


def test_slew_limit_examples():
    assert slew_limit(0.0, 10.0, 0.05, 100.0) == pytest.approx(5.0)
    assert slew_limit(0.0, -10.0, 0.05, 100.0) == pytest.approx(-5.0)
    assert slew_limit(0.0, 3.0, 0.05, 100.0) == 3.0
    assert slew_limit(1.0, 9.0, 0.0, 100.0) == 1.0
    assert slew_limit(1.0, 9.0, -0.5, 100.0) == 1.0
    with pytest.raises(ValueError):
        slew_limit(0.0, 1.0, 0.1, 0.0)


def test_channel_slew_passes_through_without_a_limit_or_a_previous_target():
    assert pwm_map().slew(0.0, 25.0, 0.01) == 25.0
    assert pwm_map(max_slew_dps=100.0).slew(None, 25.0, 0.01) == 25.0
    assert pwm_map(max_slew_dps=100.0).slew(0.0, 25.0, 0.01) == pytest.approx(1.0)


def test_inconsistent_maps_are_refused():
    with pytest.raises(ValueError):
        pwm_map(input_trim=1900.0)
    with pytest.raises(ValueError):
        pwm_map(trim_deg=40.0)


def test_maps_built_from_the_default_config_follow_its_channels():
    config = load_config(default_config_path())
    maps = channel_maps(config)
    assert len(maps) == len(config.channels)
    for channel, channel_map in zip(config.channels, maps, strict=True):
        low, high = config.channel_output_deg(channel)
        at_max = angle(channel_map, channel.input.max)
        assert at_max == pytest.approx(low if channel.reverse else high)
        assert channel_map.kind == ("pwm" if channel.source == "servo_output" else "normalized")


# ------------------------------------------------------------------------------- properties

finite = st.floats(min_value=-1e3, max_value=1e3, allow_nan=False, allow_infinity=False)


@st.composite
def channel_maps_strategy(draw) -> ChannelMap:
    kind = draw(st.sampled_from(["pwm", "normalized"]))
    if kind == "pwm":
        points = sorted(draw(st.lists(st.integers(800, 2200), min_size=3, max_size=3, unique=True)))
    else:
        points = sorted(draw(st.lists(st.floats(-1, 1), min_size=3, max_size=3, unique=True)))
        assume(points[1] - points[0] > 1e-3 and points[2] - points[1] > 1e-3)
    low = draw(st.floats(-360, 300))
    high = low + draw(st.floats(1, 360))
    span = high - low
    trim_deg = draw(st.floats(-0.45, 0.45)) * span
    lim_low = draw(st.floats(-400, 400))
    lim_high = lim_low + draw(st.floats(1, 400))
    return ChannelMap(
        kind=kind,
        input_min=float(points[0]),
        input_trim=float(points[1]),
        input_max=float(points[2]),
        output_deg=(low, high),
        limits_deg=(lim_low, lim_high),
        reverse=draw(st.booleans()),
        trim_deg=trim_deg,
        max_slew_dps=draw(st.none() | st.floats(1, 1000)),
    )


def _valid_input(channel_map: ChannelMap, fraction: float) -> float:
    if channel_map.kind == "pwm":
        return PWM_VALID_US[0] + fraction * (PWM_VALID_US[1] - PWM_VALID_US[0])
    return -1.0 + 2.0 * fraction


@given(channel_maps_strategy(), st.floats(0, 1), st.floats(0, 1))
def test_mapping_is_monotonic_in_the_configured_direction(channel_map, f1, f2):
    a, b = sorted((_valid_input(channel_map, f1), _valid_input(channel_map, f2)))
    angle_a, angle_b = angle(channel_map, a), angle(channel_map, b)
    if channel_map.reverse:
        assert angle_a >= angle_b
    else:
        assert angle_a <= angle_b


@given(channel_maps_strategy(), st.floats(0, 1))
def test_limits_are_never_exceeded(channel_map, fraction):
    result = angle(channel_map, _valid_input(channel_map, fraction))
    assert channel_map.limits_deg[0] <= result <= channel_map.limits_deg[1]


@given(channel_maps_strategy(), st.floats(0, 1))
def test_inverse_round_trips_inside_the_input_range(channel_map, fraction):
    wide = ChannelMap(**{**channel_map.__dict__, "limits_deg": (-1e4, 1e4)})
    value = wide.input_min + fraction * (wide.input_max - wide.input_min)
    target = angle(wide, value)
    assert wide.angle_to_input(target) == pytest.approx(value, abs=1e-6 * max(1.0, abs(value)))
    normalized = wide.angle_to_normalized(target)
    assert -1.0 - 1e-9 <= normalized <= 1.0 + 1e-9


@given(finite, finite, st.floats(-1, 10), st.floats(0.1, 1e4))
def test_slew_is_never_exceeded_and_never_overshoots(previous, target, dt, rate):
    result = slew_limit(previous, target, dt, rate)
    assert abs(result - previous) <= rate * max(0.0, dt) + 1e-9
    lo, hi = sorted((previous, target))
    assert lo - 1e-9 <= result <= hi + 1e-9
    if dt > 0 and abs(target - previous) <= rate * dt:
        assert result == target


@given(finite, finite, finite)
def test_clamp_reports_exactly_when_it_moves(value, a, b):
    assume(a != b)
    limits = (min(a, b), max(a, b))
    result, moved = clamp(value, limits)
    assert limits[0] <= result <= limits[1]
    assert moved == (result != value)
