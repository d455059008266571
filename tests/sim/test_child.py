"""The simulator in a child process, driven over its pipe, talked to through the real pty.

A host opens the child's device with the project's ``aa55`` interface, as the bridge does;
every request of the control protocol must be visible from that host. Waits are bounded in
count and time and only ever used as upper limits.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import can
import pytest

from mavservo.servos import RmdX
from mavservo.sim.child import SimulatorProcess, frame_key
from mavservo.transport.aa55.bus import AA55Bus


@pytest.fixture
def child() -> Iterator[tuple[SimulatorProcess, AA55Bus]]:
    sim = SimulatorProcess(2)
    bus = AA55Bus(sim.path, bitrate=1_000_000)
    try:
        yield sim, bus
    finally:
        bus.shutdown()
        sim.stop()
    assert sim.process.returncode == 0


def _collect(
    bus: can.BusABC, seconds: float, keep: Callable[[can.Message], bool], want: int = 100_000
) -> list:
    """Frames that ``keep`` accepts, for ``seconds`` or until ``want`` of them arrived."""
    got = []
    deadline = time.monotonic() + seconds
    for _ in range(100_000):
        left = deadline - time.monotonic()
        if left <= 0:
            break
        msg = bus.recv(timeout=min(left, 0.05))
        if msg is not None and keep(msg):
            got.append(msg)
            if len(got) >= want:
                break
    return got


def _ask(bus: can.BusABC, servo: int, seconds: float = 1.0) -> list[can.Message]:
    for request in RmdX(servo).telemetry_requests():
        bus.send(request)
    reply_id = 0x240 + servo
    return _collect(bus, seconds, lambda m: m.arbitration_id == reply_id, want=1)


def test_servos_answer_and_arrivals_name_the_frames_the_host_sent(child):
    sim, bus = child
    assert _ask(bus, 1) and _ask(bus, 2)
    arrivals = sim.request("arrivals")["arrivals"]
    assert set(arrivals) == {frame_key(r) for s in (1, 2) for r in RmdX(s).telemetry_requests()}
    assert sim.request("arrivals")["arrivals"] == {}  # taken: counting starts again
    assert {k: v for k, v in sim.request("wrong").items() if k != "t"} == {
        "arrived": 2,
        "wrong": 0,
    }
    stats = sim.request("stats")
    assert stats["frames_from_host"] == 2 and stats["adapter_error"] is None
    # the trace follows servo 1's request in and its reply out, in that order
    trace = sim.request("trace", t0=0.0, t1=stats["t"], ids=[0x141, 0x241])["trace"]
    assert [(direction, frame) for _, direction, frame, _ in trace] == [
        ("in", 0x141),
        ("out", 0x241),
    ]
    assert trace[0][0] <= trace[1][3] <= trace[1][0]  # reply finished after the request came


def test_a_silenced_servo_stops_answering_and_the_other_does_not(child):
    sim, bus = child
    sim.request("servo_faults", can_id=2, silent=True)
    assert _ask(bus, 2, seconds=0.3) == []
    assert _ask(bus, 1)
    sim.request("servo_faults", can_id=2, silent=False)
    assert _ask(bus, 2)


def test_lowest_priority_flood_reaches_the_host_and_replies_still_get_through(child):
    sim, bus = child
    sim.request("flood", arbitration_id=0x7FF)
    flood = _collect(bus, 1.1, lambda m: m.arbitration_id == 0x7FF)  # a full 1 s load window
    assert len(flood) > 1000
    assert _ask(bus, 1)
    assert sim.request("stats")["load_1s"] > 0.9
    sim.request("flood", arbitration_id=None)


def test_highest_priority_flood_keeps_the_servos_off_the_bus_until_it_stops(child):
    sim, bus = child
    sim.request("flood", arbitration_id=0x000)
    assert _ask(bus, 1, seconds=0.3) == []
    sim.request("flood", arbitration_id=None)
    # the request waited in the adapter's queue and goes out once the bus is free
    late = _collect(bus, 1.0, lambda m: m.arbitration_id == 0x241, want=1)
    assert late


def test_a_bad_request_is_refused_and_the_child_keeps_running(child):
    sim, bus = child
    with pytest.raises(RuntimeError, match="unknown op"):
        sim.request("explode")
    assert _ask(bus, 1)


def test_frames_the_line_corrupted_into_ones_nobody_sent_are_counted_as_wrong(child):
    sim, bus = child
    sim.request("line", flip_prob=0.05, direction="to_adapter", seed=4)
    command = RmdX(1).position_command(10.0)
    for _ in range(200):
        bus.send(command)
    # the adapter reads at its own pace: keep the line dirty until it has taken everything in
    seen = -1
    for _ in range(50):
        time.sleep(0.05)
        now_seen = sim.request("stats")["frames_from_host"]
        if now_seen == seen:
            break
        seen = now_seen
    sim.request("line")
    _ask(bus, 1)  # a clean frame after the corrupted ones: all of them have been handled
    counts = sim.request("wrong")
    assert 0 < counts["wrong"] < counts["arrived"] <= 201


def test_the_owner_bounds_the_trace_and_the_arrival_counts():
    """A long run passes smaller bounds so the child's memory is full (flat) sooner: the trace
    keeps only the last ``trace_keep`` frames, the counts at most ``max_keys`` distinct ones."""
    sim = SimulatorProcess(2, trace_keep=4, max_keys=1)
    bus = AA55Bus(sim.path, bitrate=1_000_000)
    try:
        for _ in range(3):  # 12 frames traced: each request in, each reply out
            assert _ask(bus, 1) and _ask(bus, 2)
        now = sim.request("stats")["t"]
        trace = sim.request("trace", t0=0.0, t1=now, ids=[0x141, 0x142, 0x241, 0x242])["trace"]
        assert [(direction, frame) for _, direction, frame, _ in trace] == [
            ("in", 0x141),
            ("out", 0x241),
            ("in", 0x142),
            ("out", 0x242),
        ]
        assert sim.request("arrivals")["arrivals"] == {
            frame_key(RmdX(2).telemetry_requests()[0]): 1
        }
    finally:
        bus.shutdown()
        sim.stop()
    assert sim.process.returncode == 0
