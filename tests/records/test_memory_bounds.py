"""Memory bounds of the long-running stores: metrics windows, the latency tracer, the simulated
autopilot's record logs, and the soak's time-to-flat figure.

Why these exist: a soak showed memory rising for a quarter of an hour before levelling off,
because every store was bounded only by a count it took minutes to reach. Each test feeds a
store far past its bound (100,000 samples or records), then checks that it holds at most its
bound and that what the reports read from it still matches a reference computed over the
same window. "Allocated up front" is measured with tracemalloc (bytes, not time): a primed
store fed far past its bound may leave some kB of interpreter free-list noise allocated, the
stores they replace grew by 130 kB per 4096-sample window.
"""

from __future__ import annotations

import importlib.util
import math
import os
import statistics
import sys
import threading
import tracemalloc
from collections.abc import Callable
from types import ModuleType
from typing import Any

import pytest

from mavservo.records.latency import STAGES, LatencyTracer
from mavservo.records.metrics import FloatRing, SampleStats, SchedulerMetrics, percentile
from mavservo.sim.autopilot.command_tracker import CommandTracker
from mavservo.sim.autopilot.recorder import Received
from mavservo.sim.autopilot.sitl_command import STREAM_KEEP, build_parser
from mavservo.sim.autopilot.stream import AutopilotStream, Commanded
from tests.support.paths import REPO

N = 100_000


def allocated_by(action: Callable[[], Any]) -> int:
    """Bytes still allocated (traced) after ``action`` ran, against before it."""
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        action()
        return tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()


def sample(i: int) -> float:
    """A deterministic, non-monotonic sample sequence (so order mistakes show)."""
    return math.sin(i * 0.7) * 10.0 + (i % 13) * 0.1


# ---------------------------------------------------------------- metrics: FloatRing, SampleStats


def test_ring_keeps_the_last_values_in_order_after_100k_appends():
    ring = FloatRing(1000)
    values = [sample(i) for i in range(N)]
    for v in values:
        ring.append(v)
    assert len(ring) == 1000
    assert list(ring) == values[-1000:]
    assert list(reversed(ring)) == values[-1000:][::-1]
    assert sorted(ring.values()) == sorted(values[-1000:])


def test_ring_before_it_is_full_holds_exactly_what_was_added():
    ring = FloatRing(8)
    assert not ring and list(ring) == [] and ring.values() == []
    for v in (3.0, 1.0, 2.0):
        ring.append(v)
    assert list(ring) == [3.0, 1.0, 2.0] and list(reversed(ring)) == [2.0, 1.0, 3.0]
    assert sorted(ring.values()) == [1.0, 2.0, 3.0]


def test_sample_stats_after_100k_samples_hold_the_window_and_exact_summaries():
    window = 4096
    stats = SampleStats(window)
    values = [sample(i) for i in range(N)]
    stats.extend(values)
    assert len(stats.recent) == window
    summary = stats.summary()
    # mean, sigma, min, max: over every sample (exact, paper eq. 5)
    assert summary["n"] == N
    assert summary["mean"] == pytest.approx(statistics.fmean(values), abs=1e-9)
    assert summary["sigma"] == pytest.approx(statistics.pstdev(values), rel=1e-9)
    assert (summary["min"], summary["max"]) == (min(values), max(values))
    # percentiles: over the last ``window`` samples (documented windowed)
    last = sorted(values[-window:])
    for q in (50, 95, 99):
        assert summary[f"p{q}"] == percentile(last, q)


def test_sample_stats_allocate_their_window_when_built_and_nothing_after():
    """Memory is flat from the first sample: 100,000 samples allocate (almost) nothing more.

    The deque of float objects it replaces grew by ~32 bytes a sample until full (~130 kB for
    a 4096 window, 7 minutes at 10 Hz)."""
    stats = SampleStats(4096)
    stats.add(0.0)

    def feed() -> None:
        for i in range(N):
            stats.add(sample(i))

    assert allocated_by(feed) < 16 * 1024


def test_scheduler_metrics_are_flat_from_construction():
    """Every window of a 16-servo scheduler (85 of them) filled far past its bound: no growth."""
    metrics = SchedulerMetrics(
        [f"s{i}" for i in range(1, 17)],
        command_period_s=0.02,
        telemetry_period_s=0.1,
        bitrate=1_000_000,
    )

    def feed(rounds: int) -> None:
        for i in range(rounds):
            t = i * 0.02
            metrics.command_ticks.mark(t)
            metrics.command_lateness.add(sample(i) * 1e-4)
            metrics.telemetry_ticks.mark(t * 5)
            for servo in metrics.servos.values():
                servo.latency.add(0.002 + sample(i) * 1e-5)
                servo.command_intervals.mark(t)
                servo.telemetry_intervals.mark(t * 5)

    feed(10)  # every store primed: its counters and running figures exist
    assert allocated_by(lambda: feed(6000)) < 64 * 1024  # > 4096 marks per store; was 11 MB
    servo = metrics.servos["s1"]
    assert len(servo.latency.recent) == 4096 and servo.latency.count == 6010
    assert len(servo.command_intervals.intervals.recent) == 4096


# ---------------------------------------------------------------- latency: LatencyTracer


def run_commands(tracer: LatencyTracer, count: int) -> list[dict[str, float]]:
    """``count`` complete commands of servo s1; returns each one's stage durations."""
    out = []
    for seq in range(count):
        t = seq * 0.02
        d = {
            "accept": 1e-4,
            "tx": 2e-4 + sample(seq) * 1e-6,
            "round_trip": 2e-3 + sample(seq + 1) * 1e-5,
            "publish": 5e-4,
        }
        tracer.mavlink_received("s1", t)
        tracer.on_setpoint("s1", seq, 0.0, "mavlink", t + d["accept"])
        written = t + d["accept"] + d["tx"]
        tracer.on_tx("bus0", None, written, "command", "s1", seq)
        tracer.on_rx("bus0", None, written + d["round_trip"], "s1", object())
        tracer.telemetry_sent("s1", written + d["round_trip"] + d["publish"])
        out.append(d)
    return out


def test_latency_tracer_after_100k_commands_is_bounded_and_summaries_match():
    window = 1000
    tracer = LatencyTracer(window=window)
    stages = run_commands(tracer, N)
    summary = tracer.summary()
    assert summary["counts"]["complete"] == N
    for stage in STAGES:
        values = [d[stage] for d in stages]
        got = summary["stages"][stage]
        assert len(tracer._stages[stage].recent) == window
        assert got["n"] == N
        assert got["mean"] == pytest.approx(statistics.fmean(values), rel=1e-9)
        assert got["p50"] == pytest.approx(percentile(sorted(values[-window:]), 50), abs=1e-12)
        assert got["p99"] == pytest.approx(percentile(sorted(values[-window:]), 99), abs=1e-12)


def test_latency_tracer_stores_do_not_grow_while_commands_flow():
    tracer = LatencyTracer(window=4096)
    run_commands(tracer, 10)
    # 5 stores of 4096: the deques they replace grew by 650 kB
    assert allocated_by(lambda: run_commands(tracer, 20_000)) < 64 * 1024


# ---------------------------------------------------------------- sitl: the simulated autopilot


def test_autopilot_commanded_log_is_bounded_by_keep_and_lookups_stay_exact():
    stream = AutopilotStream("udpout:127.0.0.1:9", keep=100)  # never started: no socket
    for i in range(N):
        stream.commanded.record(
            "servo", Commanded(float(i), 1, 1000 + i % 1000, "servo_output_raw")
        )
    log = stream.commanded_log("servo")
    assert 50 <= len(log) <= 100
    assert log[-1].t == N - 1
    # every kept change answers its own time and the time just after it
    for entry in log:
        assert stream.commanded_pwm(1, entry.t) == entry.value
        assert stream.commanded_pwm(1, entry.t + 0.5) == entry.value


def test_autopilot_sent_and_received_logs_are_bounded_by_keep():
    stream = AutopilotStream("udpout:127.0.0.1:9", keep=100)
    for i in range(N):
        stream.link.send("HEARTBEAT", float(i), lambda: None)
    assert len(stream.sent_log) == 100 and stream.sent["HEARTBEAT"] == N
    assert stream.sent_log[-1] == (N - 1.0, "HEARTBEAT")
    assert stream.received._log.maxlen == 100
    assert stream.commands.keep == 100 and stream.commands.acks.maxlen == 100


def test_autopilot_keep_below_two_is_refused():
    with pytest.raises(ValueError):
        AutopilotStream("udpout:127.0.0.1:9", keep=1)


class FakeMessage:
    def __init__(self, i: int) -> None:
        self.i = i

    def get_type(self) -> str:
        return "SERVO_OUTPUT_RAW" if self.i % 2 else "HEARTBEAT"


def test_received_log_after_100k_messages_holds_keep_and_counts_all():
    received = Received(keep=100)
    for i in range(N):
        received.add(float(i), FakeMessage(i))
    assert len(received.messages()) == 100
    assert received.counts() == {"SERVO_OUTPUT_RAW": N // 2, "HEARTBEAT": N // 2}
    assert received.last("HEARTBEAT").i == N - 2


def test_command_tracker_forgets_settled_commands_beyond_keep_but_never_a_pending_one():
    # no retry within the test, so an unanswered command stays pending (never given up on)
    tracker = CommandTracker(retry_interval_s=1e9, keep=100)
    for i in range(N):
        pending = i % 1000 == 7  # every thousandth command is never answered
        tracker.submit(181 if pending else 183, (1, 1500, 0, 0, 0, 0, 0), 1, 0, float(i))
        tracker.due(float(i))
        if not pending:
            tracker.on_ack(183, 0, (1, 1), (255, 0), float(i))
    assert len(tracker.acks) == 100
    settled = [r for r in tracker.commands if r.done]
    pending = [r for r in tracker.commands if not r.done]
    assert len(settled) <= 100
    assert len(pending) == N // 1000  # not one pending command forgotten
    assert [r.created for r in pending] == [float(i) for i in range(7, N, 1000)]
    assert tracker.commands[-1].created == N - 1  # the newest settled ones are kept


def test_sitl_stream_cli_keeps_few_records_by_default_and_takes_keep():
    parser = build_parser()
    assert parser.parse_args(["stream"]).keep == STREAM_KEEP <= 2000
    assert parser.parse_args(["stream", "--keep", "50"]).keep == 50
    with pytest.raises(SystemExit):
        parser.parse_args(["stream", "--keep", "1"])


# ---------------------------------------------------------------- soak: fds, threads, time to flat

SOAK = REPO / "bench" / "soak.py"


def soak_module() -> ModuleType:
    """bench/soak.py imported as a module (bench/ is not a package)."""
    sys.path.insert(0, str(SOAK.parent))
    try:
        spec = importlib.util.spec_from_file_location("soak_under_test", SOAK)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module
    finally:
        sys.path.remove(str(SOAK.parent))


def test_soak_process_figures_count_open_fds_and_threads():
    soak = soak_module()
    before = soak.process_figures()
    release = threading.Event()
    worker = threading.Thread(target=release.wait, daemon=True)
    with open(os.devnull) as _:
        worker.start()
        during = soak.process_figures()
    release.set()
    worker.join(5)
    assert during["fds"] == before["fds"] + 1
    assert during["threads"] == before["threads"] + 1
    assert during["rss_kib"] > 0


def test_soak_flat_from_is_the_first_time_after_which_memory_stays_within_one_percent():
    soak = soak_module()
    growing_then_flat = [(0, 100), (60, 150), (120, 180), (180, 181), (240, 180), (300, 181)]
    assert soak.flat_from(growing_then_flat) == 120
    still_growing = [(t, 100 + 5 * t) for t in range(10)]
    assert soak.flat_from(still_growing) == 9
    assert soak.flat_from([]) is None


def test_soak_diagnosis_rings_hold_the_last_records_and_allocate_nothing_after_built():
    soak = soak_module()
    sent = soak.Ring(3000, "ds")
    records = [(i * 0.001, ("command", "refresh", "request")[i % 3]) for i in range(N)]
    sent.extend(records[:10])
    assert list(sent) == records[:10]
    assert allocated_by(lambda: sent.extend(records[10:])) < 16 * 1024  # deque: ~300 kB
    assert len(sent) == 3000 and list(sent) == records[-3000:]
    decoded = soak.Ring(5, "d")
    decoded.extend(float(i) for i in range(N))
    assert list(decoded) == [float(i) for i in range(N - 5, N)]
    assert soak.Ring(4, "ddb").__len__() == 0 and list(soak.Ring(4, "dd")) == []


def test_soak_keeps_the_first_followed_losses_and_counts_every_verdict():
    soak = soak_module()
    diagnostics = soak.Diagnostics()
    for window in range(40):  # 40 windows of 50 followed losses, each with its trace excerpt
        diagnostics.keep_followed(
            [{"verdict": ("late", "no reply")[i % 2], "sim": [window] * 50} for i in range(50)]
        )
    assert len(diagnostics.followed) == soak.FOLLOWED_KEPT
    assert diagnostics.verdicts == {"late": 1000, "no reply": 1000}


def test_soak_followed_losses_fill_their_bound_within_a_few_windows_and_stay_small():
    """The followed losses hold trace excerpts (~50 simulator events and decode times each):
    kept 300 in full they filled for a whole noisy run, ~3 MB loss by loss."""
    soak = soak_module()
    diagnostics = soak.Diagnostics()

    def loss(window: int, i: int) -> dict[str, Any]:
        return {
            "t": window + i * 0.001,
            "verdict": "late",
            "sim": [(0.001 * e, "in", hex(0x141)) for e in range(50)],
            "host_rx": [0.001 * e for e in range(10)],
        }

    def windows(first: int, count: int) -> None:
        for window in range(first, first + count):
            diagnostics.keep_followed([loss(window, i) for i in range(5)])

    windows(0, 4)  # 20 losses followed: the bound is reached
    assert allocated_by(lambda: windows(4, 100)) < 64 * 1024
    assert diagnostics.verdicts == {"late": 520}
    assert len(diagnostics.followed) == soak.FOLLOWED_KEPT
