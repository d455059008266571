"""Issue 32, findings 2 and 4: a PARAM_SET flood must not stall the MAVLink side nor push the
failsafe alert out.

A real bridge on UDP, an autopilot peer sending HEARTBEATs, and a ground station (an allowed
source: the sets are accepted ones) flooding PARAM_SET at 200/s while every fsync takes 20 ms
more (a slow SD card, emulated). On c3ae82c each set was written and fsynced twice under the
MAVLink lock: the heartbeats queued behind and the bridge declared the healthy autopilot lost.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

from mavservo.app.bridge import Bridge
from mavservo.config.overlay import load_config_with_overlay, overlay_path
from mavservo.mavlink.connection import mavlink2
from tests.support.bridge import Peer
from tests.support.waiting import free_udp_port, wait_until

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
FLOOD_HZ = 200
FLOOD_S = 3.0
SLOW_FSYNC_S = 0.02


def test_a_set_flood_with_slow_fsync_keeps_the_autopilot_link_and_coalesces_writes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    port = free_udp_port()
    path = tmp_path / "rig.yaml"
    path.write_text(CONFIG.format(port=port))
    real_fsync = os.fsync
    fsyncs: list[float] = []

    def slow_fsync(fd: int) -> None:
        fsyncs.append(time.monotonic())
        time.sleep(SLOW_FSYNC_S)
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", slow_fsync)
    loaded = load_config_with_overlay(path)
    bridge = Bridge(
        loaded.config, config_path=path, log_dir=False, parameter_base=loaded.base
    ).start()
    peer = Peer(port)
    try:
        peer.start_heartbeats(0.2)
        assert wait_until(lambda: bridge.mavlink.stats()["core"].get("received", 0) > 2)
        start = time.monotonic()
        sent = 0
        while time.monotonic() - start < FLOOD_S and sent < FLOOD_HZ * FLOOD_S:
            value = float(1 + sent % 10)
            peer.send(mavlink2.MAVLink_param_set_message(1, 140, b"SRV1_TRIM", value, 9))
            sent += 1
            time.sleep(max(0.0, start + sent / FLOOD_HZ - time.monotonic()))
        time.sleep(1.5)  # the last write, and room for a late failsafe to show
        stats = bridge.mavlink.stats()
        assert stats["failsafe_count"] == 0, stats
        assert stats["parameters"].get("set_accepted", 0) >= 1
        assert stats["parameters"].get("set_rate_limited", 0) > 0
        flood_fsyncs = [t for t in fsyncs if t >= start]
        # one write a second at most (each write: the file and its directory)
        assert len(flood_fsyncs) <= 2 * (FLOOD_S + 2.5), len(flood_fsyncs)
        assert bridge.overlay_saver is not None
        assert wait_until(lambda: overlay_path(path).exists(), 3.0)
    finally:
        peer.close()
        bridge.stop()


# ------------------------------------------------------------------ finding 4


def test_the_failsafe_text_arrives_through_a_flood_of_refusals(tmp_path: Path) -> None:
    """The autopilot peer stops its HEARTBEATs while the ground station floods PARAM_SET with
    NaN at 50/s. On c3ae82c every refusal queued a STATUSTEXT and the 32-entry queue dropped the
    oldest: "autopilot lost, servos in failsafe" never arrived."""
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
