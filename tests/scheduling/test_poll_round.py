"""The telemetry loop's round alone (scheduling/poll_round.py): ticks, order, deferral."""

from __future__ import annotations

import pytest

from mavservo.scheduling.poll_round import PollRound

T_T = 0.1
COST = 0.001


def never_outstanding(name: str) -> bool:
    return False


def make_round(*names: str, period: float = T_T, phase: float = 0.02) -> PollRound:
    polls = PollRound([(name, period, COST) for name in names], T_T, phase)
    polls.anchor(10.0)
    return polls


def test_ticks_are_phased_after_the_start_and_a_late_loop_serves_the_latest_tick_only():
    polls = make_round("a")
    assert polls.tick(10.0) is None and polls.next_tick == pytest.approx(10.02)
    assert polls.tick(10.02) == pytest.approx(10.02)
    assert polls.tick(10.35) == pytest.approx(10.32)  # 10.12 and 10.22 are not replayed
    assert polls.next_tick == pytest.approx(10.42)


def test_a_round_goes_in_configuration_order_and_what_does_not_fit_keeps_the_front():
    polls = make_round("a", "b", "c")
    polls.tick(10.02)
    assert polls.take(10.02, 2.5 * COST, never_outstanding, []) == ["a", "b"]
    assert polls.round == ["c"]
    polls.tick(10.12)  # the next round: the leftover first, then the servos due again
    assert polls.round == ["c", "a", "b"]


def test_a_servo_with_its_request_out_is_skipped_and_a_late_poll_is_named():
    polls = make_round("a", "b")
    polls.tick(10.02)
    late: list[str] = []
    assert polls.take(10.02, 1.0, lambda name: name == "a", late) == ["b"]
    assert polls.round == ["a"] and late == []
    assert polls.take(10.02 + 0.6 * T_T, 1.0, never_outstanding, late) == ["a"]
    assert late == ["a"]
    assert polls.waiting(never_outstanding) is False


def test_a_servo_far_behind_is_not_caught_up_with_a_burst():
    polls = make_round("a", period=T_T)
    polls.tick(10.02)
    assert polls.take(15.0, 1.0, never_outstanding, []) == ["a"]
    assert polls.tick(15.02) is not None
    assert polls.round == []  # its next poll is a period after it was served, not overdue
    assert polls.tick(15.12) is not None and polls.round == ["a"]
