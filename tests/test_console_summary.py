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
