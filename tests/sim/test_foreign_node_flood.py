"""A foreign node flooding the simulated CAN bus, in simulated time (no clock, no threads).

The flood is played as segments of back-to-back frames; these tests pin that it stays a
faithful bus: arbitration by ID against every other frame, each frame its real duration,
the load it produces, and an adapter-sized transmit queue when the host can never get on.
"""

from __future__ import annotations

import math

import pytest

from mavservo.scheduling.busload import frame_time
from mavservo.servos import RmdX
from mavservo.sim.canbus import SimCanBus
from mavservo.sim.servo import SimServo

BITRATE = 1_000_000
FLOOD = frame_time(False, 8, BITRATE)  # one 8-byte standard frame
REQUEST = frame_time(False, 8, BITRATE)


def _play(bus: SimCanBus, until: float, step: float, start: float = 0.0) -> list:
    """Drive the bus like the adapter thread does: ``run_until`` every ``step`` seconds."""
    out = []
    t = start
    for _ in range(int(round((until - start) / step))):
        t += step
        out += bus.run_until(t)
    return out


def test_lowest_priority_flood_fills_the_bus_and_loses_every_arbitration():
    bus = SimCanBus([SimServo("rmd-x", 1, reply_latency_s=0.0)], BITRATE)
    bus.set_flood(0x7FF, now=0.0)
    seen = _play(bus, 0.5, step=0.002)
    assert bus.flood is not None
    assert bus.flood.sent == pytest.approx(0.5 / FLOOD, abs=2)
    assert bus.load(0.5, window=0.5) == pytest.approx(1.0, abs=1e-6)
    assert all(msg.arbitration_id == 0x7FF for _, msg in seen)

    # a request ready in the middle of a flood frame waits for that frame only, then wins
    ready = 0.5 + 0.3 * FLOOD
    bus.submit(RmdX(1).telemetry_requests()[0], ready)
    seen = _play(bus, 0.6, step=0.002, start=0.5)
    [(reply_end, reply)] = [(t, m) for t, m in seen if m.arbitration_id != 0x7FF]
    assert reply.arbitration_id == 0x241
    # the request starts when the flood frame in flight ends (flood frames follow each other
    # from t = 0), then the reply wins the next arbitration too (0x241 < 0x7FF)
    flood_end = math.ceil(ready / FLOOD) * FLOOD
    assert flood_end - ready < FLOOD
    assert reply_end == pytest.approx(flood_end + REQUEST + frame_time(False, 8, BITRATE))
    assert bus.load(0.6, window=0.1) == pytest.approx(1.0, abs=1e-6)


def test_highest_priority_flood_starves_the_host_and_its_queue_stays_bounded():
    bus = SimCanBus([SimServo("rmd-x", 1, reply_latency_s=0.0)], BITRATE, host_queue=8)
    bus.set_flood(0x000, now=0.0)
    request = RmdX(1).telemetry_requests()[0]
    t = 0.0
    seen = []
    for _ in range(100):  # the host keeps trying every 10 ms for a second
        t += 0.01
        bus.submit(request, t)
        seen += bus.run_until(t)
    assert all(msg.arbitration_id == 0x000 for _, msg in seen)
    assert bus.host_dropped == 100 - 8
    assert bus.load(t, window=1.0) == pytest.approx(1.0, abs=1e-3)

    # the flood stops: the queued requests go out, oldest first, and get their replies
    bus.set_flood(None, now=t)
    replies = bus.run_until(t + 0.1)
    assert [m.arbitration_id for _, m in replies[-8:]] == [0x241] * 8


def test_flood_frames_to_the_host_share_one_message_object():
    bus = SimCanBus([], BITRATE)
    bus.set_flood(0x123, now=0.0)
    seen = bus.run_until(0.01)
    assert len(seen) == int(0.01 / FLOOD)  # finished by now; the one on the wire is not
    assert len({id(msg) for _, msg in seen}) == 1
    assert max(t for t, _ in seen) <= 0.01


@pytest.mark.parametrize("uptime_s", [0.0, 40_000.0, 1_000_000.0])
def test_every_flood_frame_on_the_bus_reaches_the_host_whatever_the_clock_reads(
    uptime_s: float,
) -> None:
    """The driver's times are monotonic seconds since boot. Past 2**15 s their rounding made a
    finished run's frame count come out one short half the time: half the flood never reached
    the host (the bridge then measured 62 % bus load under a full flood)."""
    bus = SimCanBus([], 125_000)
    bus.set_flood(0x7FF, now=uptime_s + 0.123)
    seen = _play(bus, uptime_s + 2.123, step=0.0011, start=uptime_s + 0.123)
    assert bus.frames > 1_800  # 2 s of 1.08 ms frames
    assert len(seen) == bus.flood.sent >= bus.frames - 1  # the run in flight may still be on
