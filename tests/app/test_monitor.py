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

from tests.support.paths import REPO

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mavlink2  # noqa: E402

from mavservo.app.monitor import MonitorState, plain_lines, render  # noqa: E402
from tests.support.waiting import free_udp_port  # noqa: E402


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
        m.MAVLink_named_value_float_message(0, b"esc_first", 1.0),  # servo 1 is ESC 1 here
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


# ---------------------------------------------------------------- issue 17, item 9: 80 x 24

NINE = [
    "aileron",
    "elevator",
    "throttle",
    "rudder",
    "payload_release",
    "tow_hook",
    "gimbal_roll",
    "gimbal_pitch",
    "gimbal_yaw",
]


def _nine_servo_messages(extreme: bool = False) -> list:
    """Nine servos with values as wide as their formats make them (or a hostile 1e30)."""
    m = mavlink2
    out = [m.MAVLink_heartbeat_message(33, 8, 0, 0, 4, 3)]
    for n in range(1, 10):
        for suffix, value in (
            ("sp", -180.0),
            ("pos", -180.0),
            ("vel", -1440.0 if not extreme else 1e30),
            ("cur", -12.34),
            ("tmp", 125.0),
        ):
            out.append(m.MAVLink_named_value_float_message(0, f"s{n}_{suffix}".encode(), value))
    out.append(m.MAVLink_actuator_output_status_message(0, 0x1FF, [-1.0] * 9 + [0.0] * 23))
    out.append(m.MAVLink_statustext_message(4, b"servo tow_hook fault over_current", 0, 0))
    out.append(m.MAVLink_statustext_message(9, b"a severity outside MAV_SEVERITY", 0, 0))
    return out


def _screen(state: MonitorState, now: float, width: int = 80, height: int = 24) -> list[str]:
    from rich.console import Console

    console = Console(width=width, height=height, record=True, file=io.StringIO())
    console.print(render(state, now, "mavservo monitor  udpin:0.0.0.0:14552", width, height))
    return console.export_text().rstrip("\n").split("\n")


def test_dashboard_fits_80_by_24_with_nine_servos_every_value_whole():
    state = MonitorState(names=NINE)
    for msg in _wire(_nine_servo_messages()):
        state.update(msg, now=50.0)
    lines = _screen(state, now=50.5)
    assert len(lines) <= 24 and all(len(line) <= 80 for line in lines), lines
    assert not any("\u2026" in line for line in lines), lines  # nothing cut with an ellipsis
    header, units = lines[1].split(), lines[2].split()
    assert header == ["#", "name", "set", "pos", "vel", "norm", "I", "T", "age", "status"]
    assert units == ["deg", "deg", "deg/s", "-1..1", "A", "degC", "s"]
    rows = [line.split() for line in lines if line.split()[1:2] and line.split()[1] in NINE]
    assert [row[1] for row in rows] == NINE, lines
    for row in rows:  # the widest value of each column, whole, then age and status
        assert row[2:8] == ["-180.0", "-180.00", "-1440.0", "-1.000", "-12.34", "125"], row
        assert row[8:] == ["0.50", "FAULT" if row[1] == "tow_hook" else "ok"], row
    screen = "\n".join(lines)
    assert "[WARNING] servo tow_hook fault over_current" in screen  # severity by name
    assert "[9] a severity outside MAV_SEVERITY" in screen


def test_a_hostile_value_stays_inside_its_column():
    state = MonitorState(names=NINE)
    for msg in _wire(_nine_servo_messages(extreme=True)):
        state.update(msg, now=50.0)
    lines = _screen(state, now=50.5)
    assert all(len(line) <= 80 for line in lines)
    aileron = next(line for line in lines if " aileron " in line)
    assert aileron.split()[4] == "+1e+30"


def test_names_without_config_are_the_bridges_own_named_value_prefixes():
    state = MonitorState()
    for msg in _wire(_servo_messages()):
        state.update(msg, now=1.0)
    named = [row["name"] for row in state.servo_rows(1.1) if row["servo"] != "?"]
    assert named == ["s1", "s2"]
    assert any(line.split()[:2] == ["1", "s1"] for line in _screen(state, now=1.1))


def test_message_rate_falls_to_zero_when_the_bridge_stops():
    state = MonitorState()
    messages = _wire(_servo_messages())
    for tick in range(100):  # 10 s at 10 sends a second
        for msg in messages:
            state.update(msg, now=100.0 + tick / 10)
    n = len(messages)
    assert state.link_line(now=110.0).startswith(f"{10 * n} msg/s, {100 * n} msgs")
    quiet = state.link_line(now=125.0)
    assert quiet.startswith("0 msg/s, silent 15.1 s"), quiet
    assert "0 msg/s" in _screen(state, now=125.0)[0]


def test_too_many_servos_for_the_height_say_so_instead_of_vanishing():
    state = MonitorState(names=[f"servo{n}" for n in range(1, 31)])
    for n in range(1, 31):
        msg = mavlink2.MAVLink_named_value_float_message(0, f"s{n}_pos".encode(), 1.0)
        for received in _wire([msg]):
            state.update(received, now=5.0)
    lines = _screen(state, now=5.1)
    assert len(lines) <= 24
    assert any("more servos: a taller terminal shows them" in line for line in lines), lines


def test_plain_lines_print_each_new_statustext_once_with_its_severity_name():
    state = MonitorState(names=NINE)
    for msg in _wire(_nine_servo_messages()):
        state.update(msg, now=1.0)
    first = [line for line in plain_lines(state, 1.0, texts_shown=0) if " statustext " in line]
    assert [line.split(" statustext ")[1] for line in first] == [
        "severity=WARNING text=servo tow_hook fault over_current",
        "severity=9 text=a severity outside MAV_SEVERITY",
    ]
    again = plain_lines(state, 2.0, texts_shown=state.text_count)
    assert not any(" statustext " in line for line in again)


def test_esc_data_maps_to_servos_through_esc_first_and_motor_escs_are_left_out():
    """The bridge's servos start at ESC 17 by default; the autopilot's motors are ESC 1..4.
    Until ``esc_first`` is heard no ESC data is mapped (a guess would file it under the wrong
    servo); then ESC 17 is servo 1 and the motors' ESC 1..4 are no servo rows at all."""
    zeros = [0] * 4
    motors = mavlink2.MAVLink_esc_telemetry_1_to_4_message(
        [60] * 4, zeros, [900] * 4, zeros, zeros, [9] * 4
    )
    servos = mavlink2.MAVLink_esc_telemetry_17_to_20_message(
        [33, 0, 0, 0], zeros, [150, 0, 0, 0], zeros, zeros, [4, 0, 0, 0]
    )
    state = MonitorState()
    for msg in _wire([servos]) + _wire([motors], component=1):
        state.update(msg, 1.0)
    assert state.servos == {}
    for msg in _wire([mavlink2.MAVLink_named_value_float_message(0, b"esc_first", 17.0)]):
        state.update(msg, 1.5)
    for msg in _wire([servos]) + _wire([motors], component=1):
        state.update(msg, 2.0)
    assert set(state.servos) == {1}
    assert state.servos[1].current_a == 1.5 and state.servos[1].temperature_c == 33


def test_without_config_a_servo_name_in_a_text_makes_no_phantom_row():
    """issue 37: ``servo left not responding`` made a row of its own (servo ``?``) that stayed
    NO REPLY beside the servo's real numbered row; the numbered row's ``s<n>_flt`` says it."""
    from mavservo.servos import Fault

    state = MonitorState()
    msgs = _wire(
        [
            mavlink2.MAVLink_named_value_float_message(0, b"s1_pos", 1.0),
            mavlink2.MAVLink_statustext_message(2, b"servo left not responding", 0, 0),
            mavlink2.MAVLink_statustext_message(2, b"servo left fault over_current", 0, 0),
            mavlink2.MAVLink_named_value_float_message(0, b"s1_flt", float(Fault.NO_REPLY.value)),
        ]
    )
    for msg in msgs:
        state.update(msg, now=10.0)
    rows = state.servo_rows(now=10.1)
    assert [(row["servo"], row["name"], row["status"]) for row in rows] == [("1", "s1", "NO REPLY")]
    assert state.text_count == 2  # the texts are still shown in the tail


def test_the_monitor_listens_on_this_machine_only_by_default():
    from mavservo.app.monitor import DEFAULT_URL

    assert DEFAULT_URL == "udpin:127.0.0.1:14552"
    assert "udpout:127.0.0.1:14552" in (REPO / "config" / "sim.yaml").read_text()
