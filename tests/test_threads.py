"""The background-loop helper: start, stop, restart, a stop from inside, a loop that hangs.

Every wait is bounded by an Event with a timeout; nothing sleeps a fixed time.
"""

from __future__ import annotations

import subprocess
import sys
import threading

import pytest

from mavservo.threads import BackgroundLoop
from tests.support.paths import REPO

WAIT_S = 5.0


class Loop:
    """A loop that counts its rounds and announces that it runs."""

    def __init__(self) -> None:
        self.started = threading.Event()
        self.rounds = 0
        self.loop = BackgroundLoop(self.run, name="test-loop")

    def run(self) -> None:
        self.started.set()
        while not self.loop.stopping:
            self.rounds += 1
            self.loop.wait(0.01)


def test_start_runs_a_named_daemon_thread_and_stop_ends_it() -> None:
    loop = Loop()
    assert not loop.loop.is_running
    loop.loop.start()
    assert loop.started.wait(WAIT_S)
    names = {t.name: t for t in threading.enumerate()}
    assert "test-loop" in names and names["test-loop"].daemon
    assert loop.loop.is_running
    assert loop.loop.stop(WAIT_S)
    assert not loop.loop.is_running and loop.loop.stopping
    assert "test-loop" not in {t.name for t in threading.enumerate()}


def test_a_stopped_loop_can_be_started_again() -> None:
    loop = Loop()
    loop.loop.start()
    assert loop.started.wait(WAIT_S) and loop.loop.stop(WAIT_S)
    loop.started.clear()
    loop.loop.start()
    assert not loop.loop.stopping
    assert loop.started.wait(WAIT_S) and loop.loop.is_running
    assert loop.loop.stop(WAIT_S)


def test_starting_a_running_loop_is_refused() -> None:
    loop = Loop()
    loop.loop.start()
    try:
        with pytest.raises(RuntimeError, match="already running"):
            loop.loop.start()
    finally:
        loop.loop.stop(WAIT_S)


def test_stop_before_start_and_twice_is_harmless() -> None:
    loop = BackgroundLoop(lambda: None, name="never-started")
    assert loop.stop(0.0) and loop.stop(0.0)


def test_wait_returns_at_once_when_a_stop_is_requested() -> None:
    loop = BackgroundLoop(lambda: None, name="idle")
    loop.request_stop()
    assert loop.wait(WAIT_S) is True  # would take WAIT_S without the request


def test_a_loop_may_stop_itself() -> None:
    """The loop's own thread cannot join itself: stop() from inside asks and returns."""
    results: list[bool] = []
    done = threading.Event()

    def run() -> None:
        results.append(loop.stop(WAIT_S))
        done.set()

    loop = BackgroundLoop(run, name="self-stopping")
    loop.start()
    assert done.wait(WAIT_S)
    assert results == [False] and loop.stopping


def test_a_loop_that_ignores_the_request_is_reported_and_not_started_twice(
    caplog: pytest.LogCaptureFixture,
) -> None:
    release = threading.Event()
    loop = BackgroundLoop(lambda: release.wait(WAIT_S), name="stuck")
    loop.start()
    try:
        assert loop.stop(0.0) is False
        assert loop.is_running
        assert "stuck: still running" in caplog.text
        with pytest.raises(RuntimeError, match="already running"):
            loop.start()
    finally:
        release.set()
    assert loop.stop(WAIT_S) and not loop.is_running


def test_join_waits_for_a_loop_that_ends_by_itself() -> None:
    """A bounded run (the simulated autopilot's duration) ends on its own; join() says so and
    the stop Event stays unset for functions that take it."""
    finished = threading.Event()
    loop = BackgroundLoop(finished.set, name="one-shot")
    assert loop.join(0.0) and not loop.started
    loop.start()
    assert loop.started and loop.join(WAIT_S) and finished.is_set()
    assert not loop.stop_event.is_set()
    assert loop.stop(WAIT_S) and loop.stop_event.is_set() and not loop.started


def test_a_started_simulator_used_as_a_context_runs_one_loop() -> None:
    """``with AdapterEmulator(...).start() as e`` started the adapter loop twice (two threads
    on one state) before the helper refused it; now the context reuses the running loop."""
    from mavservo.sim.adapter import AdapterEmulator
    from mavservo.sim.servo import SimServo
    from mavservo.sim.virtual import VirtualServoBus

    with AdapterEmulator([SimServo("rmd-x", 1)]).start() as emulator:
        loops = [t for t in threading.enumerate() if t.name == "sim-usbcan-adapter"]
        assert len(loops) == 1
    assert emulator.error is None
    with VirtualServoBus([SimServo("rmd-x", 1)], channel="threads-test").start():
        assert [t.name for t in threading.enumerate()].count("sim-virtual-bus") == 1


_SIGNAL_IN_THE_WAIT_WINDOW = """
import os, signal, sys, threading
from mavservo.threads import set_from_signal_handler
event = threading.Event()
handler = {handler}
signal.signal(signal.SIGTERM, handler)
# the window: the main thread holds the event's own lock, as inside event.wait() between
# waking up and returning; the signal's handler runs here, in this thread
with event._cond:
    os.kill(os.getpid(), signal.SIGTERM)
    sum(range(1000))  # a few bytecodes: the handler runs among them
sys.exit(0 if event.wait(5.0) else 3)
"""


@pytest.mark.parametrize(
    ("handler", "stops"),
    [
        pytest.param("lambda *_: set_from_signal_handler(event)", True, id="the helper"),
        pytest.param("lambda *_: event.set()", False, id="event.set() in the handler"),
    ],
)
def test_a_stop_signal_landing_inside_the_events_wait_still_stops(
    handler: str, stops: bool
) -> None:
    """``mavservo run``/``sim``/``sitl`` stop on a signal by setting the event their main loop
    waits on. A handler that calls ``event.set()`` deadlocks when the signal lands while the
    main thread holds the event's lock inside ``event.wait()`` (it hung ``mavservo sim`` in
    CI: killed after 20 s); the helper sets it from a thread. The window is held open here
    on purpose, in a child process, bounded by a timeout."""
    code = _SIGNAL_IN_THE_WAIT_WINDOW.format(handler=handler)
    try:
        done = subprocess.run(
            [sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=6
        )
        stopped = done.returncode == 0
    except subprocess.TimeoutExpired:
        stopped = False  # the handler is still waiting for the lock its own thread holds
    assert stopped is stops
