"""The end-of-run summary shows the scheduler's stall figures beside the missed command slots.

Why: ``missed_command_slots`` stays 0 when the command loop serves every slot, only late (a
stalled loop serves the slot it woke for); ``late_command_slots`` and ``longest_command_gap_s``
(records/metrics.py) are what show the bus went silent, so the console must print them.
"""

from __future__ import annotations

from mavservo.app.console import format_summary


def bus_line(bus: dict) -> str:
    summary = {"uptime_s": 1.0, "buses": {"bus0": bus}, "servos": {}}
    return next(line for line in format_summary(summary).splitlines() if "bus bus0:" in line)


def test_summary_shows_late_slots_and_longest_gap_next_to_missed_slots() -> None:
    line = bus_line(
        {
            "missed_command_slots": 2,
            "late_command_slots": 7,
            "longest_command_gap_s": 0.1756,
            "transport": {},
        }
    )
    assert "missed command slots 2 (late 7, longest gap 175.60 ms)," in line


def test_summary_without_stall_figures_says_so_plainly() -> None:
    line = bus_line({"transport": {}})
    assert "missed command slots 0 (late 0, longest gap -)," in line
