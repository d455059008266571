"""The end-of-run summary names what went wrong on each bus, failed sends included."""

from __future__ import annotations

from mavservo.app.console import format_summary


def test_summary_counts_failed_sends_per_bus() -> None:
    summary = {
        "uptime_s": 12.0,
        "buses": {
            "bus0": {
                "load": {"current": 0.1, "mean": 0.05, "peak": 0.2, "planned": 0.3},
                "missed_command_slots": 0,
                "send_failures": {"total": 60, "outages": 1, "failing_for_s": 0.0},
                "transport": {"reconnects": 1, "bytes_discarded": 0, "rejected": {}},
            },
            "bus1": {"transport": {}},
        },
        "servos": {},
    }
    lines = format_summary(summary).splitlines()
    bus0 = next(line for line in lines if line.startswith("  bus bus0:"))
    bus1 = next(line for line in lines if line.startswith("  bus bus1:"))
    assert bus0.endswith("reconnects 1, failed sends 60")
    assert bus1.endswith("reconnects 0, failed sends 0")


def test_summary_names_frames_the_driver_could_not_parse() -> None:
    """Frames a driver's recv raised on are dropped and counted by the bus wrapper
    (``garbled``): the stop summary says how many, and nothing when there were none."""
    summary = {
        "buses": {
            "bus0": {"transport": {"reconnects": 0, "garbled": 3}},
            "bus1": {"transport": {"garbled": 0}},
        },
        "servos": {},
    }
    lines = format_summary(summary).splitlines()
    bus0 = next(line for line in lines if line.startswith("  bus bus0:"))
    bus1 = next(line for line in lines if line.startswith("  bus bus1:"))
    assert bus0.endswith("failed sends 0, frames the driver could not parse 3")
    assert bus1.endswith("failed sends 0")


def _stream_summary(uptime_s: float, received_hz: float | None, received: int) -> str:
    figures = {
        "requested_hz": 20.0,
        "answer": "accepted",
        "received_hz": received_hz,
        "received": received,
    }
    summary = {
        "uptime_s": uptime_s,
        "servos": {},
        "mavlink": {"stream": {"streams": {"SERVO_OUTPUT_RAW": figures}}},
    }
    lines = format_summary(summary).splitlines()
    return next(line for line in lines if "autopilot stream SERVO_OUTPUT_RAW" in line)


def test_a_run_shorter_than_the_rate_window_shows_the_whole_runs_figure() -> None:
    """A 3 s run has no whole 5 s window: it said "received - (last 5 s window)" (issue 37)."""
    line = _stream_summary(3.0, None, 57)
    assert "received 57 messages in the whole 3.0 s run (about 19.0 Hz;" in line
    assert " - " not in line and "last 5 s window" not in line


def test_a_longer_run_without_a_measured_rate_says_why() -> None:
    line = _stream_summary(30.0, None, 0)
    assert "received 0 messages, rate not measured (no whole 5 s window" in line
    assert " - " not in line


def test_a_measured_rate_is_shown_with_its_window() -> None:
    line = _stream_summary(30.0, 19.96, 598)
    assert line.endswith("received 20.0 Hz (last 5 s window), 598 messages")
