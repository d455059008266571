"""Issue 32, finding 4: the failsafe alert is never pushed out by a flood of refusals.

A real bridge on UDP; the autopilot peer stops its HEARTBEATs while a ground station (an allowed
source) floods PARAM_SET with NaN at 50/s. On c3ae82c every refusal queued a STATUSTEXT and the
32-entry queue dropped the oldest: "autopilot lost, servos in failsafe" never arrived.
"""

from __future__ import annotations

import time
from pathlib import Path

from conftest import free_udp_port, wait_until
from e2e_support import Peer

from mavservo.app.bridge import Bridge
from mavservo.config.overlay import load_config_with_overlay
from mavservo.sim.autopilot.link import mavlink2

CONFIG = """\
mavlink:
  url: udpin:127.0.0.1:{port}
  allowed_sources: [{{system: 255, component: 190}}]
  heartbeat_timeout_s: 1.0
servos:
  - {{name: aileron, profile: rmd-x, can_id: 1, limits_deg: [-30, 30]}}
channels:
  - {{source: servo_output, channel: 1, servo: aileron}}
"""


def test_the_failsafe_text_arrives_through_a_flood_of_refusals(tmp_path: Path) -> None:
    port = free_udp_port()
    path = tmp_path / "rig.yaml"
    path.write_text(CONFIG.format(port=port))
    loaded = load_config_with_overlay(path)
    bridge = Bridge(loaded.config, config_path=path, log_dir=False).start()
    peer = Peer(port)
    try:
        peer.gcs_heartbeat()
        peer.start_heartbeats(0.2)
        assert wait_until(lambda: bridge.mavlink.stats()["core"].get("received", 0) > 2)
        start = peer.count()
        flood_start = time.monotonic()
        sent = 0
        while time.monotonic() - flood_start < 6.0 and sent < 300:
            if sent == 50:
                peer.stop_heartbeats()  # the autopilot dies one second into the flood
            peer.send(mavlink2.MAVLink_param_set_message(1, 140, b"SRV1_TRIM", float("nan"), 9))
            sent += 1
            time.sleep(max(0.0, flood_start + sent / 50 - time.monotonic()))
        assert wait_until(
            lambda: any("autopilot lost" in t for t in peer.statustexts(start)), 3.0
        ), peer.statustexts(start)
        texts = peer.statustexts(start)
        refusals = [t for t in texts if "refus" in t]
        # one text per sender per second, with a count: ~7 for the 6 s flood, not 300
        assert 1 <= len(refusals) <= 2 * 8, refusals
        assert any("more parameter refusals from 255/190" in t for t in texts), texts
    finally:
        peer.close()
        bridge.stop()
