"""The lifecycle part alone (scheduling/lifecycle.py): when start-up and release frames are due."""

from __future__ import annotations

import math

from mavservo.scheduling.lifecycle import STARTUP_RETRY_S, Lifecycles, ServoLifecycle
from mavservo.servos import RmdX, release_frames_of


def test_start_up_goes_before_the_first_command_and_a_restart_waits_for_the_retry_interval():
    life = ServoLifecycle(RmdX(1))
    first = life.startup_frames(10.0)
    assert first is not None and [m.data[0] for m in first] == [0xB3]
    assert life.startup_frames(10.05) is None  # started, and RMD-X needs no more
    life.restart()  # back online: again, but never twice within STARTUP_RETRY_S
    assert life.startup_frames(10.0 + STARTUP_RETRY_S / 2) is None
    assert life.startup_frames(10.0 + STARTUP_RETRY_S) is not None


def test_a_release_makes_the_next_start_up_go_at_once_even_within_the_retry_interval():
    lifecycles = Lifecycles([("a", RmdX(1))])
    life = lifecycles.servos["a"]
    assert life.startup_frames(10.0) is not None
    lifecycles.release("a")
    assert life.startup_frames(10.1) is not None


def test_release_frames_are_due_at_once_in_configuration_order_and_taken_once():
    lifecycles = Lifecycles([("b", RmdX(2)), ("a", RmdX(1))])
    assert lifecycles.next_release() == math.inf and not lifecycles.wants_wake()
    assert lifecycles.due_releases(5.0) == ()
    lifecycles.release("a")
    lifecycles.release("b")
    assert lifecycles.wants_wake()
    due = lifecycles.due_releases(5.0)
    assert [name for name, _ in due] == ["b", "a"]
    assert [frames[0].data[0] for _, frames in due] == [0x80, 0x80]
    assert lifecycles.due_releases(5.0) == () and lifecycles.next_release() == math.inf


def test_a_new_setpoint_cancels_a_pending_release_and_a_refused_one_waits_for_the_next_slot():
    lifecycles = Lifecycles([("a", RmdX(1))])
    lifecycles.release("a")
    lifecycles.cancel_release("a")
    assert lifecycles.due_releases(5.0) == ()
    lifecycles.release_refused("a", released=True, next_slot=5.05)
    assert lifecycles.next_release() == 5.05 and not lifecycles.wants_wake()
    assert not lifecycles.due_releases(5.0)
    assert [name for name, _ in lifecycles.due_releases(5.05)] == ["a"]
    lifecycles.release_refused("a", released=False, next_slot=5.1)  # commanded again meanwhile
    assert lifecycles.next_release() == math.inf


def test_the_stop_sends_a_pending_release_then_the_shutdown_frames():
    profile = RmdX(1)
    lifecycles = Lifecycles([("a", profile)])
    assert lifecycles.final_frames("a") == ([], profile.shutdown_frames())
    lifecycles.release("a")
    release, shutdown = lifecycles.final_frames("a")
    assert [m.data[0] for m in release] == [m.data[0] for m in release_frames_of(profile)]
    assert shutdown == profile.shutdown_frames()
    assert lifecycles.final_frames("a")[0] == []
