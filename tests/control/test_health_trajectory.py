"""Tracking judged against the commanded trajectory (issue 37): a state that reaches the judge
late, as on a loaded machine, is compared with what was commanded up to its own time stamp,
so a servo that follows is never "not following"; one that does not follow still is."""

from __future__ import annotations

from mavservo.control.health import HealthLimits, Sample, ServoHealth

LIMITS = HealthLimits(response_s=0.2, tracking_s=0.3, speed_dps=100.0, tolerance_deg=3.0)
RATE_DPS = 50.0  # the sweep: within the servo's speed
TICK_S = 0.02
STATE_AGE_S = 0.5  # each state judged this long after it was measured (a loaded host)


def setpoint(t: float) -> float:
    return RATE_DPS * t


def judge(position, *, trajectory: bool, seconds: float = 4.0, speed: float = RATE_DPS) -> set[str]:
    """Tick every 20 ms; a state measured every 100 ms is judged STATE_AGE_S later, with the
    setpoint in force at judge time (what the backend's status says then)."""
    health = ServoHealth("s", LIMITS)
    checks: set[str] = set()
    for k in range(int(seconds / TICK_S)):
        now = k * TICK_S
        if trajectory:
            health.command(now, setpoint(now))
        measured = round((now - STATE_AGE_S) / 0.1) * 0.1
        if measured < 0:
            continue
        sample = Sample(measured, setpoint(now), position(measured), speed, 0.5, 30.0)
        for event in health.update(sample):
            if event.active:
                checks.add(event.name)
    return checks


def follows(t: float) -> float:
    return setpoint(t - 0.1)  # 100 ms behind: a healthy servo


def test_a_following_servo_judged_late_is_following_against_the_commanded_trajectory() -> None:
    assert judge(follows, trajectory=True) == set()


def test_without_the_trajectory_the_late_state_reads_as_not_following() -> None:
    """What the judgement did before: the same servo, "not following"."""
    assert judge(follows, trajectory=False) == {"tracking"}


def test_a_servo_that_does_not_follow_is_still_not_following() -> None:
    """Stuck where it was (reporting no speed, little current): not following; the
    trajectory widens the allowance by the state's age, not without end."""
    assert judge(lambda t: 0.0, trajectory=True, speed=0.0) == {"tracking"}
