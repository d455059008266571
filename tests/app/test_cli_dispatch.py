"""The ``mavservo`` dispatcher: a subcommand that also runs on its own learns its name."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import types

import pytest

from mavservo import cli
from tests.support.paths import REPO

ROOT = REPO


def _module(monkeypatch: pytest.MonkeyPatch, name: str, main, *, takes_prog: bool) -> None:
    module = types.ModuleType(name)
    module.main = main
    monkeypatch.setitem(sys.modules, name, module)
    command = cli.Command(name, "main", "a standalone tool", takes_prog=takes_prog)
    monkeypatch.setitem(cli.COMMANDS, "tool", command)


def test_a_subcommand_that_takes_prog_prints_its_mavservo_usage(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
):
    def main(argv: list[str], prog: str = "tool") -> int:
        argparse.ArgumentParser(prog=prog).parse_args(argv)
        return 0

    _module(monkeypatch, "standalone_tool", main, takes_prog=True)
    with pytest.raises(SystemExit) as info:
        cli.main(["tool", "--help"])
    assert info.value.code == 0
    assert capsys.readouterr().out.startswith("usage: mavservo tool ")


def test_a_subcommand_without_prog_is_called_with_its_arguments_only(
    monkeypatch: pytest.MonkeyPatch,
):
    seen: list[list[str]] = []

    def main(argv: list[str]) -> int:
        seen.append(argv)
        return 3

    _module(monkeypatch, "plain_tool", main, takes_prog=False)
    assert cli.main(["tool", "a", "-b"]) == 3
    assert seen == [["a", "-b"]]


def test_sitl_prints_its_mavservo_usage(capsys: pytest.CaptureFixture[str]):
    with pytest.raises(SystemExit) as info:
        cli.main(["sitl", "--help"])
    assert info.value.code == 0
    assert capsys.readouterr().out.startswith("usage: mavservo sitl ")


@pytest.mark.parametrize("argv", [["--help"], ["--version"], ["check", "config/sim.yaml"]])
def test_a_reader_that_left_is_not_an_error(argv: list[str]):
    # `mavservo --help | head -1`: the pipe's reader is gone by the time anything is written
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        result = subprocess.run(
            [sys.executable, "-m", "mavservo.cli", *argv],
            stdout=write_end,
            stderr=subprocess.PIPE,
            text=True,
            timeout=60,
            check=False,
            cwd=ROOT,
        )
    finally:
        os.close(write_end)
    assert (result.returncode, result.stderr) == (0, "")


@pytest.mark.parametrize(
    ("argv", "hint"),
    [
        (["rnu"], "unknown command 'rnu' (did you mean 'run'?)"),
        (["chek", "my.yaml"], "(did you mean 'check'?)"),
        (["my-rig.yaml"], "to run a config: mavservo run my-rig.yaml"),
    ],
)
def test_an_unknown_command_says_what_was_meant(
    argv: list[str], hint: str, capsys: pytest.CaptureFixture[str]
):
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert hint in err and "usage: mavservo COMMAND" in err
