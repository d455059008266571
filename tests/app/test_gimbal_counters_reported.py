"""The gimbal's counters (``bad_value`` above all) reach the end-of-run summary, the console and
``metrics.json`` like the other MAVLink counters, in a real run: a bridge with a gimbal on the
adapter emulator, a GCS over UDP on 127.0.0.1 sending hostile DO_MOUNT_CONTROL angles.

Why: the gimbal DENIED and counted hostile values in ``GimbalCounters.bad_value``, but that
count stayed inside the device; the run's record showed nothing of the attack.
"""

from __future__ import annotations

import json
from pathlib import Path

from mavservo.app.bridge import Bridge
from mavservo.app.console import format_summary
from tests.support.bridge import Peer, bridge_config
from tests.support.waiting import free_udp_port

MAV_CMD_DO_MOUNT_CONTROL = 205
MAV_MOUNT_MODE_MAVLINK_TARGETING = 2
MAV_RESULT_DENIED = 2
GIMBAL = """
  heartbeat_timeout_s: 60
servos:
  - {name: gimbal_pitch, profile: rmd-x, can_id: 2, limits_deg: [-90, 30], telemetry_hz: 10}
gimbals:
  - name: gimbal
    component_id: 154
    pitch: gimbal_pitch
    limits_deg: {pitch: [-90, 30]}
"""
HOSTILE_PITCHES = (1e9, -3.4e38, 361.0)


def test_gimbal_bad_value_reaches_the_summary_the_console_and_metrics_json(
    tmp_path: Path,
) -> None:
    bridge = Bridge(bridge_config(GIMBAL, free_udp_port()), log_dir=tmp_path).start()
    port = int(bridge.config.mavlink.url.rsplit(":", 1)[1])
    peer = Peer(port)
    try:
        for pitch in HOSTILE_PITCHES:
            params = [pitch, 0.0, 0.0, 0.0, 0.0, 0.0, MAV_MOUNT_MODE_MAVLINK_TARGETING]
            result = peer.command(MAV_CMD_DO_MOUNT_CONTROL, params, target=(1, 154))
            assert result == MAV_RESULT_DENIED
    finally:
        peer.close()
        summary = bridge.stop()
    assert summary["mavlink"]["gimbals"]["154"]["bad_value"] == len(HOSTILE_PITCHES)
    assert f"gimbals.154.bad_value {len(HOSTILE_PITCHES)}" in format_summary(summary)
    metrics = json.loads((Path(summary["run_dir"]) / "metrics.json").read_text())
    assert metrics["mavlink"]["gimbals"]["154"]["bad_value"] == len(HOSTILE_PITCHES)
    assert metrics["mavlink"]["commands"]["result_denied"] == len(HOSTILE_PITCHES)
