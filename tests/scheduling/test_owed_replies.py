"""The replies a servo owes, alone (scheduling/owed_replies.py): matching, late, pushes."""

from __future__ import annotations

import pytest

from mavservo.scheduling.owed_replies import OwedReplies

TIMEOUT = 0.05


def test_a_reply_answers_the_expectation_of_its_kind_and_times_a_command():
    owed = OwedReplies(only_when_asked=True, keyed_pushes=False)
    owed.expect("request", 1.0, TIMEOUT, 0x9C, 1)
    owed.expect("command", 1.0, TIMEOUT, 0xA4, 1)
    assert owed.request_outstanding
    command = owed.match(1.002, 0xA4, back_online=False)
    assert command.kind == "command" and command.latency_s == pytest.approx(0.002)
    request = owed.match(1.003, 0x9C, back_online=True)
    assert request.kind == "request" and request.latency_s is None and request.back_online
    assert not owed.expected


def test_a_reply_after_its_timeout_is_late_with_its_latency_from_the_timed_out_request():
    owed = OwedReplies(only_when_asked=True, keyed_pushes=False)
    owed.expect("request", 1.0, TIMEOUT, 0x9C, 1)
    assert owed.expire(1.0 + TIMEOUT / 2) == 0
    assert owed.expire(1.0 + TIMEOUT) == 1 and not owed.expected
    late = owed.match(1.08, 0x9C, back_online=False)
    assert late.kind == "late" and late.late_latency_s == pytest.approx(0.08)
    again = owed.match(1.09, 0x9C, back_online=False)
    assert again.kind == "late" and again.late_latency_s is None  # each timed out answers once


def test_a_pushing_servo_pushes_between_commands_and_its_first_report_times_the_command():
    owed = OwedReplies(only_when_asked=False, keyed_pushes=False)
    assert owed.match(1.0, None, back_online=False).kind is None  # a push, not late
    owed.awaiting_first_since = 2.0  # a command that provokes no reply went out
    first = owed.match(2.004, None, back_online=False)
    assert first.kind is None and first.latency_s == pytest.approx(0.004)
    assert owed.match(2.01, None, back_online=False).latency_s is None


def test_a_push_told_apart_from_the_answers_due_is_not_late():
    owed = OwedReplies(only_when_asked=False, keyed_pushes=True)
    owed.expect("command", 1.0, TIMEOUT, "answer", 1)
    assert owed.match(1.001, "report", back_online=False).kind is None
    assert owed.match(1.002, "answer", back_online=False).kind == "command"


def test_a_refused_frame_owes_nothing():
    owed = OwedReplies(only_when_asked=True, keyed_pushes=False)
    kept = owed.expect("request", 1.0, TIMEOUT, None, 1)
    refused = owed.expect("command", 1.0, TIMEOUT, None, 2)
    owed.forget(refused)
    assert tuple(owed.expected) == kept
