"""ArduPlane SITL scripts: the launcher's command line, and a live run when ArduPilot is here.

The live test needs ``sim_vehicle.py`` or ``arduplane`` (PATH or $ARDUPILOT_HOME); without them it
is skipped with that reason. Nothing is ever downloaded.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
from pathlib import Path

import pytest
from autopilot_support import collect, of_type, peer
from conftest import free_udp_port

from mavservo.sim.autopilot.link import mavlink2 as mav

REPO = Path(__file__).resolve().parent.parent
AUTOPILOT = REPO / "mavservo" / "sim" / "autopilot"  # the simulator and its ArduPilot files
SCRIPT = AUTOPILOT / "run-arduplane.sh"


def _parm(path: Path) -> dict[str, float]:
    values = {}
    for line in path.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            name, value = line.replace(",", " ").split()
            values[name] = float(value)
    return values


def test_parameter_files_match_the_recorded_sessions() -> None:
    companion = _parm(AUTOPILOT / "arduplane-companion.parm")
    gimbal = _parm(AUTOPILOT / "arduplane-gimbal.parm")
    assert companion["SERIAL1_PROTOCOL"] == 2
    assert (companion["SERVO9_FUNCTION"], companion["SERVO10_FUNCTION"]) == (0, 1)
    assert (gimbal["MNT1_TYPE"], gimbal["SCHED_LOOP_RATE"]) == (6, 100)
    assert gimbal["MNT1_PITCH_MIN"] == -90 and gimbal["MNT1_YAW_MAX"] == 160


def _bare_env(tmp_path: Path, with_binary: bool) -> dict[str, str]:
    """PATH with only the basic tools, plus a stand-in ``arduplane`` when asked."""
    bindir = tmp_path / "bin"
    bindir.mkdir()
    for tool in ("bash", "sed", "dirname", "cat"):
        found = shutil.which(tool)
        assert found
        (bindir / tool).symlink_to(found)
    if with_binary:
        fake = bindir / "arduplane"
        fake.write_text("#!/bin/sh\nexit 0\n")
        fake.chmod(0o755)
    env = {k: v for k, v in os.environ.items() if k != "ARDUPILOT_HOME"}
    env["PATH"] = str(bindir)
    return env


def test_launcher_says_clearly_when_ardupilot_is_missing(tmp_path: Path) -> None:
    done = subprocess.run(
        ["bash", str(SCRIPT)],
        env=_bare_env(tmp_path, False),
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert done.returncode == 3
    assert "not installed" in done.stderr and "never" in done.stderr
    assert done.stdout == ""


def test_dry_run_without_ardupilot_shows_the_command_to_use_once_it_is_installed(
    tmp_path: Path,
) -> None:
    # docs/sitl.md: "--dry-run  # show the command instead of running it", installed or not
    done = subprocess.run(
        ["bash", str(SCRIPT), "--dry-run", "--gimbal", "--port", "14600", "--", "--console"],
        env=_bare_env(tmp_path, False),
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert done.returncode == 0, done.stderr
    assert "not installed" in done.stderr
    words = done.stdout.split()
    assert words[:3] == ["sim_vehicle.py", "-v", "ArduPlane"]
    assert "--serial1=udpclient:127.0.0.1:14600" in words
    param_files = [w.split("=", 1)[1] for w in words if w.startswith("--add-param-file=")]
    assert param_files == [
        str(AUTOPILOT / "arduplane-companion.parm"),
        str(AUTOPILOT / "arduplane-gimbal.parm"),
    ]
    assert words[-2:] == ["-w", "--console"]


def test_launcher_command_line_for_the_arduplane_binary(tmp_path: Path) -> None:
    done = subprocess.run(
        ["bash", str(SCRIPT), "--dry-run", "--gimbal", "--port", "14600"],
        env=_bare_env(tmp_path, True),
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert done.returncode == 0, done.stderr
    words = done.stdout.split()
    assert words[0].endswith("arduplane")
    assert words[words.index("--serial1") + 1] == "udpclient:127.0.0.1:14600"
    defaults = words[words.index("--defaults") + 1].replace("\\,", ",")
    gimbal_parm = AUTOPILOT / "arduplane-gimbal.parm"
    assert defaults.endswith(f"arduplane-companion.parm,{gimbal_parm}")


def _find_ardupilot() -> str | None:
    home = os.environ.get("ARDUPILOT_HOME")
    if home and (Path(home) / "build" / "sitl" / "bin" / "arduplane").exists():
        return str(Path(home) / "build" / "sitl" / "bin" / "arduplane")
    return shutil.which("arduplane") or shutil.which("sim_vehicle.py")


@pytest.mark.skipif(
    _find_ardupilot() is None,
    reason="ArduPilot SITL not installed (no arduplane / sim_vehicle.py on PATH, "
    "no $ARDUPILOT_HOME build); tests never download it",
)
@pytest.mark.timeout(180)
def test_real_arduplane_streams_servo_outputs_and_obeys_do_set_servo(tmp_path: Path) -> None:
    port = free_udp_port()
    conn = peer(port)
    proc = subprocess.Popen(
        ["bash", str(SCRIPT), "--port", str(port)],
        cwd=tmp_path,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        start_new_session=True,
    )
    try:
        boot = collect(conn, 90.0, until=lambda m: m.get_type() == "SERVO_OUTPUT_RAW")
        assert of_type(boot, "SERVO_OUTPUT_RAW"), "no SERVO_OUTPUT_RAW from SITL within 90 s"
        hb = of_type(boot, "HEARTBEAT")[0]
        assert hb.autopilot == mav.MAV_AUTOPILOT_ARDUPILOTMEGA
        conn.mav.command_long_send(1, 1, mav.MAV_CMD_DO_SET_SERVO, 0, 9, 1234, 0, 0, 0, 0, 0)
        after = collect(
            conn, 10.0, until=lambda m: m.get_type() == "SERVO_OUTPUT_RAW" and m.servo9_raw == 1234
        )
        assert of_type(after, "SERVO_OUTPUT_RAW")[-1].servo9_raw == 1234
    finally:
        conn.close()
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGTERM)
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(5)
