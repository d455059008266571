"""The pure cores are type-checked with mypy's strict flags (issue 31, must show).

mypy's ``--strict`` is a command-line switch for the whole run; ``.ci/run`` runs plain ``mypy
mavservo``, so the strictness of the pure cores (no I/O, no clock: codec, servo profiles and
their wire helpers, schedule core, bus plan, MAVLink core) lives in a per-module override of
pyproject.toml. These tests read that file the way mypy does (its own config parser and module
pattern matching) and ask mypy itself which flags ``--strict`` turns on, so a flag mypy adds to
``--strict`` later, a family whose profile escapes the pattern, or an override lost in a merge
fails here rather than silently loosening the check.
"""

from __future__ import annotations

import io
from pathlib import Path

import pytest
from mypy.config_parser import parse_config_file
from mypy.main import process_options
from mypy.options import PER_MODULE_OPTIONS, Options

ROOT = Path(__file__).resolve().parents[1]

#: The pure cores named by the issue, besides every family's profile (found on disk below).
CORES = (
    "mavservo.transport.aa55.codec",
    "mavservo.transport.aa55.candidates",
    "mavservo.transport.aa55.layout",
    "mavservo.servos.base",
    "mavservo.servos.mit",
    "mavservo.servos.cubemars.mit_mode",
    "mavservo.servos.dronecan.wire",
    "mavservo.servos.dronecan.node",
    "mavservo.servos.dronecan.alloc",
    "mavservo.servos.dronecan.actuator_watch",
    "mavservo.servos.dronecan.bus_sharing",
    "mavservo.servos.dronecan.info_service",
    "mavservo.servos.dronecan.notices",
    "mavservo.servos.dronecan.safety",
    "mavservo.servos.dronecan.get_node_info",
    "mavservo.scheduling.schedule_core",
    "mavservo.scheduling.bus_plan",
    "mavservo.scheduling.lifecycle",
    "mavservo.scheduling.liveness",
    "mavservo.scheduling.owed_replies",
    "mavservo.scheduling.poll_round",
    "mavservo.mavlink.mavlink_core",
)


def _family_profiles() -> list[str]:
    found = sorted((ROOT / "mavservo" / "servos").glob("*/profile.py"))
    return [".".join(p.relative_to(ROOT).with_suffix("").parts) for p in found]


def _strict_per_module_flags() -> dict[str, object]:
    """Each per-module option ``--strict`` changes, with the value it sets (mypy's own answer)."""
    _, strict = process_options(["--strict", "--config-file=", "x.py"])
    _, plain = process_options(["--config-file=", "x.py"])
    return {
        name: getattr(strict, name)
        for name in sorted(PER_MODULE_OPTIONS)
        if getattr(strict, name, None) != getattr(plain, name, None)
    }


def _project_options() -> Options:
    options = Options()
    errors = io.StringIO()
    parse_config_file(options, lambda: None, str(ROOT / "pyproject.toml"), io.StringIO(), errors)
    assert errors.getvalue() == "", errors.getvalue()
    return options


def test_every_family_profile_is_found() -> None:
    # the eight built-in families live in seven folders (cubemars holds two modes)
    assert len(_family_profiles()) >= 7, _family_profiles()


def test_mypy_strict_still_has_per_module_flags() -> None:
    flags = _strict_per_module_flags()
    assert {"disallow_untyped_defs", "warn_return_any", "implicit_reexport"} <= set(flags)


@pytest.mark.parametrize("module", [*CORES, *_family_profiles()])
def test_a_pure_core_gets_every_strict_flag(module: str) -> None:
    options = _project_options().clone_for_module(module)
    loose = {
        name: getattr(options, name)
        for name, value in _strict_per_module_flags().items()
        if getattr(options, name) != value
    }
    assert loose == {}, f"{module}: flags --strict sets but pyproject.toml does not: {loose}"


@pytest.mark.parametrize("module", ["mavservo.servos.rmdx.sim", "mavservo.app.bridge"])
def test_a_module_with_io_is_checked_but_not_strict(module: str) -> None:
    """The override is per module: a simulated device or the app is not swept in by a pattern."""
    options = _project_options().clone_for_module(module)
    assert options.check_untyped_defs
    assert not options.disallow_untyped_defs
