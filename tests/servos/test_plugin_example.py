"""The worked plug-in (examples/mavservo-example-servo), installed as a user would install it:
into a temporary virtual environment, then checked and run on the built-in simulation with no
line of mavservo changed, and held to the conformance test like a built-in family.

The environment reuses this one's packages (``--system-site-packages`` plus a ``.pth`` that adds
this environment's site directory) and installs the example with ``--no-deps
--no-build-isolation``, so no network is needed and it takes seconds.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from tests.support.paths import REPO
from tests.support.venv import TIMEOUT_S, child_env, pip_install
from tests.support.waiting import free_udp_port

EXAMPLE = REPO / "examples" / "mavservo-example-servo"


@pytest.fixture(scope="module")
def plugin_python(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A temporary environment's python with the example plug-in installed."""
    env_dir = tmp_path_factory.mktemp("plugin-env")
    python = child_env(env_dir)
    source = env_dir / "example"  # built from a copy: the build leaves files behind
    shutil.copytree(EXAMPLE, source, ignore=shutil.ignore_patterns("build", "*.egg-info"))
    pip_install(python, source, env_dir)
    return python


def _mavservo(python: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(python), "-m", "mavservo", *args],
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        cwd=REPO,
    )


def test_the_plugin_is_listed_with_its_origin_and_options(plugin_python: Path) -> None:
    result = _mavservo(plugin_python, "check", "--profiles")
    assert result.returncode == 0, result.stderr
    assert "example-dm" in result.stdout
    assert "plug-in mavservo-example-servo" in result.stdout
    assert "master_id" in result.stdout and "comm_timeout_ms" in result.stdout


def test_the_example_config_is_valid_with_the_plugin_installed(plugin_python: Path) -> None:
    result = _mavservo(plugin_python, "check", str(EXAMPLE / "example.yaml"))
    assert result.returncode == 0, result.stderr
    assert "example-dm" in result.stdout


def test_without_the_plugin_the_profile_is_unknown_and_says_where_plugins_come_from() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "mavservo", "check", str(EXAMPLE / "example.yaml")],
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        cwd=REPO,
    )
    assert result.returncode == 2
    assert "unknown servo profile 'example-dm'" in result.stderr
    assert "'mavservo.profiles' entry points" in result.stderr


def test_a_new_family_at_0x41_colliding_with_rmdx_1_is_refused_naming_both(
    plugin_python: Path, tmp_path: Path
) -> None:
    config = tmp_path / "clash.yaml"
    config.write_text(
        textwrap.dedent(
            """\
            servos:
              - {name: pan, profile: rmd-x, can_id: 1}
              - {name: newcomer, profile: example-dm, can_id: 0x41}
            """
        )
    )
    result = _mavservo(plugin_python, "check", str(config))
    assert result.returncode == 2
    assert f"{config}:3: servos[1].can_id:" in result.stderr
    assert "'newcomer'" in result.stderr and "'pan'" in result.stderr
    assert "0x141" in result.stderr


def test_the_plugin_runs_on_the_built_in_simulation(plugin_python: Path) -> None:
    port = free_udp_port()
    result = _mavservo(
        plugin_python,
        "run",
        "--config",
        str(EXAMPLE / "example.yaml"),
        "--duration",
        "3",
        "--no-log",
        "--quiet",
        "--mavlink",
        f"udpin:127.0.0.1:{port}",
    )
    assert result.returncode == 0, result.stderr
    assert "tilt" in result.stdout
    assert "Traceback" not in result.stderr


def test_the_plugin_passes_the_conformance_test(plugin_python: Path) -> None:
    result = subprocess.run(
        [
            str(plugin_python),
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:cacheprovider",
            str(REPO / "tests" / "servos" / "test_profile_contract.py"),
            "-k",
            "example-dm",
        ],
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        cwd=REPO,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert " passed" in result.stdout and "deselected" in result.stdout
