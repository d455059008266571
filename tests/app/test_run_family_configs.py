"""``mavservo run`` on the family example configs (Damiao DM-J, CubeMars AK in MIT mode,
ODrive, Robstride, LK-Tech), on the built-in simulation as a user starts it: the simulated
autopilot drives the servos, they follow, telemetry comes back, nothing is lost, and the configs
pass ``mavservo check``."""

from __future__ import annotations

from collections.abc import Iterator
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


@pytest.fixture(scope="module")
def family_runs(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, ExampleRun]]:
    """Every family config's ``mavservo run``, all started at once, side by side (each a child
    process of its own with its own simulation, log directory and output), so the five 8 s runs
    take the time of one; each config's test judges its own run in full. pytest-xdist hands a
    worker consecutive tests, so these five normally share one worker's fixture; one that gets
    only some of them starts all five anyway (seconds of CPU, no extra waiting)."""
    runs = {
        name: ExampleRun(name, tmp_path_factory.mktemp(Path(name).stem)) for name in FAMILY_CONFIGS
    }
    try:
        yield runs
    finally:
        for run in runs.values():
            run.kill()


@pytest.mark.parametrize("config_name", FAMILY_CONFIGS)
def test_family_config_runs_follows_and_loses_nothing(
    config_name: str, family_runs: dict[str, ExampleRun]
) -> None:
    family_runs[config_name].assert_follows_and_loses_nothing()
