"""ArduPlane SITL scripts: the launcher's command line, and a live run when ArduPilot is here.

The live test needs ``sim_vehicle.py`` or ``arduplane`` (PATH or $ARDUPILOT_HOME); without them it
is skipped with that reason. Nothing is ever downloaded. Run it on loopback only (SITL's
listeners bind every address) in a network namespace that has only ``lo``::

    ARDUPILOT_HOME=/path/to/ardupilot unshare -n sh -c \
        'ip link set lo up && python -m pytest -s tests/sim/test_ardupilot_launcher.py'
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest

from mavservo.config.loader import load_config
from mavservo.config.views import mavlink_settings
from mavservo.mavlink.connection import mavlink2 as mav
from mavservo.mavlink.settings import MavlinkSettings
from mavservo.mavlink.side import MavlinkSide
from mavservo.mavlink.stream_request import WINDOW_S
from tests.support.autopilot import collect, of_type, peer
from tests.support.mavlink_doubles import RecordingBackend
from tests.support.paths import REPO
from tests.support.processes import stop_session
from tests.support.waiting import free_udp_port, wait_until

AUTOPILOT = REPO / "mavservo" / "sim" / "autopilot"  # the simulator and its ArduPilot files
SCRIPT = AUTOPILOT / "run-arduplane.sh"
SITL_CONFIG = REPO / "config" / "ardupilot-sitl.yaml"


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
    # stream rates stay at ArduPilot's defaults: the bridge asks for its own (issue 17)
    assert not [n for n in companion if n.startswith(("SR", "MAV"))]
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
    assert "not built" in done.stderr and "never" in done.stderr
    assert done.stdout == ""


def test_dry_run_without_ardupilot_shows_the_command_to_use_once_it_is_installed(
    tmp_path: Path,
) -> None:
    # docs/engineering/sitl.md: "--dry-run  # the SITL command it would run", built or not
    done = subprocess.run(
        ["bash", str(SCRIPT), "--dry-run", "--gimbal", "--port", "14600", "--", "--console"],
        env=_bare_env(tmp_path, False),
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert done.returncode == 0, done.stderr
    assert "not built" in done.stderr
    words = done.stdout.split()
    assert words[0] == "ARDUPILOT_HOME/build/sitl/bin/arduplane"  # never sim_vehicle.py
    assert words[words.index("--serial1") + 1] == "udpclient:127.0.0.1:14600"
    defaults = words[words.index("--defaults") + 1].replace("\\,", ",").split(",")
    assert defaults == [
        str(AUTOPILOT / "arduplane-companion.parm"),
        str(AUTOPILOT / "arduplane-gimbal.parm"),
    ]
    assert words[-2:] == ["-w", "--console"]


def test_sim_vehicle_on_path_only_finds_its_trees_binary_and_is_never_run(tmp_path: Path) -> None:
    """ArduPilot's docs put Tools/autotest on PATH; sim_vehicle.py there rebuilds the tree and
    fetches submodules. The launcher takes the tree's built binary instead, or says it is not
    built, and never runs sim_vehicle.py."""
    home = tmp_path / "ardupilot"
    autotest = home / "Tools" / "autotest"
    (autotest / "models").mkdir(parents=True)
    (autotest / "models" / "plane.parm").write_text("ARSPD_USE 1\n")
    marker = tmp_path / "sim_vehicle-ran"
    (autotest / "sim_vehicle.py").write_text(f"#!/bin/sh\ntouch {marker}\nexit 1\n")
    (autotest / "sim_vehicle.py").chmod(0o755)
    env = _bare_env(tmp_path, False)
    env["PATH"] = f"{autotest}:{env['PATH']}"
    unbuilt = subprocess.run(
        ["bash", str(SCRIPT)], env=env, capture_output=True, text=True, timeout=30
    )
    assert unbuilt.returncode == 3 and f"no build/sitl/bin/arduplane in {home}" in unbuilt.stderr
    (home / "build" / "sitl" / "bin").mkdir(parents=True)
    fake = home / "build" / "sitl" / "bin" / "arduplane"
    fake.write_text("#!/bin/sh\nexit 0\n")
    fake.chmod(0o755)
    done = subprocess.run(
        ["bash", str(SCRIPT), "--dry-run"], env=env, capture_output=True, text=True, timeout=30
    )
    assert done.returncode == 0, done.stderr
    words = done.stdout.split()
    assert words[0] == str(fake)
    assert words[words.index("--defaults") + 1].replace("\\,", ",").split(",")[0] == str(
        autotest / "models" / "plane.parm"
    )
    ran = subprocess.run(["bash", str(SCRIPT)], env=env, capture_output=True, timeout=30)
    assert ran.returncode == 0
    assert not marker.exists()


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


def test_launcher_dry_run_takes_the_plane_defaults_of_the_binarys_tree_and_does_not_wait_for_a_gcs(
    tmp_path: Path,
) -> None:
    """A dry run with a stand-in binary: only the command line is checked (SERIAL0 listens
    without ``:wait`` unless --wait-gcs). That SITL really boots without a GCS is
    test_real_arduplane_boots_without_a_gcs."""
    # a current ArduPilot tree: defaults in Tools/autotest/models/, binary in build/sitl/bin/
    home = tmp_path / "ardupilot"
    (home / "Tools" / "autotest" / "models").mkdir(parents=True)
    (home / "Tools" / "autotest" / "models" / "plane.parm").write_text("ARSPD_USE 1\n")
    (home / "build" / "sitl" / "bin").mkdir(parents=True)
    fake = home / "build" / "sitl" / "bin" / "arduplane"
    fake.write_text("#!/bin/sh\nexit 0\n")
    fake.chmod(0o755)
    env = _bare_env(tmp_path, False)
    for with_home in (True, False):  # ARDUPILOT_HOME, or the binary on PATH in its tree
        run_env = (
            dict(env, ARDUPILOT_HOME=str(home))
            if with_home
            else dict(env, PATH=f"{fake.parent}:{env['PATH']}")
        )
        done = subprocess.run(
            ["bash", str(SCRIPT), "--dry-run"],
            env=run_env,
            capture_output=True,
            text=True,
            timeout=30,
        )
        assert done.returncode == 0, done.stderr
        words = done.stdout.split()
        assert words[0] == str(fake)
        defaults = words[words.index("--defaults") + 1].replace("\\,", ",").split(",")
        assert defaults == [
            str(home / "Tools" / "autotest" / "models" / "plane.parm"),
            str(AUTOPILOT / "arduplane-companion.parm"),
        ]
        assert words[words.index("--serial0") + 1] == "tcp:0"  # listens, does not wait
    waiting = subprocess.run(
        ["bash", str(SCRIPT), "--dry-run", "--wait-gcs"],
        env=dict(env, ARDUPILOT_HOME=str(home)),
        capture_output=True,
        text=True,
        timeout=30,
    )
    words = waiting.stdout.split()
    assert words[words.index("--serial0") + 1] == "tcp:0:wait"


def _find_arduplane_binary() -> str | None:
    """The ArduPlane SITL binary the launcher would run itself (not sim_vehicle.py)."""
    home = os.environ.get("ARDUPILOT_HOME")
    if home and (Path(home) / "build" / "sitl" / "bin" / "arduplane").exists():
        return str(Path(home) / "build" / "sitl" / "bin" / "arduplane")
    return shutil.which("arduplane")


def _find_ardupilot() -> str | None:
    return _find_arduplane_binary() or shutil.which("sim_vehicle.py")


def _without_sim_vehicle() -> dict[str, str]:
    """This environment with no sim_vehicle.py on PATH: the launcher then runs the binary
    itself (sim_vehicle.py would start MAVProxy, a GCS, on SERIAL0)."""
    dirs = os.environ.get("PATH", "").split(os.pathsep)
    kept = [d for d in dirs if not (Path(d or ".") / "sim_vehicle.py").exists()]
    return dict(os.environ, PATH=os.pathsep.join(kept))


@pytest.mark.skipif(
    _find_arduplane_binary() is None,
    reason="no ArduPlane SITL binary (arduplane on PATH or $ARDUPILOT_HOME/build/sitl/bin/"
    "arduplane); tests never build or download ArduPilot",
)
@pytest.mark.timeout(150)
def test_real_arduplane_boots_without_a_gcs(tmp_path: Path) -> None:
    """The real binary, started by the launcher with nobody on SERIAL0 (its GCS port): it
    boots and its SERIAL1 sends the companion ArduPilot heartbeats and SERVO_OUTPUT_RAW; SIGTERM
    then stops it cleanly. With ``tcp:0:wait`` it would wait for a GCS and send nothing."""
    port = free_udp_port()
    conn = peer(port)
    proc = _launch(tmp_path, port, env=_without_sim_vehicle())
    try:
        boot = collect(conn, 90.0, until=lambda m: m.get_type() == "SERVO_OUTPUT_RAW")
    finally:
        conn.close()
        code = stop_session(proc)
    assert of_type(boot, "SERVO_OUTPUT_RAW"), "SITL sent no SERVO_OUTPUT_RAW within 90 s"
    heartbeats = of_type(boot, "HEARTBEAT")
    assert heartbeats and heartbeats[0].autopilot == mav.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert code == 0, f"SITL did not stop cleanly on SIGTERM (status {code})"


@pytest.mark.skipif(
    _find_ardupilot() is None,
    reason="ArduPilot SITL not installed (no arduplane / sim_vehicle.py on PATH, "
    "no $ARDUPILOT_HOME build); tests never download it",
)
@pytest.mark.timeout(240)
def test_real_arduplane_streams_servo_outputs_and_obeys_do_set_servo(tmp_path: Path) -> None:
    """Boots the real ArduPlane with the launcher (no GCS), reads its SERIAL1 as it comes (the
    parameter files leave the stream rates at ArduPilot's defaults), then runs the bridge's
    MAVLink side with the shipped SITL config: its own SET_MESSAGE_INTERVAL must bring
    SERVO_OUTPUT_RAW to the configured rate. SIGTERM must stop SITL cleanly."""
    port = free_udp_port()
    conn = peer(port)
    started = time.monotonic()
    proc = _launch(tmp_path, port)
    try:
        boot = collect(conn, 90.0, until=lambda m: m.get_type() == "SERVO_OUTPUT_RAW")
        assert of_type(boot, "SERVO_OUTPUT_RAW"), "no SERVO_OUTPUT_RAW from SITL within 90 s"
        booted_s = time.monotonic() - started
        hb = of_type(boot, "HEARTBEAT")[0]
        assert hb.autopilot == mav.MAV_AUTOPILOT_ARDUPILOTMEGA
        unasked = collect(conn, 2 * WINDOW_S)
        unasked_hz = len(of_type(unasked, "SERVO_OUTPUT_RAW")) / (2 * WINDOW_S)
        conn.mav.command_long_send(1, 1, mav.MAV_CMD_DO_SET_SERVO, 0, 9, 1234, 0, 0, 0, 0, 0)
        after = collect(
            conn, 10.0, until=lambda m: m.get_type() == "SERVO_OUTPUT_RAW" and m.servo9_raw == 1234
        )
        assert of_type(after, "SERVO_OUTPUT_RAW")[-1].servo9_raw == 1234
        conn.close()

        settings = _bridge_settings(port)
        wanted = settings.stream_request.rates_hz["SERVO_OUTPUT_RAW"]
        needed = settings.stream_request.min_hz["SERVO_OUTPUT_RAW"]
        with MavlinkSide(settings, RecordingBackend()) as side:
            figures = lambda: side.stats()["stream"]["streams"]["SERVO_OUTPUT_RAW"]  # noqa: E731
            assert wait_until(lambda: figures()["answer"] == "accepted", timeout=20)
            assert wait_until(lambda: figures()["received_hz"] is not None, timeout=30)
            asked = figures()
        print(
            f"\nSITL boot to first SERVO_OUTPUT_RAW: {booted_s:.1f} s; SERVO_OUTPUT_RAW unasked "
            f"{unasked_hz:.1f} Hz; bridge asked {wanted:g} Hz ({asked['answer']}), received "
            f"{asked['received_hz']} Hz over {WINDOW_S:g} s"
        )
        assert unasked_hz < needed, "the default stream already fast: the test shows nothing"
        assert asked["received_hz"] >= needed
    finally:
        conn.close()
        code = stop_session(proc)
    assert code == 0, f"SITL did not stop cleanly on SIGTERM (status {code})"


@pytest.mark.skipif(
    _find_arduplane_binary() is None,
    reason="no ArduPlane SITL binary (arduplane on PATH or $ARDUPILOT_HOME/build/sitl/bin/"
    "arduplane); tests never build or download ArduPilot",
)
@pytest.mark.timeout(240)
def test_a_gcs_behind_real_arduplane_gets_what_the_docs_say(tmp_path: Path) -> None:
    """docs/ground-stations.md, "through ArduPilot": the bridge (config/ardupilot-sitl.yaml, the
    default link budget) on SERIAL1, a ground station on SERIAL0 (TCP 5760). The ground station
    sees the bridge's components and telemetry, reads a parameter of component 140, and
    downloads both metadata files over MAVLink FTP with QGroundControl's time-out and retries
    (issue 38: through ArduPlane general.json took 3-4 s and parameters.json.xz never came);
    ESC_INFO, ESC_STATUS and COMPONENT_METADATA never arrive (ArduPilot drops ids it does not
    know)."""
    from mavservo.app.bridge import Bridge
    from mavservo.config import load_config_text
    from mavservo.mavlink.ftp import crc32
    from tests.support.qgc_ftp import QgcLikeFtp

    port = free_udp_port()
    text = SITL_CONFIG.read_text().replace("udpin:127.0.0.1:14551", f"udpin:127.0.0.1:{port}")
    bridge = Bridge(load_config_text(text, "<ardupilot-sitl.yaml>"), log_dir=False).start()
    proc = _launch(tmp_path, port, env=_without_sim_vehicle())
    gcs = None
    try:
        gcs = _serial0(90.0)
        gcs.mav.heartbeat_send(6, 8, 0, 0, 0)
        seen = collect(gcs, 10.0)
        sources = {(m.get_srcSystem(), m.get_srcComponent()) for _, m in seen}
        assert (1, 140) in sources, sorted(sources)
        from_bridge = {m.get_type() for _, m in seen if m.get_srcComponent() == 140}
        assert {"HEARTBEAT", "NAMED_VALUE_FLOAT", "ACTUATOR_OUTPUT_STATUS"} <= from_bridge
        # Mission Planner's ESC view: ArduPilot forwards the bridge's ESC_TELEMETRY (ESC 17..)
        assert any(kind.startswith("ESC_TELEMETRY_") for kind in from_bridge), from_bridge
        unknown = {m.get_type() for _, m in seen if m.get_type().startswith("UNKNOWN_")}
        assert not unknown & {"UNKNOWN_290", "UNKNOWN_291", "UNKNOWN_397"}, unknown

        assert bridge.parameters is not None
        name = bridge.parameters.names(140)[0]
        gcs.mav.param_request_read_send(1, 140, name.encode(), -1)
        reply = collect(
            gcs, 10.0, until=lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == name
        )
        assert of_type(reply, "PARAM_VALUE"), f"no PARAM_VALUE for {name} through ArduPilot"

        served = bridge.mavlink.core.metadata.servers[140].files
        client = QgcLikeFtp(gcs, (1, 140))
        for file in ("general.json", "parameters.json.xz"):
            got = client.download(f"/{file}")
            assert got.data == served[file] and crc32(got.data) == crc32(served[file])
            print(
                f"\n{file}: {len(got.data)} B in {got.seconds:.1f} s through ArduPlane, "
                f"longest wait {max(got.waits):.2f} s, {got.retries} retries"
            )

        gcs.mav.command_long_send(1, 140, 512, 0, 397, 0, 0, 0, 0, 0, 0)
        after = collect(gcs, 3.0)
        assert not [m for _, m in after if m.get_type() == "UNKNOWN_397"]
    finally:
        if gcs is not None:
            gcs.close()
        code = stop_session(proc)
        bridge.stop()
    assert code == 0, f"SITL did not stop cleanly on SIGTERM (status {code})"


def _serial0(timeout: float) -> Any:
    """A ground station on SITL's SERIAL0 (TCP 5760), once SITL listens there."""
    from mavservo.mavlink.connection import open_connection

    deadline = time.monotonic() + timeout
    while True:
        try:
            return open_connection("tcp:127.0.0.1:5760", source_system=255, source_component=190)
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)


def _launch(tmp_path: Path, port: int, env: dict[str, str] | None = None) -> subprocess.Popen:
    """The launcher, SERIAL1 to ``port``, nobody on SERIAL0; its own session, so stop_session ends
    SITL with it."""
    return subprocess.Popen(
        ["bash", str(SCRIPT), "--port", str(port)],
        cwd=tmp_path,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        start_new_session=True,
    )


def _bridge_settings(port: int) -> MavlinkSettings:
    """The MAVLink settings of config/ardupilot-sitl.yaml, on this test's port."""
    cfg = load_config(SITL_CONFIG)
    settings = mavlink_settings(cfg)
    return dataclasses.replace(settings, url=f"udpin:127.0.0.1:{port}", signing=None)
