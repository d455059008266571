"""Issue 17, item 10: the console of ``mavservo run`` speaks one format, says whether the
autopilot's heartbeat has been heard, and a normal end reads as a normal end."""

from __future__ import annotations

import io
import logging
import math
import re
import subprocess
import sys
from pathlib import Path

from mavservo.app.console import ConsoleFormatter, HeartbeatNotices, StatusDisplay, event_level
from tests.support.paths import REPO

#: the one format: ``[HH:MM:SS] LEVEL   source: text``
LINE = re.compile(r"^\[\d\d:\d\d:\d\d\] (INFO|WARNING|ERROR|DEBUG|CRITICAL) +[\w.]+: \S")


def test_log_records_and_bridge_events_share_one_format() -> None:
    stream = io.StringIO()
    StatusDisplay(enabled=False, stream=stream).event("servo aileron offline")
    StatusDisplay(enabled=False, stream=stream).event("servo aileron back online")
    record = logging.LogRecord(
        "mavservo.scheduling.runner", logging.WARNING, __file__, 1, "bus %s lost", ("b0",), None
    )
    lines = [*stream.getvalue().splitlines(), ConsoleFormatter().format(record)]
    assert all(LINE.match(line) for line in lines), lines
    assert " WARNING bridge: servo aileron offline" in lines[0]
    assert " INFO    bridge: servo aileron back online" in lines[1]
    assert lines[2].endswith(" WARNING scheduling.runner: bus b0 lost")


def test_event_levels_name_recoveries_info_and_problems_warning() -> None:
    assert event_level("failsafe: autopilot heartbeat lost") == "WARNING"
    assert event_level("failsafe cleared: servos move again on fresh commands") == "INFO"
    assert event_level("MAVLink link recovered") == "INFO"
    assert event_level("MAVLink link lost") == "WARNING"
    assert event_level("stopped (SIGTERM): servos told their failsafe action: hold 1") == "INFO"


def test_heartbeat_heard_once_and_silence_warned_rate_limited() -> None:
    notices = HeartbeatNotices(started=100.0, warn_after_s=2.0, repeat_s=30.0)
    autopilot = (1, 1)
    assert notices.check(autopilot, None, 101.0) is None  # not yet overdue
    level, text = notices.check(autopilot, None, 102.5) or ("", "")
    assert level == "WARNING" and "autopilot 1/1: no heartbeat in 2 s" in text
    assert notices.check(autopilot, None, 110.0) is None  # rate-limited
    level, text = notices.check(autopilot, None, 132.5) or ("", "")
    assert level == "WARNING" and "no heartbeat in 32 s" in text
    level, text = notices.check(autopilot, 140.0, 140.1) or ("", "")
    assert level == "INFO" and text == "autopilot 1/1: heartbeat heard, 40.0 s after start"
    assert notices.check(autopilot, 141.0, 141.0) is None  # said once
    assert notices.check(autopilot, 141.0, 500.0) is None  # loss is the watchdog's event


def run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "mavservo", "run", *args, "--no-log", "--quiet"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=REPO,
    )


def test_run_on_the_simulation_hears_the_autopilot_and_ends_normally() -> None:
    proc = run("--duration", "1.5")
    assert proc.returncode == 0, proc.stderr
    events = [line for line in proc.stdout.splitlines() if line.startswith("[")]
    assert events and all(LINE.match(line) for line in events), events
    assert any("INFO    bridge: autopilot 1/1: heartbeat heard" in line for line in events)
    [stopped] = [line for line in events if "stopped (" in line]
    assert "INFO    bridge: stopped (end of --duration 1.5 s): servos told their failsafe" in (
        stopped
    )
    assert "failsafe: shutdown" not in proc.stdout
    assert all(LINE.match(line) for line in proc.stderr.splitlines() if line.strip()), proc.stderr


def test_run_without_an_autopilot_warns_once_per_interval(tmp_path: Path) -> None:
    config = tmp_path / "alone.yaml"
    config.write_text(
        "mavlink: {url: 'udpin:127.0.0.1:0', heartbeat_timeout_s: 0.3}\n"
        "servos: [{name: a, profile: rmd-x, can_id: 1}]\n"
        "channels: [{servo: a, source: servo_output, channel: 1}]\n"
    )
    proc = run(str(config), "--duration", "2")
    assert proc.returncode == 0, proc.stderr
    warnings = [line for line in proc.stdout.splitlines() if "no heartbeat" in line]
    assert len(warnings) == 1, proc.stdout  # one, not one per loop turn
    assert (
        LINE.match(warnings[0])
        and " WARNING bridge: autopilot 1/1: no heartbeat in" in (warnings[0])
    )
    assert "heartbeat heard" not in proc.stdout


def test_a_field_the_family_never_reports_reads_as_a_dash_not_nan() -> None:
    """DroneCAN's actuator.Status carries no current or temperature: the profile leaves them
    UNKNOWN (NaN), and the console shows them as not known, like before the first report."""
    from mavservo.app.console import status_line

    row = {
        "servo": "aileron_l",
        "setpoint_deg": 10.0,
        "position_deg": 9.5,
        "velocity_dps": 1.0,
        "current_a": math.nan,
        "temperature_c": math.nan,
        "faults": "",
        "online": True,
        "age_s": 0.05,
    }
    line = status_line(row)
    assert "nan" not in line
    assert "I     - A" in line and "T     - C" in line
    assert "pos     9.5 deg" in line


def test_status_columns_line_up_before_the_first_report() -> None:
    """Before its first report a servo's values are "-": the line printed "set - deg  pos - deg"
    and its columns slid left of the reporting servos' (issue 37)."""
    from mavservo.app.console import status_line

    reporting = {
        "servo": "aileron_l",
        "setpoint_deg": -12.5,
        "position_deg": 100.25,
        "velocity_dps": -3.0,
        "current_a": 1.25,
        "temperature_c": 41.0,
        "faults": "",
        "online": True,
        "age_s": 0.05,
    }
    waiting = {
        **reporting,
        "servo": "rudder",
        **dict.fromkeys(
            ("setpoint_deg", "position_deg", "velocity_dps", "current_a", "temperature_c")
        ),
        "age_s": None,
    }
    lines = [status_line(reporting), status_line(waiting)]
    for unit in (" deg  pos", " deg  vel", " dps  I", " A  T", " C  age", " ms"):
        assert lines[0].index(unit) == lines[1].index(unit), (unit, lines)
    assert len(lines[0]) == len(lines[1])
