"""The built-in simulated autopilot never drives a real bus (issue 37, the safety blocker).

A hardware config that lost its ``mavlink.url`` ran on the simulated autopilot, which swept
the real servos +-25 deg while ``check`` called the file valid. Here the "hardware" is the
AA-55 adapter emulator on a pty (to the bridge, a serial device like any USB adapter), and the
emulator counts every byte the host sends: a refused config must leave it at zero (not even
the adapter's settings frame), while the same config with an autopilot link does reach the
servos (so the rig can tell the difference).
"""

from __future__ import annotations

import io
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from mavservo.app.bridge import Bridge
from mavservo.app.check import check_main
from mavservo.config import SimulatedAutopilotError, load_config_text
from mavservo.sim.adapter import AdapterEmulator
from mavservo.sim.servo import SimServo
from tests.support.paths import REPO

SERVOS = "servos:\n  - {name: aileron, profile: rmd-x, can_id: 1, limits_deg: [-30, 30]}\n"


@pytest.fixture
def adapter() -> Iterator[AdapterEmulator]:
    emulator = AdapterEmulator([SimServo("rmd-x", 1)]).start()
    try:
        yield emulator
    finally:
        emulator.stop()


def _mavservo(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "mavservo", *args],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=REPO,
    )


def _check(path: Path) -> tuple[int, str]:
    out, err = io.StringIO(), io.StringIO()
    return check_main([str(path)], out=out, err=err), err.getvalue()


def _untouched(adapter: AdapterEmulator) -> bool:
    """Nothing reached the adapter: no settings frame, no CAN frame, the servo where it was."""
    [servo] = adapter.servos
    return (
        adapter.settings_received == 0
        and adapter.frames_from_host == 0
        and servo.target_deg == servo.physics.initial_position_deg
    )


@pytest.mark.parametrize("mavlink", ["", "mavlink: {heartbeat_timeout_s: 2}\n"])
def test_a_hardware_config_without_mavlink_url_is_refused_and_nothing_moves(
    tmp_path: Path, adapter: AdapterEmulator, mavlink: str
) -> None:
    config = tmp_path / "hw.yaml"
    config.write_text(
        mavlink + f"can:\n  buses:\n    - {{name: bus0, channel: '{adapter.path}'}}\n" + SERVOS
    )
    bus_line = 4 if mavlink else 3
    status, err = _check(config)
    assert status == 2
    assert f"{config}:{bus_line}: can.buses[0].channel: mavlink.url is not set" in err
    assert "simulated autopilot" in err and "url: /dev/serial0" in err and "udpin:" in err
    proc = _mavservo("run", str(config), "--duration", "2", "--no-log")
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert f"{config}:{bus_line}: can.buses[0].channel: mavlink.url is not set" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert _untouched(adapter)


def test_an_explicit_sim_url_on_a_real_bus_is_refused_at_its_line(
    tmp_path: Path, adapter: AdapterEmulator
) -> None:
    config = tmp_path / "copied.yaml"  # a shipped example with only the channel changed
    config.write_text(
        "mavlink:\n  url: sim\n"
        f"can:\n  buses:\n    - {{name: bus0, interface: aa55, channel: '{adapter.path}'}}\n"
        + SERVOS
    )
    status, err = _check(config)
    assert status == 2 and f"{config}:2: mavlink.url: mavlink.url is 'sim'" in err
    proc = _mavservo("run", str(config), "--duration", "2", "--no-log")
    assert proc.returncode == 2 and f"{config}:2: mavlink.url" in proc.stderr
    assert _untouched(adapter)


def test_port_on_the_built_in_simulation_is_refused(adapter: AdapterEmulator) -> None:
    """``mavservo run --port DEVICE``: the built-in config's simulated autopilot on a device."""
    proc = _mavservo("run", "--port", adapter.path, "--duration", "2", "--no-log")
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert f"from --port {adapter.path}" in proc.stderr and "--mavlink URL" in proc.stderr
    assert _untouched(adapter)


def test_the_same_bus_with_an_autopilot_link_does_reach_the_servo(
    tmp_path: Path, adapter: AdapterEmulator
) -> None:
    """The control: given a link (nobody on it), the bridge opens the adapter and talks to the
    servo, so the zero counts above are the refusal, not a rig that cannot see frames."""
    config = tmp_path / "hw.yaml"
    config.write_text(f"can:\n  buses:\n    - {{name: bus0, channel: '{adapter.path}'}}\n" + SERVOS)
    proc = _mavservo(
        "run", str(config), "--mavlink", "udpin:127.0.0.1:0", "--duration", "1", "--no-log", "-q"
    )
    assert proc.returncode == 0, proc.stderr
    assert adapter.settings_received >= 1 and adapter.frames_from_host > 0


def test_the_bridge_itself_refuses_a_config_built_past_the_checks(
    adapter: AdapterEmulator,
) -> None:
    """A program that builds its config without ``check``/``run`` meets the same rule."""
    config = load_config_text(
        f"can:\n  buses:\n    - {{name: bus0, channel: '{adapter.path}'}}\n" + SERVOS
    )
    bridge = Bridge(config, log_dir=False)
    with pytest.raises(SimulatedAutopilotError, match="simulated autopilot"):
        bridge.start()
    assert bridge.autopilot_sim is None
    assert _untouched(adapter)
