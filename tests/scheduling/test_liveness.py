"""Online/offline alone (scheduling/liveness.py): misses, silent pushers, refused sends."""

from __future__ import annotations

import pytest

from mavservo.scheduling.liveness import Liveness

MISSES = 3
TIMEOUT = 0.05


def make(*servos: tuple[str, float | None]) -> Liveness:
    liveness = Liveness(list(servos), MISSES, TIMEOUT)
    liveness.anchor(10.0)
    return liveness


def test_a_polled_servo_is_offline_at_the_third_miss_in_a_row_and_back_with_its_next_reply():
    liveness = make(("p", None))
    assert [liveness.missed("p", on_send=False) for _ in range(4)] == [False, False, True, False]
    assert not liveness.is_online("p")
    assert liveness.heard("p", 11.0) is True and liveness.is_online("p")
    assert liveness.heard("p", 11.1) is False
    assert liveness.fell_silent(100.0) == ()  # a polled servo's silence is its misses


def test_a_pushing_servo_falls_silent_after_its_limit_once():
    liveness = make(("push", 0.1), ("p", None))
    limit = MISSES * 0.1 + TIMEOUT
    assert liveness.silence_limit_s("push") == pytest.approx(limit)
    assert liveness.silence_limit_s("p") is None
    assert liveness.fell_silent(10.0 + limit) == ()
    assert list(liveness.fell_silent(10.0 + limit + 0.01)) == ["push"]
    assert not liveness.is_online("push")
    assert liveness.fell_silent(20.0) == ()  # already offline: not again
    assert liveness.heard("push", 20.0) is True
    assert liveness.fell_silent(20.0 + limit - 0.01) == ()


def test_refused_sends_bring_back_only_a_servo_nothing_else_could():
    liveness = make(("idle", None), ("polled", None), ("push", 0.1))
    for name in ("idle", "polled", "push"):
        for _ in range(MISSES):
            liveness.missed(name, on_send=True)
    assert liveness.offline_on_sends == {"idle", "polled", "push"}
    back = liveness.back_on_send(lambda name: name == "idle")
    assert back == ["idle"] and liveness.is_online("idle")
    assert liveness.offline_on_sends == {"polled", "push"}  # a reply or a push brings them
    liveness.heard("polled", 11.0)
    assert liveness.offline_on_sends == {"push"}
