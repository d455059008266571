"""LatencyTracer: each stage is measured between the right two events, and memory stays bounded."""

from __future__ import annotations

import pytest

from mavservo.records.latency import STAGES, LatencyTracer

STATE = object()


def _command(
    tracer: LatencyTracer, servo: str, seq: int, t: float, gaps=(0.001, 0.002, 0.003, 0.004)
) -> None:
    received = t
    tracer.mavlink_received(servo, received)
    accepted = received + gaps[0]
    tracer.on_setpoint(servo, seq, 1.0, "test", accepted)
    written = accepted + gaps[1]
    tracer.on_tx("bus0", None, written, "command", servo, seq)
    decoded = written + gaps[2]
    tracer.on_rx("bus0", None, decoded, servo, STATE)
    tracer.telemetry_sent(servo, decoded + gaps[3])


def test_complete_command_has_every_stage():
    records = []
    tracer = LatencyTracer(on_record=records.append)
    _command(tracer, "s1", 1, 100.0, gaps=(0.001, 0.002, 0.004, 0.008))
    (record,) = records
    assert record.outcome == "complete"
    stages = record.stage_seconds()
    assert [stages[s] for s in STAGES] == pytest.approx([0.001, 0.002, 0.004, 0.008])


def test_refresh_and_early_reply_do_not_count():
    records = []
    tracer = LatencyTracer(on_record=records.append)
    tracer.on_setpoint("s1", 5, 1.0, "test", 10.0)
    tracer.on_rx("bus0", None, 10.001, "s1", STATE)  # reply to an older frame: before the write
    tracer.on_tx("bus0", None, 10.002, "refresh", "s1", 5)
    tracer.on_tx("bus0", None, 10.003, "command", "s1", 4)  # another seq
    tracer.on_tx("bus0", None, 10.004, "command", "s1", 5)
    tracer.on_tx("bus0", None, 10.005, "command", "s1", 5)  # a second write keeps the first
    tracer.on_rx("bus0", None, 10.010, "s1", STATE)
    tracer.telemetry_sent("s1", 10.020)
    (record,) = records
    assert record.written == 10.004
    assert record.decoded == 10.010
    assert record.received is None and record.stage_seconds()["accept"] is None


def test_superseded_and_timed_out_commands_are_reported_partial():
    records = []
    tracer = LatencyTracer(on_record=records.append)
    tracer.on_setpoint("s1", 1, 1.0, "test", 1.0)
    tracer.on_setpoint("s1", 2, 2.0, "test", 1.01)
    tracer.on_tx("bus0", None, 1.02, "command", "s1", 2)
    tracer.on_lost("bus0", "s1", 1.07)
    assert [(r.seq, r.outcome) for r in records] == [(1, "superseded"), (2, "timed_out")]
    assert tracer.counts["superseded"] == 1 and tracer.counts["timed_out"] == 1
    tracer.on_setpoint("s1", 3, 3.0, "test", 2.0)
    tracer.close_open()
    assert records[-1].outcome == "open"


def test_servos_are_traced_independently():
    tracer = LatencyTracer()
    tracer.on_setpoint("a", 1, 0.0, "t", 0.0)
    tracer.on_setpoint("b", 1, 0.0, "t", 0.0)
    tracer.on_tx("bus0", None, 0.001, "command", "a", 1)
    tracer.on_tx("bus0", None, 0.005, "command", "b", 1)
    tracer.on_rx("bus0", None, 0.006, "b", STATE)
    tracer.on_rx("bus0", None, 0.009, "a", STATE)
    tracer.telemetry_sent("a", 0.01)
    tracer.telemetry_sent("b", 0.01)
    summary = tracer.summary()
    assert sorted([0.008, 0.001]) == pytest.approx(
        [summary["stages"]["round_trip"]["min"], summary["stages"]["round_trip"]["max"]]
    )


def test_memory_is_bounded_by_the_window():
    tracer = LatencyTracer(window=16)
    for i in range(200):
        _command(tracer, f"s{i % 3}", i, float(i))
    summary = tracer.summary()
    assert summary["counts"]["complete"] == 200
    assert all(summary["stages"][s]["n"] == 200 for s in STAGES)
    assert all(len(stats.recent) == 16 for stats in tracer._stages.values())
    assert len(tracer._open) == 0
