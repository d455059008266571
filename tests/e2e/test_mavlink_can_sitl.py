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
