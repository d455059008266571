"""``mavservo run`` on the family example configs (Damiao DM-J, CubeMars AK in MIT mode,
ODrive, Robstride, LK-Tech), on the built-in simulation as a user starts it: the simulated
autopilot drives the servos, they follow, telemetry comes back, nothing is lost, and the configs
pass ``mavservo check``."""

from __future__ import annotations

from pathlib import Path

import pytest

from mavservo.cli import main
from tests.app.test_run_cli import REPO
from tests.support.bridge import run_example_config_follows_and_loses_nothing

FAMILY_CONFIGS = [
    "damiao.yaml",
    "cubemars-mit.yaml",
    "odrive.yaml",
    "robstride.yaml",
    "lk.yaml",
]


@pytest.mark.parametrize("config_name", FAMILY_CONFIGS)
def test_family_config_passes_check(config_name: str, capsys: pytest.CaptureFixture[str]) -> None:
    # ``mavservo check``'s own entry point, in this process (the command line's dispatch to it
    # is tests/app/test_cli_dispatch.py's subject; a child interpreter here only cost its start)
    assert main(["check", str(REPO / "config" / config_name)]) == 0, capsys.readouterr()


@pytest.mark.parametrize("config_name", FAMILY_CONFIGS)
def test_family_config_runs_follows_and_loses_nothing(config_name: str, tmp_path: Path) -> None:
    run_example_config_follows_and_loses_nothing(config_name, tmp_path)
