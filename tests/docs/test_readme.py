"""The README is a landing page whose two commands are the ones that are really run.

Issue 37 item 5: a README of at most 200 lines; its test command is "exactly what CI runs"
(`.ci/run` says to keep the two identical), so a change to one without the other fails here.
Every link of the README into the repository names a file that exists.
"""

from __future__ import annotations

import re

from tests.support.paths import REPO

README = (REPO / "README.md").read_text(encoding="utf-8")
CI = (REPO / ".ci" / "run").read_text(encoding="utf-8")
_BASH = re.compile(r"```bash\n(.*?)```", re.S)


def test_the_readme_is_a_landing_page() -> None:
    assert len(README.splitlines()) <= 200


def test_the_readmes_test_command_is_the_one_ci_runs() -> None:
    commands = [block.strip() for block in _BASH.findall(README)]
    tests = [command for command in commands if "pytest" in command]
    assert len(tests) == 1, commands
    installs, _, run = tests[0].partition("pip install '.[test,interop]' && ")
    assert installs and run, tests[0]
    assert "python -m pip install --quiet '.[test,interop]'" in CI
    assert any(line.startswith(run) for line in CI.splitlines()), (
        f"README runs `{run}`; .ci/run runs none such: keep the two identical"
    )


def test_the_quick_start_runs_the_built_in_simulation() -> None:
    commands = [block.strip() for block in _BASH.findall(README)]
    assert commands[0] == (
        "python3 -m venv .venv && . .venv/bin/activate && pip install . && "
        "mavservo run --duration 20"
    )


def test_every_link_into_the_repository_names_a_file_there() -> None:
    targets = re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", README)
    assert len(targets) > 20
    missing = [target for target in targets if not (REPO / target).exists()]
    assert missing == []
