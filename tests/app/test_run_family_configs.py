"""``mavservo run`` on the family example configs (Damiao DM-J, CubeMars AK in MIT mode,
ODrive, Robstride, LK-Tech), on the built-in simulation as a user starts it: the simulated
autopilot drives the servos, they follow, telemetry comes back, nothing is lost, and the configs
pass ``mavservo check``."""

from __future__ import annotations

from pathlib import Path

import pytest

from mavservo.cli import main
from tests.app.test_run_cli import REPO
from tests.support.bridge import ExampleRun

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


def test_every_family_config_runs_follows_and_loses_nothing(tmp_path: Path) -> None:
    """Each family config's ``mavservo run``, all five started at once, side by side (each a
    child process of its own with its own simulation, log directory and output), then each
    judged in full: the five 8 s runs take the time of one. One test rather than one per config
    because pytest-xdist hands out a module's first tests one per worker in turn, so a shared
    module fixture would start all five on both workers. Every config is judged, and a failure
    names the config and what failed (the others' verdicts with it)."""
    runs = {name: ExampleRun(name, tmp_path / Path(name).stem) for name in FAMILY_CONFIGS}
    failures: dict[str, str] = {}
    try:
        for name, run in runs.items():
            try:
                run.assert_follows_and_loses_nothing()
            except AssertionError as failure:
                failures[name] = str(failure)
    finally:
        for run in runs.values():
            run.kill()
    assert failures == {}
