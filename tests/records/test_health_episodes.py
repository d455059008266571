"""Where a health episode is recorded (issue 33): the run log's trace.csv, metrics.json, the
end-of-run summary, the report and the live monitor."""

from __future__ import annotations

import json
from pathlib import Path

from mavservo.app.bridge import Bridge, free_udp_port
from mavservo.app.console import event_level, format_summary
from mavservo.app.monitor import MonitorState
from mavservo.app.report import generate
from mavservo.mavlink.backend import Health
from mavservo.mavlink.connection import mavlink2
from tests.app.test_run_cli import read_trace
from tests.e2e.test_health_faults import BODY, pwm_for
from tests.support.bridge import bridge_config, sim_servo, status
from tests.support.waiting import WAIT_S, wait_until


def test_a_jam_episode_is_in_the_trace_metrics_summary_and_report(tmp_path: Path) -> None:
    config = bridge_config(BODY, free_udp_port())
    bridge = Bridge(config, log_dir=tmp_path).start()
    try:
        assert wait_until(lambda: status(bridge, "pitch").online, WAIT_S)
        assert bridge.backend is not None
        servo = sim_servo(bridge, "pitch")
        servo.faults.jammed_at_deg = -10.0
        # channel 2, as the e2e test drives it (a DO_SET_SERVO's path minus the link)
        assert bridge.backend.apply_servo_output(2, pwm_for(-30.0), "test", 0.0).ok
        assert wait_until(lambda: Health.JAMMED in status(bridge, "pitch").health, WAIT_S)
        servo.faults.jammed_at_deg = None
        assert wait_until(lambda: not status(bridge, "pitch").health, WAIT_S)
    finally:
        summary = bridge.stop()
    assert summary["health"]["episodes"] == {"pitch": {"jammed": 1}}
    text = format_summary(summary)
    assert "health: " in text and "episodes: pitch jammed 1" in text
    assert bridge.run_dir is not None
    rows = read_trace(bridge.run_dir / "trace.csv")
    health_rows = [r for r in rows if r["event"].startswith("health")]
    assert [r["event"] for r in health_rows] == ["health:jammed", "health-cleared:jammed"]
    assert abs(float(health_rows[0]["current_a"])) >= 2.8  # the figures it was judged on
    metrics = json.loads((bridge.run_dir / "metrics.json").read_text())
    assert metrics["health"]["episodes"] == {"pitch": {"jammed": 1}}
    assert any("pitch: jammed at -10.0 deg" in e for e in metrics["events"])
    report = generate(bridge.run_dir)
    markdown = (report["response"].parent / "report.md").read_text()
    assert "## Servo health" in markdown
    assert "- onset: pitch: jammed at -10.0 deg" in markdown
    assert "- cleared: pitch: moving again after" in markdown


def test_onsets_read_as_warnings_and_clearings_as_info_on_the_console() -> None:
    assert event_level("elevator: not following, 14.2 deg behind for 0.8 s at 3.1 A") == "WARNING"
    assert event_level("elevator: jammed at 10.0 deg, 12.0 deg short at 4.0 A") == "WARNING"
    assert event_level("elevator: following again after 2.0 s") == "INFO"
    assert event_level("elevator: moving again after 2.0 s") == "INFO"
    assert event_level("elevator: supply back in range after 1.0 s") == "INFO"


def test_the_monitor_shows_the_health_bits_from_periodic_telemetry() -> None:
    state = MonitorState(["elevator", "pitch"])
    bits = (Health.JAMMED | Health.SUPPLY).value
    state.update(mavlink2.MAVLink_named_value_float_message(0, b"s2_hlt", float(bits)), 1.0)
    state.update(mavlink2.MAVLink_named_value_float_message(0, b"s2_pos", 3.0), 1.0)
    row = state.servo_rows(1.0)[1]
    assert row["faults"] == "jammed|supply" and row["status"] == "FAULT"
    state.update(mavlink2.MAVLink_named_value_float_message(0, b"s2_hlt", 0.0), 2.0)
    assert state.servo_rows(2.0)[1]["faults"] == "-"
    for garbage in (float("nan"), -1.0, float("inf"), 3.0e38):  # a hostile sender's values
        state.update(mavlink2.MAVLink_named_value_float_message(0, b"s2_hlt", garbage), 3.0)
    every = "|".join(sorted(h.name.lower() for h in Health if h.name))
    assert state.servo_rows(3.0)[1]["faults"] in ("-", every)
