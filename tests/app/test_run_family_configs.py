"""``mavservo run`` on the family example configs (Damiao DM-J, CubeMars AK in MIT mode,
ODrive, Robstride, LK-Tech), on the built-in simulation as a user starts it: the simulated
autopilot drives the servos, they follow, telemetry comes back, nothing is lost, and the configs
pass ``mavservo check``. The same run of the DroneCAN, DroneCAN PWM and slcan examples is here
too (moved from the DroneCAN and bus factory test files), so all eight run side by side."""

from __future__ import annotations

import json
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
OTHER_EXAMPLES = ["dronecan.yaml", "dronecan-pwm.yaml", "slcan.yaml"]


@pytest.mark.parametrize("config_name", FAMILY_CONFIGS)
def test_family_config_passes_check(config_name: str, capsys: pytest.CaptureFixture[str]) -> None:
    # ``mavservo check``'s own entry point, in this process (the command line's dispatch to it
    # is tests/app/test_cli_dispatch.py's subject; a child interpreter here only cost its start)
    assert main(["check", str(REPO / "config" / config_name)]) == 0, capsys.readouterr()


AT_ONCE = 4
"""Runs side by side: each bridge and its simulation take about a quarter of a core, so four
leave room for the other pytest worker on a two-core machine (eight at once on a loaded one
delayed replies enough to blur a servo's following)."""


@pytest.fixture(scope="module")
def example_runs(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, ExampleRun]]:
    """Every example's ``mavservo run``, ``AT_ONCE`` at a time side by side (each a child
    process of its own with its own simulation, log directory and output), so the eight 8 s
    runs take about the time of two; each config's test judges its own run in full. pytest-xdist
    hands a worker consecutive tests, so these normally share one worker's fixture; one that
    gets only some of them runs all eight anyway (seconds of CPU, no extra waiting)."""
    names = FAMILY_CONFIGS + OTHER_EXAMPLES
    runs: dict[str, ExampleRun] = {}
    try:
        for first in range(0, len(names), AT_ONCE):
            wave = names[first : first + AT_ONCE]
            for name in wave:
                runs[name] = ExampleRun(name, tmp_path_factory.mktemp(Path(name).stem))
            for name in wave:
                runs[name].wait()
        yield runs
    finally:
        for run in runs.values():
            run.kill()


@pytest.mark.parametrize("config_name", FAMILY_CONFIGS)
def test_family_config_runs_follows_and_loses_nothing(
    config_name: str, example_runs: dict[str, ExampleRun]
) -> None:
    example_runs[config_name].assert_follows_and_loses_nothing()


def test_shipped_dronecan_config_runs_follows_and_loses_nothing(
    example_runs: dict[str, ExampleRun],
) -> None:
    """(From tests/e2e/test_dronecan_through_bridge.py.)"""
    example_runs["dronecan.yaml"].assert_follows_and_loses_nothing()


def test_shipped_pwm_config_runs_follows_and_loses_nothing(
    example_runs: dict[str, ExampleRun],
) -> None:
    """``config/dronecan-pwm.yaml``: four PWM outputs of one ArduPilot-style node, the bridge's
    SafetyState, the simulated autopilot's sweep followed, telemetry back, nothing lost. (From
    tests/e2e/test_dronecan_nodes.py.)"""
    run = example_runs["dronecan-pwm.yaml"]
    run.assert_follows_and_loses_nothing()
    # SAFETY_ON went out at the stop (safety_on: stop), and the summary and metrics.json say
    # so (issue 37: both lacked it: they were taken before the stop frames went out)
    [run_dir] = list(run.logs.iterdir())
    assert json.loads((run_dir / "metrics.json").read_text())["safety_on"] == 1
    assert "SAFETY_ON 1 time" in (run.logs.parent / "stdout.txt").read_text()


def test_mavservo_run_through_python_can_slcan_drives_servos_and_loses_nothing(
    example_runs: dict[str, ExampleRun],
) -> None:
    """config/slcan.yaml as shipped: python-can's slcan interface, the simulated LAWICEL
    adapter, servos that follow the simulated autopilot, telemetry back, 0 lost. (From
    tests/transport/test_bus_factory.py.)"""
    example_runs["slcan.yaml"].assert_follows_and_loses_nothing()
