"""The paper's multi-step experiment through the whole bridge, checked for its structure.

The stream simulator (sitl AutopilotStream, the "staircase" profile) plays the autopilot over
UDP; two servos (RMD-X polled, CubeMars pushing) follow a wide staircase through the aa55 path.
Recorded from the scheduler: position, velocity and current of every reply. Checked: each step
level is reached and held, in order; telemetry intervals cluster at the poll period (no poll skipped
systematically) and the run's latency, jitter and bus-utilisation figures are present and
consistent with a clean line (nothing lost, late or rejected, load under the budget). Nothing is
written to docs from here: the numbers belong to bench/ runs.
"""

from __future__ import annotations

import math
import threading

import pytest

from mavservo.sim.autopilot.motion_scripts import StaircaseProfile
from mavservo.sim.autopilot.stream import AutopilotStream
from tests.support.bridge import running
from tests.support.waiting import wait_until

# a bridge thread dying (an exception nobody catches) fails the test, not just warns
pytestmark = pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")

STEPS = 6
HOLD_S = 0.6

CONFIG = """
servos:
  - {name: wide, profile: rmd-x, can_id: 1, limits_deg: [-120, 120], telemetry_hz: 11}
  - {name: pushy, profile: cubemars-ak, can_id: 2, limits_deg: [-120, 120], telemetry_hz: 20}
channels:
  - {servo: wide, source: servo_output, channel: 1, input: {min: 1100, max: 1900},
     output_deg: [-120, 120]}
  - {servo: pushy, source: servo_output, channel: 2, input: {min: 1100, max: 1900},
     output_deg: [-120, 120]}
# a reply counts as lost only when it never comes: a loaded shared machine can delay one
# past the usual 50 ms, and that is timing, which these tests do not judge
scheduler: {reply_timeout_s: 0.5}
simulation:
  servos:
    default: {physics: {max_speed_dps: 900, max_accel_dps2: 9000}}
"""


def test_staircase_levels_reached_in_order_with_clean_timing_structure() -> None:
    profile = StaircaseProfile(steps=STEPS, hold_s=HOLD_S)
    # the angles of the PWMs the profile really sends (whole microseconds) on channel 1 / 2
    pwms = [profile.pwm((i + 0.5) * HOLD_S)[0] for i in range(STEPS + 1)]
    assert pwms == sorted(pwms) and pwms[0] == 1100 and pwms[-1] == 1900
    levels = [-120 + 240 * (pwm - 1100) / 800 for pwm in pwms]
    samples: dict[str, list[tuple[float, float, float, float]]] = {"wide": [], "pushy": []}
    lock = threading.Lock()

    def on_state(servo: str, state) -> None:
        with lock:
            samples[servo].append(
                (state.timestamp, state.position_deg, state.velocity_dps, state.current_a)
            )

    with running(CONFIG) as (bridge, port):
        bridge.schedulers["bus0"].subscribe(on_state)
        stream = AutopilotStream(f"udpout:127.0.0.1:{port}", profile, duration_s=profile.period_s)
        stream.start()
        try:
            assert wait_until(lambda: not stream.running, profile.period_s + 10)
        finally:
            stream.stop()
        assert stream.error is None
        summary = bridge.stop()
        reply_timeout_s = bridge.config.scheduler.reply_timeout_s

    for name, tolerance in (("wide", 0.5), ("pushy", 0.05)):
        with lock:
            rows = list(samples[name])
        positions = [p for _, p, _, _ in rows]
        # every level of the staircase is reached and held, in order: two samples in a row
        # within tolerance (passing through on the way to the next level cannot give that),
        # each searched from where the previous one was held (the servo starts at 0)
        at: int | None = 0
        for level in levels:
            at = first_hold(positions, level, tolerance, start=at or 0)
            assert at is not None, f"{name} never held level {level}: {positions}"
        # the recorded motion is a motion: speed and current while stepping, finite throughout
        assert max(abs(v) for _, _, v, _ in rows) > 100
        assert max(abs(c) for _, _, _, c in rows) > 0
        assert all(math.isfinite(x) for row in rows for x in row)
        stamps = [t for t, _, _, _ in rows]
        assert stamps == sorted(stamps)

    info = summary["buses"]["bus0"]
    assert info["bus_rejected"] == 0  # (missed slots depend on the machine: not asserted)
    assert 0 < info["load"]["peak"] <= info["info"]["max_load"]
    assert info["load"]["peak"] <= info["load"]["planned"] * 1.5
    for name in ("wide", "pushy"):
        row = summary["servos"][name]
        frames = row["frames"]
        assert frames["lost"] == 0 and frames["rejected"] == 0, (name, str(frames))
        assert frames["late"] == 0, (name, frames)
        intervals = row["telemetry_interval_s"]
        nominal = intervals["nominal"]
        dist = intervals["interval"]
        # structure, not speed: the median interval is the poll period, not a multiple of it
        assert 0.5 * nominal < dist["p50"] < 1.5 * nominal, (name, dist, nominal)
        assert dist["min"] <= dist["p50"] <= dist["max"]
        assert_latency_consistent(name, row["latency_s"], frames, reply_timeout_s)
    # the polled servo got polled; the pushing one was never asked
    assert summary["servos"]["wide"]["frames"]["requests"] > 0
    assert summary["servos"]["pushy"]["frames"]["requests"] == 0


def first_hold(positions: list[float], level: float, tolerance: float, start: int) -> int | None:
    """Index of the first of two samples in a row at ``level`` (within ``tolerance``)."""
    for i in range(start, len(positions) - 1):
        if abs(positions[i] - level) <= tolerance and abs(positions[i + 1] - level) <= tolerance:
            return i
    return None


def assert_latency_consistent(
    name: str, latency: dict[str, float], frames: dict[str, int], reply_timeout_s: float
) -> None:
    """The round-trip figures L agree with each other and with the frame counters.

    No threshold on how fast: only relations that hold on any machine. One sample per command
    or refresh reply at most (polls are not L); the order statistics and the mean inside
    [min, max]; the population sigma within half the range, and zero only when every sample is
    the same; no sample longer than the reply timeout, since no reply was late or lost.
    """
    n, low, high = latency["n"], latency["min"], latency["max"]
    assert 0 < n <= frames["commands"] + frames["refreshes"], (name, latency, frames)
    assert 0 < low <= latency["p50"] <= latency["p95"] <= latency["p99"] <= high, (name, latency)
    assert low <= latency["mean"] <= high, (name, latency)
    assert 0 <= latency["sigma"] <= (high - low) / 2 + 1e-12, (name, latency)
    assert (latency["sigma"] > 0) == (high > low), (name, latency)
    assert high <= reply_timeout_s, (name, latency, reply_timeout_s)
