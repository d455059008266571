"""Issue 17, item 12: small things a user hits at the command line, each over the real CLI.

``mavservo run CONFIG`` (positional, as ``check`` takes it), ``--duration`` above 0 only,
``sim --help`` and ``sitl --help`` that explain themselves, ``--version`` in ``--help``, SIGHUP
cleaning up ``mavservo sim``'s link, ``check`` naming a servo no input drives, a tab in the YAML
and a bad bitrate reported where they are.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from mavservo.sim.sim_command import build_parser as sim_parser
from tests.app.test_run_cli import run_mavservo as mavservo
from tests.support.paths import REPO
from tests.support.signals import as_under_nohup, default_signal_dispositions

MINIMAL = "mavlink: {url: sim}\nservos: [{name: a, profile: rmd-x, can_id: 1}]\n"


def test_run_takes_its_config_as_a_positional_argument_like_check(tmp_path: Path) -> None:
    config = tmp_path / "one.yaml"
    config.write_text(MINIMAL)
    proc = mavservo("run", str(config), "--duration", "0.5", "--no-log", "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert f"running {config}" in proc.stdout and "mavservo summary" in proc.stdout
    other = tmp_path / "other.yaml"
    other.write_text(MINIMAL)
    both = mavservo("run", str(config), "--config", str(other), "--duration", "0.5")
    assert both.returncode == 2
    assert "two configs given" in both.stderr and "Traceback" not in both.stderr


@pytest.mark.parametrize("duration", ["-1", "0", "nan", "inf", "soon"])
def test_run_refuses_a_duration_that_is_not_a_positive_number(duration: str) -> None:
    proc = mavservo("run", "--duration", duration, "--no-log", "--quiet")
    assert proc.returncode == 2
    assert "--duration" in proc.stderr and "Traceback" not in proc.stderr
    assert "seconds" in proc.stderr
    assert "mavservo summary" not in proc.stdout  # refused before anything ran


def test_sim_help_explains_every_option_and_the_printed_device_path() -> None:
    parser = sim_parser()
    silent = [
        action.option_strings
        for action in parser._actions
        if action.option_strings
        and not isinstance(action, argparse._HelpAction)
        and not action.help
    ]
    assert not silent, f"options without help: {silent}"
    proc = mavservo("sim", "--help")
    assert proc.returncode == 0
    text = " ".join(proc.stdout.split())
    assert "first line on standard output is the device path" in text
    assert "--bitrate BITRATE CAN bitrate in bit/s" in text and "(default 1000000)" in text
    assert "SIGHUP" in text


def test_sitl_help_shows_the_real_command() -> None:
    proc = mavservo("sitl", "--help")
    assert proc.returncode == 0
    assert "``" not in proc.stdout and "python -m" not in proc.stdout
    assert "mavservo sitl stream" in " ".join(proc.stdout.split())


def test_top_level_help_lists_version() -> None:
    proc = mavservo("--help")
    assert proc.returncode == 0
    assert "-V, --version" in proc.stdout
    version = mavservo("--version")
    assert version.returncode == 0 and version.stdout.startswith("mavservo ")


@contextlib.contextmanager
def running_sim(link: Path, nohup: bool = False) -> Iterator[subprocess.Popen[str]]:
    """``mavservo sim --link LINK`` once it has printed the link (so its signal handlers are in
    place); killed on the way out if a test left it running. ``nohup``: SIGHUP ignored at
    start, as ``nohup`` does."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "mavservo", "sim", "--link", str(link)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
        preexec_fn=as_under_nohup if nohup else default_signal_dispositions,
    )
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == str(link)
        assert link.is_symlink()
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)


def test_sighup_stops_sim_and_removes_its_link(tmp_path: Path) -> None:
    link = tmp_path / "ttyUSBsim"
    with running_sim(link) as proc:
        proc.send_signal(signal.SIGHUP)
        _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert not link.is_symlink() and not link.exists()


def test_nohup_sim_outlives_a_hangup(tmp_path: Path) -> None:
    link = tmp_path / "ttyUSBsim"
    with running_sim(link, nohup=True) as proc:
        proc.send_signal(signal.SIGHUP)
        with pytest.raises(subprocess.TimeoutExpired):
            proc.wait(timeout=1.0)  # still running: the hangup stayed ignored
        assert link.is_symlink()
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=20)
    assert proc.returncode == 0 and not link.is_symlink()


def test_check_warns_about_a_servo_no_input_drives(tmp_path: Path) -> None:
    config = tmp_path / "undriven.yaml"
    config.write_text(
        "servos:\n"
        "  - {name: aileron, profile: rmd-x, can_id: 1}\n"
        "  - {name: spare, profile: rmd-x, can_id: 2}\n"
        "  - {name: cam_pitch, profile: rmd-x, can_id: 3}\n"
        "channels:\n"
        "  - {servo: aileron, source: servo_output, channel: 1}\n"
        "gimbals:\n"
        "  - {name: cam, pitch: cam_pitch}\n"
    )
    proc = mavservo("check", str(config))
    assert proc.returncode == 0, proc.stderr
    warnings = [line for line in proc.stdout.splitlines() if "driven by no input" in line]
    assert len(warnings) == 1, proc.stdout
    assert warnings[0].strip().startswith(f"{config}:3: servos[1].name: servo 'spare'")


def test_a_tab_in_the_yaml_gets_an_indentation_hint_at_its_line(tmp_path: Path) -> None:
    config = tmp_path / "tabbed.yaml"
    config.write_text("servos:\n  - name: a\n\tprofile: rmd-x\n    can_id: 1\n")
    proc = mavservo("check", str(config))
    assert proc.returncode == 2
    assert f"{config}:3:" in proc.stderr
    assert "tabs are not allowed for indentation in YAML; use spaces" in proc.stderr


def test_a_bad_bitrate_is_reported_at_the_bitrate_key(tmp_path: Path) -> None:
    config = tmp_path / "bitrate.yaml"
    config.write_text(
        "can:\n"
        "  buses:\n"
        "    - name: bus0\n"
        "      interface: aa55\n"
        "      channel: sim\n"
        "      bitrate: 123456\n"
        "servos: [{name: a, profile: rmd-x, can_id: 1}]\n"
    )
    proc = mavservo("check", str(config))
    assert proc.returncode == 2
    assert f"{config}:6: can.buses[0].bitrate: an aa55 adapter supports bitrates" in proc.stderr


def test_sighup_ends_a_run_cleanly_with_the_failsafe_sent(tmp_path: Path) -> None:
    """Before, a hangup (terminal or ssh session closed) killed the bridge with no failsafe,
    no summary and its run log unclosed."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "mavservo", "run", "--log-dir", str(tmp_path), "--quiet"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
        preexec_fn=default_signal_dispositions,  # a SIGHUP ignored by nohup is not inherited
    )
    try:
        assert proc.stdout is not None
        line = ""
        for _ in range(20):  # the "running" line comes after the signal handlers are set
            line = proc.stdout.readline()
            if "running" in line or not line:
                break
        assert "running" in line
        proc.send_signal(signal.SIGHUP)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
    assert proc.returncode == 0, err
    assert "INFO    bridge: stopped (SIGHUP): servos told their failsafe action:" in out
    assert "mavservo summary" in out
