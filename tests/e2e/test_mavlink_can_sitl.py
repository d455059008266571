"""Live: servos on ArduPlane SITL's own CAN port through MAVLink (``mavlink-can``).

Skipped unless an ArduPlane SITL binary is built (``$ARDUPILOT_HOME/build/sitl/bin/arduplane``
or ``arduplane`` on PATH) and this process may make a network namespace (``unshare -n``, root):
SITL listens on 0.0.0.0 and sends multicast, so everything runs in a namespace with loopback
only. Runs ``bench/bench_mavlink_can_sitl.py`` briefly (its figures: docs/engineering/
mavlink-can.md) and checks what must hold whatever the machine's load: no reply lost through
the autopilot, the restart seen as an outage and recovered from.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def arduplane() -> str | None:
    home = os.environ.get("ARDUPILOT_HOME")
    if home and os.access(Path(home) / "build/sitl/bin/arduplane", os.X_OK):
        return str(Path(home) / "build/sitl/bin/arduplane")
    return shutil.which("arduplane")


def can_unshare() -> bool:
    if shutil.which("unshare") is None or shutil.which("ip") is None:
        return False
    return subprocess.run(["unshare", "-n", "true"], capture_output=True).returncode == 0


BINARY = arduplane()
pytestmark = pytest.mark.skipif(
    BINARY is None or not can_unshare(),
    reason="needs a built ArduPlane SITL and `unshare -n` (root)",
)


def test_four_rmd_x_through_arduplane_sitl_lose_nothing_and_survive_its_restart() -> None:
    script = (
        "ip link set lo up && ip link set lo multicast on && "
        "ip route add 239.0.0.0/8 dev lo && "
        f"exec {sys.executable} {REPO / 'bench/bench_mavlink_can_sitl.py'} "
        f"--arduplane {BINARY} --seconds 15 --restart-at 5 --down-s 2 --restart-run-s 30"
    )
    done = subprocess.run(
        ["unshare", "-n", "sh", "-c", script], capture_output=True, text=True, timeout=240
    )
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout)
    tunnel, baseline = result["mavlink_can"], result["aa55"]
    assert tunnel["frames_sent"] > 0 and baseline["frames_sent"] > 0
    assert tunnel["lost"] == 0, tunnel
    restart = result["restart"]
    assert restart["outage_detected_after_kill_s"] is not None, restart
    assert restart["bus_back_after_relaunch_s"] is not None, restart
    assert restart["servos_online_after_relaunch_s"] is not None, restart
    said = [e for e in restart["events"] if e.startswith("fc: ")]  # in the port's own words
    assert any(e.startswith("fc: the autopilot stopped forwarding CAN bus 1") for e in said), said
    assert any(e.startswith("fc: the autopilot's CAN port is back after") for e in said), said


def ap_periph() -> str | None:
    """An AP_Periph SITL binary (``$AP_PERIPH`` or ``AP_Periph`` on PATH): another DroneCAN
    node on the vehicle's multicast CAN, so the port carries DroneCAN traffic."""
    path = os.environ.get("AP_PERIPH") or shutil.which("AP_Periph")
    return path if path and os.access(path, os.X_OK) else None


def tunnel_run(*extra: str) -> dict:
    script = (
        "ip link set lo up && ip link set lo multicast on && "
        "ip route add 239.0.0.0/8 dev lo && "
        f"exec {sys.executable} {REPO / 'bench/bench_mavlink_can_sitl.py'} "
        f"--arduplane {BINARY} --tunnel-only --seconds 15 " + " ".join(extra)
    )
    done = subprocess.run(
        ["unshare", "-n", "sh", "-c", script], capture_output=True, text=True, timeout=240
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout)


@pytest.mark.skipif(ap_periph() is None, reason="needs an AP_Periph SITL binary ($AP_PERIPH)")
def test_the_autopilots_filter_keeps_the_servo_replies_and_drops_its_dronecan() -> None:
    """CAN_FILTER_MODIFY (on by default for an 11-bit-only bus) with ArduPlane's and an
    AP_Periph's DroneCAN on the port: every servo reply still forwarded, the DroneCAN frames
    no longer; without the filter they come along (the link carries them)."""
    periph = f"--periph {ap_periph()}"
    filtered = tunnel_run(periph)
    unfiltered = tunnel_run(periph, "--no-autopilot-filter")
    for run in (filtered, unfiltered):
        assert run["mavlink_can"]["frames_sent"] > 0 and run["mavlink_can"]["lost"] == 0, run
    assert unfiltered["link_frames_per_s"]["of_them_29_bit"] > 10, unfiltered
    assert filtered["mavlink_can"]["transport"]["ignored"] == 0, filtered
