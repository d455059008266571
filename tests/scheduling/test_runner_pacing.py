"""The runner's waits alone (scheduling/runner_pacing.py), on a clock the test moves."""

from __future__ import annotations

import threading

from mavservo.scheduling.runner_pacing import RunnerPacing
from mavservo.scheduling.schedule_core import TimingConfig


class SteppingClock:
    """Each read advances by ``step``: a spin that reads it reaches any deadline."""

    def __init__(self, step: float) -> None:
        self.now = 0.0
        self.step = step
        self.reads = 0

    def __call__(self) -> float:
        self.reads += 1
        self.now += self.step
        return self.now


def make(clock: SteppingClock) -> tuple[RunnerPacing, threading.Event, threading.Event]:
    stop, wake = threading.Event(), threading.Event()
    timing = TimingConfig(spin_s=1.0)  # every wait below is within the spin
    return RunnerPacing("bus0", timing, clock, stop, wake), stop, wake


def test_a_wait_within_the_spin_returns_at_the_deadline():
    clock = SteppingClock(0.01)
    pacing, _, _ = make(clock)
    pacing.wait_until(0.1)
    assert 0.1 <= clock.now < 0.15


def test_a_wake_ends_the_wait_at_once_and_is_consumed():
    clock = SteppingClock(0.0)  # a clock that never reaches the deadline
    pacing, _, wake = make(clock)
    wake.set()
    pacing.wait_until(1.0)
    assert not wake.is_set()


def test_a_stopped_runner_does_not_wait():
    clock = SteppingClock(0.0)
    pacing, stop, _ = make(clock)
    stop.set()
    pacing.wait_until(1.0)
    assert clock.reads == 0


def test_without_realtime_asked_the_status_says_so_and_the_spin_is_the_configured_one():
    pacing, _, _ = make(SteppingClock(0.0))
    pacing.apply_realtime(50, "runner")
    assert pacing.realtime_status == "not requested"
    assert pacing.spin_s == 1.0
