"""metrics: eq. (5) sigma, percentiles, bounded windows, sliding-window bus load."""

from __future__ import annotations

import json
import statistics

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from mavservo.records.metrics import (
    LoadMeter,
    PeriodStats,
    SampleStats,
    SchedulerMetrics,
    percentile,
    write_json,
)

finite = st.floats(-1e3, 1e3, allow_nan=False)


@given(st.lists(finite, min_size=1, max_size=200))
def test_mean_and_population_sigma_match_eq_5(values):
    stats = SampleStats()
    stats.extend(values)
    assert stats.mean == pytest.approx(statistics.fmean(values), abs=1e-6)
    assert stats.sigma == pytest.approx(statistics.pstdev(values), abs=1e-6)
    assert (stats.minimum, stats.maximum) == (min(values), max(values))


@given(st.lists(finite, min_size=1, max_size=200), st.floats(0, 100))
def test_percentile_matches_linear_interpolation(values, q):
    ordered = sorted(values)
    assert percentile(ordered, q) == pytest.approx(np.percentile(ordered, q), abs=1e-6)


def test_percentile_of_nothing_is_an_error():
    with pytest.raises(ValueError):
        percentile([], 50)


def test_window_bounds_memory_but_mean_covers_everything():
    stats = SampleStats(window=10)
    stats.extend(range(100))
    assert len(stats.recent) == 10 and stats.count == 100
    summary = stats.summary()
    assert summary["mean"] == pytest.approx(49.5)
    assert summary["p50"] == pytest.approx(94.5)  # percentiles describe the recent window


def test_empty_summary_is_all_none():
    summary = SampleStats().summary()
    assert summary["n"] == 0 and summary["sigma"] is None and summary["p99"] is None


def test_period_stats_measure_intervals_and_deviation_from_nominal():
    period = PeriodStats(nominal_s=0.05)
    for t in (0.0, 0.050, 0.101, 0.149, 0.200):
        period.mark(t)
    summary = period.summary()
    assert summary["interval"]["n"] == 4
    assert summary["interval"]["mean"] == pytest.approx(0.05)
    assert summary["abs_deviation"]["max"] == pytest.approx(0.002)


def test_load_meter_slides_its_window():
    meter = LoadMeter(bitrate=1000, window_s=1.0)
    meter.add(0.0, 100)
    meter.add(0.5, 200)
    assert meter.ratio(0.5) == pytest.approx(0.3)
    assert meter.ratio(1.2) == pytest.approx(0.2)  # the frame at t=0 left the window
    assert meter.ratio(2.0) == 0.0
    assert meter.total_bits == 300 and meter.peak == pytest.approx(0.3)


@given(st.lists(st.tuples(st.floats(0, 0.01), st.integers(1, 200)), max_size=300))
def test_load_meter_agrees_with_a_brute_force_window(events):
    meter = LoadMeter(bitrate=10_000, window_s=0.05, max_events=10_000)
    t, history = 0.0, []
    for dt, bits in events:
        t += dt
        meter.add(t, bits)
        history.append((t, bits))
    expected = sum(b for ts, b in history if ts > t - 0.05) / (0.05 * 10_000)
    assert meter.ratio(t) == pytest.approx(expected)


def test_scheduler_metrics_snapshot_is_json(tmp_path):
    metrics = SchedulerMetrics(["a", "b"], 0.05, 0.09, 1_000_000)
    metrics.servos["a"].latency.extend([0.001, 0.003])
    metrics.servos["a"].commands_sent = 2
    metrics.load.add(1.0, 135)
    snapshot = metrics.to_dict(now=1.0)
    assert snapshot["servos"]["a"]["latency_s"]["sigma"] == pytest.approx(0.001)
    assert snapshot["servos"]["a"]["frames"]["sent"] == 2
    assert snapshot["load"]["current"] == pytest.approx(135e-6)
    path = write_json(tmp_path / "deep" / "metrics.json", snapshot)
    assert json.loads(path.read_text()) == json.loads(json.dumps(snapshot))


def test_refused_sends_are_a_servo_counter_next_to_lost_and_rejected():
    metrics = SchedulerMetrics(["a"], 0.05, 0.09, 1_000_000)
    servo = metrics.servos["a"]
    servo.commands_sent, servo.send_failed, servo.timed_out = 3, 2, 1
    frames = metrics.to_dict(now=0.0)["servos"]["a"]["frames"]
    assert (frames["send_failed"], frames["lost"], frames["sent"]) == (2, 1, 3)


def test_a_late_reply_is_late_not_lost():
    """The summary once said ``lost 1`` for a reply that came late (``late_replies: 1``):
    lost is what timed out and never came."""
    metrics = SchedulerMetrics(["a"], 0.05, 0.09, 1_000_000)
    servo = metrics.servos["a"]
    servo.timed_out, servo.late_replies = 3, 1
    frames = metrics.to_dict(now=0.0)["servos"]["a"]["frames"]
    assert (frames["timed_out"], frames["late"], frames["lost"]) == (3, 1, 2)
    servo.late_replies = 4  # a duplicate late reply: late, and nothing is lost below zero
    assert metrics.to_dict(now=0.0)["servos"]["a"]["frames"]["lost"] == 0


def test_load_mean_is_every_bit_over_the_time_since_the_first_frame():
    meter = LoadMeter(bitrate=1000, window_s=1.0)
    for t in (10.0, 10.5, 11.0, 13.0):
        meter.add(t, 100)
    assert meter.mean(14.0) == pytest.approx(400 / (4.0 * 1000))
    assert meter.peak == pytest.approx(0.2)  # (10.0, 11.0]: two frames
    assert LoadMeter(bitrate=1000).mean(5.0) == 0.0
