"""`mavservo sitl stream|replay --help`: every option says what it does (issue 37, item 7)."""

from __future__ import annotations

import argparse

import pytest

from mavservo.sim.autopilot.sitl_command import build_parser


def _subparser(name: str) -> argparse.ArgumentParser:
    parser = build_parser()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action.choices[name]
    raise AssertionError("no subcommands")


@pytest.mark.parametrize("name", ["stream", "replay"])
def test_every_option_and_argument_has_help(name: str) -> None:
    sub = _subparser(name)
    missing = [
        action.dest
        for action in sub._actions
        if not isinstance(action, argparse._HelpAction) and not action.help
    ]
    assert missing == []


def test_script_help_gives_an_example_and_the_docs_not_a_source_file() -> None:
    text = _subparser("stream").format_help()
    assert "autopilot_script.py" not in text
    assert "do_set_servo" in text
    assert "docs/configuration.md" in text
