"""`mavservo monitor` attached to a running bridge (not a stand-in sender), in a pseudo-terminal."""

from __future__ import annotations

import os
import pty
import re
import select
import subprocess
import sys
import time
from pathlib import Path

from mavservo.app.bridge import Bridge, free_udp_port
from mavservo.config import load_config
from tests.support.paths import REPO

CONFIG = """
mavlink:
  url: sim
  monitor_outputs: ["udpout:127.0.0.1:{port}"]
can: {{buses: [{{name: bus0, interface: aa55, channel: sim}}]}}
servos:
  - {{name: aileron, profile: rmd-x, can_id: 1, limits_deg: [-30, 30], telemetry_hz: 10}}
  - {{name: cam_pitch, profile: cubemars-ak, can_id: 2, limits_deg: [-90, 30], telemetry_hz: 20}}
channels:
  - {{servo: aileron, source: servo_output, channel: 1, output_deg: [-30, 30]}}
gimbals:
  - {{name: cam, pitch: cam_pitch}}
simulation: {{autopilot: {{profile: sweep, gimbal: true}}}}
"""


def test_monitor_shows_a_running_bridges_servos_in_a_terminal(tmp_path: Path) -> None:
    port = free_udp_port()
    path = tmp_path / "bridge.yaml"
    path.write_text(CONFIG.format(port=port))
    bridge = Bridge(load_config(path), log_dir=False, status=lambda line: None).start()
    master, slave = pty.openpty()
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "mavservo",
            "monitor",
            f"udpin:127.0.0.1:{port}",
            "--duration",
            "4",
            "--config",
            str(path),
        ],
        stdin=slave,
        stdout=slave,
        stderr=subprocess.PIPE,
        cwd=REPO,
        env={**os.environ, "COLUMNS": "160", "LINES": "40", "TERM": "xterm"},
    )
    os.close(slave)
    chunks: list[bytes] = []
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            ready, _, _ = select.select([master], [], [], 0.2)
            if ready:
                try:
                    data = os.read(master, 65536)
                except OSError:  # the monitor exited and closed its side
                    break
                if not data:
                    break
                chunks.append(data)
            elif proc.poll() is not None:
                break
        rc = proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
        os.close(master)
        bridge.stop()
    screen = b"".join(chunks).decode(errors="replace")
    assert rc == 0, proc.stderr.read().decode() if proc.stderr else ""
    assert "\x1b[" in screen  # a live terminal dashboard
    assert "aileron" in screen and "cam_pitch" in screen  # names from the bridge's config
    assert "154" in screen  # the gimbal component's heartbeat is listed


def test_monitor_plain_lines_carry_the_bridges_values(tmp_path: Path) -> None:
    port = free_udp_port()
    path = tmp_path / "bridge.yaml"
    path.write_text(CONFIG.format(port=port))
    bridge = Bridge(load_config(path), log_dir=False, status=lambda line: None).start()
    try:
        proc = subprocess.run(
            [
                sys.executable,
                "-m",
                "mavservo",
                "monitor",
                f"udpin:127.0.0.1:{port}",
                "--duration",
                "4",
                "--plain",
                "--config",
                str(path),
            ],
            capture_output=True,
            text=True,
            timeout=30,
            cwd=REPO,
        )
    finally:
        bridge.stop()
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    # setpoint and measured position of the mirrored surface, as numbers
    assert any(
        re.search(r"name=aileron setpoint=[-+]\d+\.\d+ position=[-+]\d+\.\d+", ln) for ln in lines
    ), proc.stdout[-2000:]
    # exactly the configured servos: empty ESC_TELEMETRY slots do not become phantom rows
    assert not any("servo=3 " in ln for ln in lines)
    # the wire round trip L comes from the bridge's schedulers, labelled as such (this bridge
    # keeps no run log, so there is no cmd->telemetry figure to show)
    assert any(
        re.search(r"round trip L p50 \d+\.\d\dms p95 \d+\.\d\dms p99 \d+\.\d\dms", ln)
        for ln in lines
    ), proc.stdout[-2000:]
    assert not any("cmd->telemetry" in ln for ln in lines)


SIGNED = """
mavlink:
  url: "udpin:127.0.0.1:{port}"
  signing: {{key: "{key}"}}
  link_budget_bytes_s: 20000  # the servo's values within the monitor's 4 s, whatever the load
servos:
  - {{name: aileron, profile: rmd-x, can_id: 1, limits_deg: [-30, 30], telemetry_hz: 10}}
"""


def _monitors_lines(url: str, *option_sets: tuple[str, ...]) -> list[list[str]]:
    """The plain lines of one ``mavservo monitor URL --duration 4 --plain OPTIONS`` per option
    set, all running side by side (each a peer of its own: its own UDP port, its own signing or
    none), so the bridge serves them at once, as it serves several ground stations."""
    procs = [
        subprocess.Popen(
            [sys.executable, "-m", "mavservo", "monitor", url, "--duration", "4", "--plain"]
            + list(options),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            cwd=REPO,
        )
        for options in option_sets
    ]
    outputs = []
    try:
        for proc in procs:
            out, err = proc.communicate(timeout=30)
            assert proc.returncode == 0, err
            outputs.append(out.splitlines())
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait(10)
    return outputs


def test_monitor_signs_with_a_signed_configs_key_and_the_bridge_answers_it(
    tmp_path: Path,
) -> None:
    """A signing bridge answers only peers whose messages verify: the monitor takes the key
    from the bridge's config (or --signing-key-file) and so sees the servos on the bridge's own
    link; unsigned, it sees nothing."""
    port = free_udp_port()
    key = "5a" * 32
    path = tmp_path / "signed.yaml"
    path.write_text(SIGNED.format(port=port, key=key))
    key_file = tmp_path / "signing.key"
    key_file.write_text(key)
    url = f"udpout:127.0.0.1:{port}"
    values = re.compile(r"name=aileron setpoint=\S+ position=[-+]\d+\.\d+")
    bridge = Bridge(load_config(path), log_dir=False, status=lambda line: None).start()
    try:
        signed, by_file, unsigned = _monitors_lines(
            url, ("--config", str(path)), ("--signing-key-file", str(key_file)), ()
        )
    finally:
        bridge.stop()
    assert any(values.search(line) for line in signed), "\n".join(signed[-20:])
    assert any("position=" in line and "servo=1 " in line for line in by_file), by_file[-20:]
    assert not any("position=" in line for line in unsigned)
