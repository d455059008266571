"""What ``check`` and ``run`` say about where they connect, and the command-line usage texts.

A config that leaves out ``can:`` or ``mavlink.url`` runs on the built-in simulation; these
tests hold that both commands say so, and name the real interface, channel and MAVLink URL
otherwise, so hardware and simulation cannot be confused.
"""

from __future__ import annotations

import io
import subprocess
import sys
import textwrap
import types
from pathlib import Path

import pytest

from mavservo.app.check import check_main
from mavservo.app.console import StatusDisplay
from mavservo.config import load_config, load_config_text
from mavservo.config.endpoints import bitrate_text, endpoint_lines
from mavservo.config.overrides import apply_overrides
from tests.support.paths import REPO

SERVO = "servos:\n  - {name: a, profile: rmd-x, can_id: 1}\n"
HARDWARE = textwrap.dedent("""\
    mavlink: {url: /dev/ttyAMA0, baud: 921600}
    can:
      buses:
        - {name: surfaces, channel: /dev/ttyUSB0, bitrate: 500000}
        - {name: tail, interface: socketcan, channel: can1, bitrate: 250000}
    servos:
      - {name: a, profile: rmd-x, can_id: 1, bus: surfaces}
      - {name: b, profile: rmd-x, can_id: 2, bus: tail}
""")


def _check(path: Path) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    status = check_main([str(path)], out=out, err=err)
    return status, out.getvalue(), err.getvalue()


def test_check_says_when_left_out_keys_mean_the_simulation(tmp_path: Path):
    config = tmp_path / "min.yaml"
    config.write_text(SERVO)
    status, out, _ = _check(config)
    assert status == 0
    assert "mavlink: built-in stream simulator (mavlink.url not set)" in out
    assert "bus0: built-in simulation" in out and "@ 1 Mbit/s (can not set)" in out
    # Each link is said once: one line for the simulated autopilot, one for the bus.
    assert out.count("stream simulator") == 1
    assert out.count("built-in simulation") == 1
    assert "(1 servo, " in out  # not "1 servos"


def test_check_names_the_interface_channel_and_mavlink_url_of_real_hardware(tmp_path: Path):
    config = tmp_path / "hw.yaml"
    config.write_text(HARDWARE)
    status, out, _ = _check(config)
    assert status == 0
    assert "mavlink: serial /dev/ttyAMA0 @ 921600 baud" in out
    assert "surfaces: aa55 /dev/ttyUSB0 @ 500 kbit/s (serial 2000000 baud)" in out
    assert "tail: socketcan can1 @ 250 kbit/s" in out
    assert "not set" not in out and "simulation" not in out


def test_an_explicit_sim_is_described_without_a_not_set_note():
    config = load_config_text(
        "mavlink: {url: sim}\ncan: {buses: [{name: bus0, channel: sim}]}\n" + SERVO
    )
    lines = endpoint_lines(config)
    assert "mavlink: built-in stream simulator" in lines
    assert any(line.startswith("bus0: built-in simulation") for line in lines)
    assert not any("not set" in line for line in lines)


def test_a_bus_without_a_channel_is_named_as_the_key_left_out():
    config = load_config_text("can: {buses: [{name: left}]}\n" + SERVO)
    lines = endpoint_lines(config)
    assert [line for line in lines if line.startswith("left:")] == [
        "left: built-in simulation (AA-55 adapter emulator on a pty, simulated servos) @ 1 Mbit/s"
        " (can.buses[0].channel not set)"
    ]
    assert len(lines) == 2


def test_overrides_keep_the_record_of_what_the_file_left_out():
    config = load_config_text(SERVO)
    overridden = apply_overrides(config, port="/dev/ttyUSB3")
    lines = endpoint_lines(overridden)
    assert "mavlink: built-in stream simulator (mavlink.url not set)" in lines
    assert len(lines) == 2
    assert "bus0: aa55 /dev/ttyUSB3 @ 1 Mbit/s (serial 2000000 baud)" in lines
    assert not any(line.startswith("can") for line in lines)
    lines = endpoint_lines(apply_overrides(config, mavlink="udpin:0.0.0.0:14550"))
    assert "mavlink: udpin:0.0.0.0:14550 (listening)" in lines
    assert any(
        line.startswith("bus0: built-in simulation") and line.endswith("(can not set)")
        for line in lines
    )


def test_run_banner_lists_the_connections(tmp_path: Path):
    config = tmp_path / "min.yaml"
    config.write_text(SERVO)
    stream = io.StringIO()
    bridge = types.SimpleNamespace(config=load_config(config), run_dir=None)
    StatusDisplay(enabled=False, stream=stream).started(config, bridge)
    lines = stream.getvalue().splitlines()
    assert lines[0] == f"mavservo: running {config}"
    assert "  mavlink: built-in stream simulator (mavlink.url not set)" in lines
    assert lines[2].startswith("  bus0: built-in simulation") and lines[2].endswith("(can not set)")
    assert len(lines) == 3


def test_mavservo_run_prints_the_interface_and_mavlink_url(tmp_path: Path):
    config = tmp_path / "virtual.yaml"
    config.write_text(
        "mavlink: {url: 'udpin:127.0.0.1:0'}\n"
        "can: {buses: [{name: bench, interface: virtual, channel: mavservo-test-banner}]}\n" + SERVO
    )
    proc = run_briefly(config)
    assert proc.returncode == 0, proc.stderr
    assert "  mavlink: udpin:127.0.0.1:0 (listening)" in proc.stdout
    assert "  bench: virtual mavservo-test-banner @ 1 Mbit/s" in proc.stdout


def run_briefly(config: Path, *options: str) -> subprocess.CompletedProcess[str]:
    """``mavservo run`` for half a second, no run log, plain output."""
    return subprocess.run(
        [sys.executable, "-m", "mavservo", "run", "-c", str(config), "--duration", "0.5"]
        + ["--no-log", "--quiet", *options],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=REPO,
    )


@pytest.mark.parametrize(("bitrate", "text"), [(1_000_000, "1 Mbit/s"), (125_000, "125 kbit/s")])
def test_bitrate_text(bitrate: int, text: str):
    assert bitrate_text(bitrate) == text


# ------------------------------------------------------------------------------ usage texts


@pytest.mark.parametrize("flag", ["--help", "-h"])
def test_check_help_prints_usage_and_exits_zero(flag: str, capsys: pytest.CaptureFixture[str]):
    assert check_main([flag]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: mavservo check ")
    assert "CONFIG" in out and "cannot read" not in out


def test_check_without_a_file_prints_usage_and_exits_two(capsys: pytest.CaptureFixture[str]):
    assert check_main([]) == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: mavservo check ")
    assert "CONFIG" in err


@pytest.mark.parametrize(("argv", "status"), [(["--help"], 0), ([], 2), (["--bogus", "x"], 2)])
def test_check_usage_goes_to_the_streams_it_was_given(
    argv: list[str], status: int, capsys: pytest.CaptureFixture[str]
):
    out, err = io.StringIO(), io.StringIO()
    assert check_main(argv, out=out, err=err) == status
    assert capsys.readouterr() == ("", "")  # nothing on the process's own stdout/stderr
    written = (out if status == 0 else err).getvalue()
    assert written.startswith("usage: mavservo check ")
    assert (err if status == 0 else out).getvalue() == ""


def test_check_through_the_mavservo_command(capsys: pytest.CaptureFixture[str]):
    from mavservo.cli import main

    assert main(["check", "--help"]) == 0
    assert capsys.readouterr().out.startswith("usage: mavservo check ")


def test_report_names_the_report_extra_when_matplotlib_is_missing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
):
    from mavservo.app import report

    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib -> ImportError
    assert report.main([str(tmp_path)]) == 2
    err = " ".join(capsys.readouterr().err.split())  # undo rich's line wrapping
    assert "pip install 'mavservo[report]'" in err
    assert "pip install '.[report]'" in err


def test_run_reports_what_the_file_left_out_and_a_bad_mavlink_option(tmp_path: Path):
    """``mavservo run`` applies its options without hiding which keys the file left out, and a
    bad ``--mavlink`` is named as the option, in one line, before anything starts.

    (In a subprocess: ``run`` sets up the process's logging, which must not outlive the test.)
    """
    config = tmp_path / "min.yaml"
    config.write_text(SERVO)
    bad = run_briefly(config, "--mavlink", "udpin:127.0.0.1:bad")
    assert bad.returncode == 2
    err = bad.stderr.strip()
    assert err.startswith("mavservo: --mavlink udpin:127.0.0.1:bad: port 'bad'")
    assert "\n" not in err
    proc = run_briefly(config, "--mavlink", "udpin:127.0.0.1:0")
    assert proc.returncode == 0, proc.stderr
    assert "(can not set)" in proc.stdout
    assert "  mavlink: udpin:127.0.0.1:0 (listening)" in proc.stdout
    assert "mavlink.url: not set" not in proc.stdout


def test_run_logs_recoveries_next_to_the_warnings_they_answer(tmp_path: Path):
    """A journal that shows "servo offline" or "CAN adapter lost" must also show the "back
    online" / "sends work again" lines, which are info level; the rest stays at warnings."""
    config = tmp_path / "min.yaml"
    config.write_text(SERVO)
    script = (
        "import logging, sys\n"
        "from mavservo.app import run as runcmd\n"
        "status = runcmd.main(sys.argv[1:])\n"
        "levels = [logging.getLogger(n).getEffectiveLevel() for n in runcmd.RECOVERY_LOGGERS]\n"
        "print(status, levels, logging.getLogger('mavservo.app.bridge').getEffectiveLevel())\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", script, "-c", str(config), "--duration", "0.3"]
        + ["--no-log", "--quiet"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=REPO,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "0 [20, 20] 30"
