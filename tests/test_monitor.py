"""monitor: the pure state model from real pymavlink messages, and the dashboard in a real pty."""

from __future__ import annotations

import io
import os
import pty
import select
import subprocess
import sys
import threading
import time
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")
from conftest import free_udp_port  # noqa: E402
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mavlink2  # noqa: E402

from mavservo.app.monitor import MonitorState, plain_lines, render  # noqa: E402

REPO = Path(__file__).resolve().parent.parent


def _wire(messages, system=1, component=140):
    """Pack with one MAVLink instance and parse with another: real wire round trip."""
    sender = mavlink2.MAVLink(None, srcSystem=system, srcComponent=component)
    receiver = mavlink2.MAVLink(None)
    out = []
    for msg in messages:
        out.extend(receiver.parse_buffer(msg.pack(sender)) or [])
    return out


def _servo_messages():
    m = mavlink2
    return [
        m.MAVLink_heartbeat_message(33, 8, 0, 0, 4, 3),
        m.MAVLink_named_value_float_message(0, b"s1_pos", 12.5),
        m.MAVLink_named_value_float_message(0, b"s1_vel", -3.0),
        m.MAVLink_named_value_float_message(0, b"s1_cur", 0.42),
        m.MAVLink_named_value_float_message(0, b"s1_tmp", 41.0),
        m.MAVLink_named_value_float_message(0, b"s2_pos", -7.25),
        m.MAVLink_named_value_float_message(0, b"bus0_load", 0.123),
        m.MAVLink_named_value_float_message(0, b"lat_p95", 104.5),
        m.MAVLink_named_value_float_message(0, b"rtt_p50", 0.72),
        m.MAVLink_named_value_float_message(0, b"rtt_p99", 1.25),
        m.MAVLink_esc_telemetry_1_to_4_message(
            [41, 39, 0, 0], [1200, 1210, 0, 0], [42, 10, 0, 0], [0] * 4, [0] * 4, [5, 5, 0, 0]
        ),
        m.MAVLink_actuator_output_status_message(0, 0b11, [0.25, -0.5] + [float("nan")] * 30),
        m.MAVLink_statustext_message(2, b"servo right fault stall|over_current", 0, 0),
    ]


def test_state_model_rows_from_real_messages():
    state = MonitorState(names=["left", "right"])
    for msg in _wire(_servo_messages()):
        state.update(msg, now=100.0)
    rows = {row["servo"]: row for row in state.servo_rows(now=100.5)}
    assert set(rows) == {"1", "2"}
    left, right = rows["1"], rows["2"]
    assert (left["name"], left["position"], left["velocity"]) == ("left", "+12.50", "-3.0")
    assert (left["current"], left["temperature"], left["normalized"]) == ("0.42", "41", "+0.250")
    assert left["age"] == "0.50s" and left["status"] == "ok"
    assert (right["position"], right["current"], right["normalized"]) == ("-7.25", "0.10", "-0.500")
    assert right["faults"] == "over_current|stall" and right["status"] == "FAULT"
    (component,) = state.component_rows(now=100.5)
    assert component["component"] == "1/140" and component["type"] == "servo"
    health = state.health_line(now=100.5)
    assert "bus0 12.3%" in health
    # each latency named for what it spans, so ~100 ms and ~1 ms do not read as a contradiction
    assert "cmd->telemetry p95 104.5ms" in health
    assert "round trip L p50 0.72ms p99 1.25ms" in health


def test_state_model_marks_silence_and_recovery():
    state = MonitorState(names=["left"])
    msgs = _wire(
        [
            mavlink2.MAVLink_named_value_float_message(0, b"s1_pos", 1.0),
            mavlink2.MAVLink_statustext_message(2, b"servo left not responding", 0, 0),
        ]
    )
    state.update(msgs[0], now=10.0)
    assert state.servo_rows(now=10.1)[0]["status"] == "ok"
    assert state.servo_rows(now=15.0)[0]["status"] == "STALE"
    state.update(msgs[1], now=15.0)
    assert state.servo_rows(now=15.0)[0]["status"] == "NO REPLY"
    back = _wire(
        [
            mavlink2.MAVLink_statustext_message(5, b"servo left responding again", 0, 0),
            mavlink2.MAVLink_named_value_float_message(0, b"s1_pos", 2.0),
        ]
    )
    for msg in back:
        state.update(msg, now=16.0)
    assert state.servo_rows(now=16.0)[0]["status"] == "ok"
    assert state.component_rows(now=16.0) == []


def test_render_and_plain_lines_show_the_same_values():
    from rich.console import Console

    state = MonitorState(names=["left", "right"])
    for msg in _wire(_servo_messages()):
        state.update(msg, now=1.0)
    console = Console(width=160, record=True, file=io.StringIO())
    console.print(render(state, now=1.2))
    screen = console.export_text()
    text = "\n".join(plain_lines(state, now=1.2))
    for value in ("+12.50", "-7.25", "over_current|stall", "1/140"):
        assert value in screen and value in text


def _send_until(port: int, stop: threading.Event, limit_s: float = 15.0) -> None:
    conn = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{port}", source_system=1, source_component=140, dialect="ardupilotmega"
    )
    deadline = time.monotonic() + limit_s
    try:
        while not stop.is_set() and time.monotonic() < deadline:
            for msg in _servo_messages():
                conn.mav.send(msg)
            stop.wait(0.05)
    finally:
        conn.close()


def _run_monitor(port: int, stdout, extra=()) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(REPO), COLUMNS="160", LINES="40", TERM="xterm-256color")
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "mavservo.app.monitor",
            f"udpin:127.0.0.1:{port}",
            "--duration",
            "3",
            *extra,
        ],
        stdout=stdout,
        stderr=subprocess.PIPE,
        env=env,
        cwd=REPO,
    )


def test_dashboard_renders_in_a_pseudo_terminal():
    port = free_udp_port()
    master, slave = pty.openpty()
    stop = threading.Event()
    sender = threading.Thread(target=_send_until, args=(port, stop), daemon=True)
    proc = _run_monitor(port, slave)
    os.close(slave)
    sender.start()
    chunks = []
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            ready, _, _ = select.select([master], [], [], 0.2)
            if ready:
                try:
                    data = os.read(master, 65536)
                except OSError:  # EIO: the child closed its side
                    break
                if not data:
                    break
                chunks.append(data)
            elif proc.poll() is not None:
                break
        rc = proc.wait(timeout=10)
    finally:
        stop.set()
        sender.join(timeout=5)
        if proc.poll() is None:
            proc.kill()
        os.close(master)
    screen = b"".join(chunks).decode(errors="replace")
    assert rc == 0, proc.stderr.read().decode()
    assert "\x1b[" in screen  # a terminal got a terminal dashboard, not plain lines
    assert "mavservo monitor" in screen
    assert "+12.50" in screen and "-7.25" in screen and "servo" in screen


def test_plain_lines_when_not_a_terminal():
    port = free_udp_port()
    stop = threading.Event()
    sender = threading.Thread(target=_send_until, args=(port, stop), daemon=True)
    proc = _run_monitor(port, subprocess.PIPE)
    sender.start()
    try:
        out, err = proc.communicate(timeout=30)
    finally:
        stop.set()
        sender.join(timeout=5)
    text = out.decode()
    assert proc.returncode == 0, err.decode()
    assert "\x1b[" not in text
    assert "servo servo=1" in text and "position=+12.50" in text


def test_gimbal_failure_flags_are_named():
    state = MonitorState()
    q = [1.0, 0.0, 0.0, 0.0]
    nan3 = [float("nan")] * 3
    for flags, shown in (
        (0x20, "0x20 motor_error"),
        (0x0, "0x0 ok"),
        (0x2 | 0x400, "0x402 at_pitch_limit|0x400?"),
    ):
        status = mavlink2.MAVLink_gimbal_device_attitude_status_message(
            0, 0, 0, 0, q, nan3[0], nan3[1], nan3[2], flags
        )
        for msg in _wire([status], component=154):
            state.update(msg, 1.0)
        assert f"failure_flags {shown}" in state.health_line(1.0)
