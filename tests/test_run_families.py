"""``mavservo run`` on the family example configs (Damiao DM-J, CubeMars AK in MIT mode,
ODrive, Robstride), on the built-in simulation as a user starts it: the simulated autopilot
drives the servos, they follow, telemetry comes back, nothing is lost, and the configs pass
``mavservo check``."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml
from test_run_cli import REPO, assert_positions_followed, read_trace, run_mavservo

from mavservo.config import load_config

FAMILY_CONFIGS = ["damiao.yaml", "cubemars-mit.yaml", "odrive.yaml", "robstride.yaml"]


@pytest.mark.parametrize("config_name", FAMILY_CONFIGS)
def test_family_config_passes_check(config_name: str) -> None:
    proc = run_mavservo("check", str(REPO / "config" / config_name))
    assert proc.returncode == 0, proc.stderr + proc.stdout


@pytest.mark.parametrize("config_name", FAMILY_CONFIGS)
def test_family_config_runs_follows_and_loses_nothing(config_name: str, tmp_path: Path) -> None:
    # the example as shipped, except that a reply counts as lost only when it never comes: a
    # loaded test machine can delay one past the 50 ms default, and timing is not judged here
    document = yaml.safe_load((REPO / "config" / config_name).read_text())
    document["scheduler"]["reply_timeout_s"] = 0.5
    document["logging"]["dir"] = str(tmp_path / "runs")
    path = tmp_path / config_name
    path.write_text(yaml.safe_dump(document))
    logs = tmp_path / "runs"
    proc = run_mavservo("run", "--config", str(path), "--duration", "8", "--log-dir", str(logs))
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    out = proc.stdout
    assert "decoder rejections 0" in out
    config = load_config(path)
    for servo in config.servos:
        # columns: sent, recv, pushed, lost, late, rej (a pushing servo's pushed is not lost)
        row = re.search(rf"^\s+{servo.name}" + r"\s+(\d+)" * 6, out, re.M)
        assert row, f"no summary row for {servo.name}:\n{out}"
        sent, received, _pushed, lost, _late, rejected = map(int, row.groups())
        assert sent > 0 and received > 0, row.group(0)
        assert lost == 0 and rejected == 0, row.group(0)
    [run_dir] = list(logs.iterdir())
    trace = read_trace(run_dir / "trace.csv")
    for servo in config.servos:
        # the simulated autopilot sweeps every servo of these configs: each one follows
        assert_positions_followed(servo.name, trace, span=20.0)
