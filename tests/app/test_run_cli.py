"""``mavservo run`` end to end on the built-in simulation, as a user starts it."""

from __future__ import annotations

import csv
import gc
import math
import re
import signal
import statistics
import struct
import subprocess
import sys
import time
from pathlib import Path

from mavservo.app.bridge import settle_heap
from mavservo.config import Config, default_config_path, load_config
from mavservo.records.runlog import read_can_log
from mavservo.servos.rmdx.profile import CMD_POSITION, REQUEST_BASE
from tests.support.paths import REPO
from tests.support.signals import default_signal_dispositions

SWEPT_CHANNELS = (1, 2, 3, 4)
"""SERVO_OUTPUT_RAW channels the default simulated autopilot sweeps (its ``sweep`` profile)."""


def run_mavservo(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "mavservo", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=REPO,
    )


def test_default_run_moves_servos_and_reports_both_directions(tmp_path: Path) -> None:
    proc = run_mavservo("run", "--duration", "5", "--log-dir", str(tmp_path))
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    assert "Traceback" not in proc.stderr
    assert "mavservo summary" in out
    # every configured servo has a summary row with frames sent and received, none lost
    names = [s.name for s in load_config(default_config_path()).servos]
    for name in names:
        row = re.search(rf"^\s+{name}" + r"\s+(\d+)" * 7, out, re.M)
        assert row, f"no summary row for {name}:\n{out}"
        sent, received, _pushed, _offline, lost, _late, rejected = map(int, row.groups())
        assert sent > 0 and received > 0, f"{name}: {row.group(0)}"
        assert lost == 0, f"{name} lost replies on the built-in simulation: {row.group(0)}"
        assert rejected == 0
    assert "decoder rejections 0" in out
    # the swept surfaces moved: the run's trace and CAN log show it
    config = load_config(default_config_path())
    [run_dir] = list(tmp_path.iterdir())
    trace = read_trace(run_dir / "trace.csv")
    commanded = commanded_angles_on_the_wire(run_dir, config)
    for name, (low, high) in swept_surfaces(config).items():
        assert_commands_moved(name, trace, commanded, span=high - low)
        assert_positions_followed(name, trace, span=high - low)


def swept_surfaces(config: Config) -> dict[str, tuple[float, float]]:
    """Servo name -> the angle range of its channel, for every channel the sweep drives."""
    surfaces = {}
    for channel in config.channels:
        if channel.source == "servo_output" and channel.channel in SWEPT_CHANNELS:
            low, high = sorted(channel.output_deg)
            surfaces[channel.servo] = (low, high)
    assert len(surfaces) == len(SWEPT_CHANNELS), surfaces
    return surfaces


def read_trace(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def commanded_angles_on_the_wire(run_dir: Path, config: Config) -> dict[str, list[float]]:
    """Servo name -> the angles of every RMD-X position command (0xA4) in the run's CAN log."""
    names = {REQUEST_BASE + s.can_id: s.name for s in config.servos if s.profile == "rmd-x"}
    angles: dict[str, list[float]] = {name: [] for name in names.values()}
    for msg in read_can_log(run_dir, "asc"):
        name = names.get(msg.arbitration_id)
        if msg.is_rx or msg.is_extended_id or name is None or msg.data[0] != CMD_POSITION:
            continue
        angles[name].append(struct.unpack_from("<i", msg.data, 4)[0] / 100)
    return angles


def assert_commands_moved(
    name: str, trace: list[dict[str, str]], wire: dict[str, list[float]], span: float
) -> None:
    """Accepted setpoints and the position commands on the wire take many values, widely."""
    setpoints = [float(r["setpoint_deg"]) for r in trace if on(r, name, "setpoint")]
    for what, angles in (("accepted setpoints", setpoints), ("commands on the wire", wire[name])):
        assert len(set(angles)) >= 10, f"{name}: {what} barely change: {sorted(set(angles))}"
        assert max(angles) - min(angles) >= span / 3, f"{name}: {what} span only {angles}"
    # what went on the wire is what was accepted (to the wire's 0.01 deg), nothing invented
    invented = [a for a in wire[name] if min(abs(a - s) for s in setpoints) > 0.005 + 1e-9]
    assert not invented, f"{name}: commanded on the wire but never accepted: {invented}"


def assert_positions_followed(name: str, trace: list[dict[str, str]], span: float) -> None:
    """Measured positions move over the commanded range, with the setpoint in force.

    Structure, not speed: positions rise and fall with the commands (correlation well above
    chance; a lagging reply on a loaded machine lowers it a little, a servo that stands still
    or moves the wrong way makes it ~0 or negative) and never leave the commanded range
    (RMD-X reports whole degrees).
    """
    rows = [r for r in trace if on(r, name, "state") and r["setpoint_deg"]]
    # a state may precede the first position reading (Damiao: the echo of a start-up register
    # write): its position is unknown (NaN), which says nothing about following
    rows = [r for r in rows if not math.isnan(float(r["position_deg"] or "nan"))]
    assert len(rows) >= 10, f"{name}: {len(rows)} measured states"
    setpoints = [float(r["setpoint_deg"]) for r in rows]
    positions = [float(r["position_deg"]) for r in rows]
    assert max(positions) - min(positions) >= span / 3, f"{name}: positions {positions}"
    assert min(setpoints) - 1 <= min(positions) and max(positions) <= max(setpoints) + 1, name
    assert len(set(setpoints)) > 1 and len(set(positions)) > 1, name
    assert statistics.correlation(setpoints, positions) > 0.5, (name, setpoints, positions)


def on(row: dict[str, str], servo: str, event: str) -> bool:
    return row["servo"] == servo and row["event"] == event


def test_sigterm_stops_cleanly_with_status_zero(tmp_path: Path) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "mavservo", "run", "--log-dir", str(tmp_path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
        preexec_fn=default_signal_dispositions,
    )
    try:
        deadline = time.monotonic() + 20
        line = ""
        while time.monotonic() < deadline and "running" not in line:
            line = proc.stdout.readline() if proc.stdout else ""
        time.sleep(1.0)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert "mavservo summary" in out
    # a normal end reads as one, at INFO, still saying what the servos were told
    assert "INFO    bridge: stopped (SIGTERM): servos told their failsafe action:" in out
    assert "failsafe: shutdown" not in out
    # then one INFO line per servo with what it does by itself, and its own timeout's value
    # (issue 37: every normal stop ended in WARNINGs naming comm_timeout_ms, not its value)
    for servo in load_config(default_config_path()).servos:
        (line,) = [x for x in out.splitlines() if f"after the stop: servo {servo.name} (" in x]
        assert " INFO    bridge: " in line, line
    assert "motor off 1 s after the last frame (comm_timeout_ms" in out  # the RMD-X default
    assert "then on their own" not in out


def test_bad_config_exits_2_with_file_and_line_and_no_traceback(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        "servos:\n  - name: a\n    profile: rmd-x\n    can_id: 1\n    limts_deg: [0, 1]\n"
    )
    proc = run_mavservo("run", "--config", str(bad), "--duration", "1")
    assert proc.returncode == 2
    assert f"{bad}:5" in proc.stderr
    assert "limts_deg" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_missing_serial_port_is_one_clear_line(tmp_path: Path) -> None:
    cfg = tmp_path / "hw.yaml"
    cfg.write_text(
        "mavlink: {url: 'udpin:127.0.0.1:0'}\n"
        "can: {buses: [{name: bus0, interface: aa55, channel: /dev/ttyUSB-not-there}]}\n"
        "servos: [{name: a, profile: rmd-x, can_id: 1}]\n"
    )
    proc = run_mavservo("run", "--config", str(cfg), "--duration", "1", "--no-log")
    assert proc.returncode == 1
    assert "cannot start" in proc.stderr and "ttyUSB-not-there" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_check_command_validates_the_simulation_configs() -> None:
    # (the hardware examples need the user's signing key file; tests/config/ covers them)
    configs = [str(REPO / "config" / "sim.yaml"), str(REPO / "config" / "ardupilot-sitl.yaml")]
    proc = run_mavservo("check", *configs)
    assert proc.returncode == 0, proc.stderr + proc.stdout
    assert "bus" in proc.stdout.lower()


def test_settle_heap_puts_the_start_up_heap_out_of_the_collectors_way() -> None:
    long_lived = [[i] for i in range(2000)]  # tracked containers, as a bridge's start-up makes
    before = gc.get_freeze_count()
    settle_heap()
    try:
        assert gc.get_freeze_count() >= before + len(long_lived)
    finally:
        gc.unfreeze()
