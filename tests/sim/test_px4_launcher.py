"""``mavservo sitl px4``: the launcher's command line, its parameter shim, and a live run against
PX4 SITL when a built PX4 is here (issue 39).

The live tests need ``$PX4_HOME/build/px4_sitl_default/bin/px4`` (or ``px4`` on PATH); without it
they are skipped with that reason. Nothing is ever built or downloaded. PX4's listeners bind
every address, and one instance 0 runs per machine (lock file ``px4_lock-0``): run them on
loopback only, one at a time, in a network namespace that has only ``lo``::

    PX4_HOME=/path/to/PX4-Autopilot unshare -n sh -c \\
        'ip link set lo up && python -m pytest -s tests/sim/test_px4_launcher.py'
"""

from __future__ import annotations

import ast
import dataclasses
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mavservo.config.loader import load_config
from mavservo.config.views import mavlink_settings
from mavservo.mavlink.settings import MavlinkSettings
from mavservo.mavlink.side import MavlinkSide
from mavservo.sim.autopilot.px4_sitl import (
    COMPANION_PARAMS,
    ONBOARD_REMOTE_PORT,
    find_px4,
    onboard_link,
    telemetry_status,
    write_param_shim,
)
from tests.support.mavlink_doubles import RecordingBackend
from tests.support.paths import REPO
from tests.support.processes import stop_session
from tests.support.waiting import wait_until

PX4_CONFIG = REPO / "config" / "px4-sitl.yaml"


def _sitl(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "mavservo", "sitl", "px4", *args],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )


def _bare_env() -> dict[str, str]:
    """No PX4 anywhere: PX4_HOME unset, PATH with only the interpreter's folder."""
    env = {k: v for k, v in os.environ.items() if k != "PX4_HOME"}
    env["PATH"] = str(Path(sys.executable).parent)
    return env


def _fake_px4(tmp_path: Path) -> Path:
    """A PX4 tree whose 'binary' records its argv, working directory and environment."""
    home = tmp_path / "PX4-Autopilot"
    build = home / "build" / "px4_sitl_default"
    (build / "etc" / "init.d-posix").mkdir(parents=True)
    (build / "bin").mkdir(parents=True)
    binary = build / "bin" / "px4"
    binary.write_text(
        "#!/bin/sh\n"
        'echo "$@" > "$PWD/argv.txt"\n'
        'printf "PX4_SYS_AUTOSTART=%s\\nPX4_SIMULATOR=%s\\nPX4_SIM_MODEL=%s\\nPATH=%s\\n" '
        '"$PX4_SYS_AUTOSTART" "$PX4_SIMULATOR" "$PX4_SIM_MODEL" "$PATH" > "$PWD/env.txt"\n'
        "exit 0\n"
    )
    binary.chmod(0o755)
    return home


def test_without_a_built_px4_it_says_so_and_builds_nothing() -> None:
    done = _sitl(env=_bare_env())
    assert done.returncode == 3
    assert "not built" in done.stderr and "never builds nor downloads" in done.stderr
    dry = _sitl("--dry-run", env=_bare_env())
    assert dry.returncode == 0
    assert "PX4_SYS_AUTOSTART=10041" in dry.stdout and "-d -w" in dry.stdout
    assert "param set MNT_MODE_OUT 2" in dry.stdout


def test_it_runs_the_built_binary_headless_with_the_sih_airframe_and_the_params(
    tmp_path: Path,
) -> None:
    home = _fake_px4(tmp_path)
    work = tmp_path / "work"
    done = _sitl(
        "--px4-home",
        str(home),
        "--workdir",
        str(work),
        "--param",
        "mav_0_rate=0",
        env=_bare_env(),
    )
    assert done.returncode == 0, done.stderr
    assert f"udpin:127.0.0.1:{ONBOARD_REMOTE_PORT}" in done.stderr
    etc = home / "build" / "px4_sitl_default" / "etc"
    assert (work / "argv.txt").read_text().split() == ["-d", "-w", str(work), str(etc)]
    env = dict(
        line.split("=", 1) for line in (work / "env.txt").read_text().splitlines() if "=" in line
    )
    assert (env["PX4_SYS_AUTOSTART"], env["PX4_SIMULATOR"], env["PX4_SIM_MODEL"]) == (
        "10041",
        "sihsim",
        "sihsim_airplane",
    )
    shim_dir = work / "mavservo-rc"
    assert env["PATH"].split(os.pathsep)[0] == str(shim_dir)
    shim = (shim_dir / "px4-rc.simulator").read_text().splitlines()
    assert "param set MNT_MODE_IN 4" in shim and "param set MAV_0_RATE 0" in shim
    assert shim[-1] == '. "${R}etc/init.d-posix/px4-rc.simulator"'  # PX4's own, after
    assert find_px4(str(home)) == (home / "build" / "px4_sitl_default" / "bin" / "px4", etc)


def test_a_bad_param_is_refused_before_anything_runs(tmp_path: Path) -> None:
    done = _sitl("--param", "MNT_MODE_IN", "--px4-home", str(_fake_px4(tmp_path)))
    assert done.returncode == 2 and "bad --param" in done.stderr
    shim = write_param_shim(tmp_path, dict(COMPANION_PARAMS))
    assert shim.read_text().count("param set") == len(COMPANION_PARAMS)


# ------------------------------------------------------------------------------ live PX4 SITL

_PX4 = find_px4(os.environ.get("PX4_HOME"))
needs_px4 = pytest.mark.skipif(
    _PX4 is None,
    reason="no PX4 SITL binary ($PX4_HOME/build/px4_sitl_default/bin/px4 or px4 on PATH); "
    "tests never build or download PX4",
)


def _launch(work: Path) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [sys.executable, "-m", "mavservo", "sitl", "px4", "--workdir", str(work)],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )


def _settings() -> MavlinkSettings:
    return dataclasses.replace(mavlink_settings(load_config(PX4_CONFIG)), signing=None)


@needs_px4
@pytest.mark.timeout(180)
def test_real_px4_is_followed_as_px4(tmp_path: Path) -> None:
    """PX4 SITL with the launcher and the shipped config: the bridge learns PX4 from its
    HEARTBEAT (autopilot 12), PX4 accepts the stream requests (ACTUATOR_OUTPUT_STATUS and the
    gimbal setpoints), finds the gimbal, the outputs are mirrored from both streams, PX4 drops
    nothing the bridge sends as unknown, and SIGTERM stops PX4 cleanly."""
    backend = RecordingBackend()
    proc = _launch(tmp_path)
    try:
        with MavlinkSide(_settings(), backend) as side:

            def streams() -> dict:
                return side.stats()["stream"]["streams"]

            assert wait_until(
                lambda: side.stats()["autopilot_flavour"]["heard"] == "px4", timeout=90
            ), "no PX4 HEARTBEAT on the onboard link within 90 s"
            assert wait_until(
                lambda: streams()["ACTUATOR_OUTPUT_STATUS"]["answer"] == "accepted", timeout=20
            )
            assert wait_until(
                lambda: streams()["ACTUATOR_OUTPUT_STATUS"]["received_hz"] is not None,
                timeout=30,
            )
            time.sleep(3.0)  # the bridge's telemetry flows (ESC messages included)
            stats = side.stats()
            assert _PX4 is not None
            onboard = onboard_link(telemetry_status(_PX4[0].parent))
    finally:
        code = stop_session(proc)
    got = stats["stream"]["streams"]
    print(f"\nPX4 streams: {got}")
    assert (
        got["ACTUATOR_OUTPUT_STATUS"]["received_hz"] >= got["ACTUATOR_OUTPUT_STATUS"]["needed_hz"]
    )
    assert backend.servo_calls("servo"), "SERVO_OUTPUT_RAW never mirrored"
    assert {c[1] for c in backend.servo_calls("actuator")} >= {1}, "output 1 never mirrored"
    assert stats["autopilot_flavour"]["heard"] == "px4"
    assert onboard is not None, "no onboard MAVLink instance in PX4's telemetry_status"
    print(f"PX4's onboard link: {onboard}")
    assert int(onboard["rx_message_count"]) > 0
    # nothing the bridge sends is dropped by PX4 as unknown (ESC_TELEMETRY would be)
    assert int(onboard["rx_message_lost_count"]) == 0
    assert code == 0, f"PX4 did not stop cleanly on SIGTERM (status {code})"


def test_sitl_stream_can_be_the_simulated_px4(capsys: pytest.CaptureFixture[str]) -> None:
    """``mavservo sitl stream --autopilot px4`` runs mavservo/sim/autopilot/px4.py: PX4's
    onboard defaults (SERVO_OUTPUT_RAW 10 Hz), its HEARTBEAT, its gimbal discovery."""
    from mavservo.sim.autopilot.sitl_command import main

    code = main(
        [
            "stream",
            "--autopilot",
            "px4",
            "--gimbal",
            "--duration",
            "1.0",
            "--url",
            "udpout:127.0.0.1:9",
        ]
    )
    out = capsys.readouterr().out
    assert code == 0
    sent = ast.literal_eval(out.split("sitl: sent ", 1)[1].splitlines()[0])
    # 10 Hz for 1 s (a loaded machine sends fewer, never more: ArduPilot's 20 Hz would be ~20)
    assert 1 <= sent["SERVO_OUTPUT_RAW"] <= 12
    assert sent["COMMAND_LONG"] >= 1  # REQUEST_MESSAGE(GIMBAL_DEVICE_INFORMATION) to 0/0
