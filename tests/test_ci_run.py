"""``.ci/run``'s test step (the README's test command): the layer contracts are checked even
after a test failed, and the step fails on either (issue 37: with ``pytest && lint-imports``
a failing test hid every broken contract). Run with stand-ins for pytest and lint-imports."""

from __future__ import annotations

import os
import stat
import subprocess
from pathlib import Path

import pytest

from tests.support.paths import REPO


def _test_step() -> str:
    """The lines of .ci/run from ``set +e`` to the ``exit`` after it."""
    lines = (REPO / ".ci" / "run").read_text().splitlines()
    start = lines.index("set +e")
    end = next(k for k in range(start, len(lines)) if lines[k].startswith("if ["))
    return "\n".join(["set -euo pipefail", *lines[start : end + 1], "exit 0"])


def _stand_in(directory: Path, name: str, status: int) -> None:
    path = directory / name
    path.write_text(f'#!/bin/sh\necho "{name}" >> "$CALLS"\nexit {status}\n')
    path.chmod(path.stat().st_mode | stat.S_IXUSR)


@pytest.mark.parametrize(
    ("pytest_status", "lint_status", "expected"),
    [(0, 0, 0), (1, 0, 1), (5, 0, 5), (0, 1, 1), (1, 1, 1)],
)
def test_lint_imports_runs_after_a_test_failure_and_either_fails_the_step(
    tmp_path: Path, pytest_status: int, lint_status: int, expected: int
) -> None:
    _stand_in(tmp_path, "python", pytest_status)
    _stand_in(tmp_path, "lint-imports", lint_status)
    calls = tmp_path / "calls"
    env = {**os.environ, "PATH": f"{tmp_path}:{os.environ['PATH']}", "CALLS": str(calls)}
    done = subprocess.run(["bash", "-c", _test_step()], env=env, timeout=30, check=False)
    assert done.returncode == expected
    assert calls.read_text().split() == ["python", "lint-imports"]
