"""GimbalPointing alone: the demand in effect, driven to a recording servo side."""

from __future__ import annotations

import pytest

from mavservo.mavlink.backend import ApplyResult, Outcome
from mavservo.mavlink.gimbal_pointing import (
    NEUTRAL,
    PITCH_LOCK,
    RETRACT,
    YAW_IN_VEHICLE_FRAME,
    YAW_LOCK,
    Demand,
    GimbalPointing,
    Mode,
)
from mavservo.mavlink.gimbal_settings import GimbalCounters, GimbalSettings

SETTINGS = GimbalSettings(
    name="cam",
    axis_servos={"pitch": "p", "yaw": "y"},
    limits_deg={"pitch": (-90.0, 30.0), "yaw": (-160.0, 160.0)},
)


class RecordingDrive:
    """The servo side: records each request, answers ``outcome``."""

    def __init__(self) -> None:
        self.calls: list[tuple[float | None, float | None, float | None]] = []
        self.outcome = Outcome.ACCEPTED

    def apply_gimbal(self, gimbal, roll_deg, pitch_deg, yaw_deg, source, now) -> ApplyResult:
        assert (gimbal, source) == ("cam", "gimbal")
        self.calls.append((roll_deg, pitch_deg, yaw_deg))
        return ApplyResult(self.outcome, "" if self.outcome is Outcome.ACCEPTED else "offline")


def make(measured=(0.0, 0.0, 0.0)) -> tuple[GimbalPointing, RecordingDrive, GimbalCounters]:
    drive, counters = RecordingDrive(), GimbalCounters()
    return GimbalPointing(SETTINGS, drive, counters, measured=lambda: measured), drive, counters


def test_an_unchanged_target_is_sent_once_and_a_change_is_sent() -> None:
    pointing, drive, counters = make()
    for t in (0.0, 0.02, 0.04):
        pointing.point(Demand(Mode.ANGLE, (5.0, -20.0, 10.0)), t)
    pointing.point(Demand(Mode.ANGLE, (0.0, -25.0, 10.0)), 0.06)
    # roll has no servo: never sent
    assert drive.calls == [(None, -20.0, 10.0), (None, -25.0, 10.0)]
    assert counters.applied == 2


def test_a_refused_demand_is_forgotten_and_the_same_demand_later_is_fresh() -> None:
    pointing, drive, counters = make()
    drive.outcome = Outcome.TEMPORARILY_REJECTED
    result = pointing.point(Demand(Mode.ANGLE, (0.0, -10.0, 0.0)), 0.0)
    assert result.outcome is Outcome.TEMPORARILY_REJECTED
    assert pointing.demand is None and counters.rejected == 1
    pointing.advance(1.0)
    assert len(drive.calls) == 1  # never retried
    drive.outcome = Outcome.ACCEPTED
    assert pointing.point(Demand(Mode.ANGLE, (0.0, -10.0, 0.0)), 2.0).ok
    assert len(drive.calls) == 2


def test_an_earth_frame_yaw_waits_for_the_heading_then_follows_it() -> None:
    pointing, drive, _ = make()
    pointing.point(Demand(Mode.ANGLE, (0.0, 0.0, 90.0), yaw_in_earth_frame=True), 0.0)
    assert drive.calls == [(None, 0.0, None)]
    pointing.follow_vehicle_yaw(30.0, 0.1)
    pointing.follow_vehicle_yaw(60.0, 0.2)
    assert drive.calls[1:] == [(None, 0.0, 60.0), (None, 0.0, 30.0)]
    assert pointing.status_flags() & YAW_LOCK


def test_a_target_beyond_a_limit_is_clamped_and_counted_once() -> None:
    pointing, drive, counters = make()
    pointing.point(Demand(Mode.ANGLE, (0.0, 80.0, 0.0)), 0.0)
    pointing.point(Demand(Mode.ANGLE, (0.0, 85.0, 0.0)), 0.1)
    assert drive.calls == [(None, 30.0, 0.0)]
    assert pointing.clamped_axes == frozenset({"pitch"}) and counters.clamped == 1
    pointing.point(Demand(Mode.ANGLE, (0.0, 0.0, 0.0)), 0.2)
    assert pointing.clamped_axes == frozenset()


def test_rates_integrate_from_the_measured_angles_within_the_limits() -> None:
    pointing, drive, _ = make(measured=(0.0, 10.0, -5.0))
    pointing.start_rates((None, -20.0, None), flags=0, now=0.0)
    pointing.advance(1.0)
    pointing.advance(10.0)
    assert drive.calls == [(None, 10.0, -5.0), (None, -10.0, -5.0), (None, -90.0, -5.0)]


@pytest.mark.parametrize(
    ("demand", "flags"),
    [
        (None, YAW_IN_VEHICLE_FRAME),
        (Demand(Mode.RETRACT, flags=RETRACT), YAW_IN_VEHICLE_FRAME | RETRACT),
        (Demand(Mode.NEUTRAL, flags=NEUTRAL), YAW_IN_VEHICLE_FRAME | NEUTRAL),
        (Demand(Mode.ANGLE, (0.0, 0.0, 0.0), False, PITCH_LOCK), YAW_IN_VEHICLE_FRAME | PITCH_LOCK),
    ],
)
def test_status_flags_echo_the_demand_in_effect(demand, flags) -> None:
    pointing, _, _ = make()
    if demand is not None:
        pointing.point(demand, 0.0)
    assert pointing.status_flags() == flags


def test_retract_goes_to_the_lower_pitch_limit_by_default() -> None:
    pointing, drive, _ = make()
    pointing.point(Demand(Mode.RETRACT, flags=RETRACT), 0.0)
    assert drive.calls == [(None, -90.0, 0.0)]
