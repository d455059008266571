"""A stranger's SET_MESSAGE_INTERVAL cannot re-plan the link budget to starve the telemetry.

Red team (review3), real UDP sockets on 127.0.0.1, the default policy (no allowed_sources: anyone
may command; parameters read-only). Before: one SET_MESSAGE_INTERVAL of 1 us for
NAMED_VALUE_FLOAT from an unknown sender was ACCEPTED; the budget was re-planned for a 1 MHz
stream, every stream's ratio fell to 1.5e-6, and ACTUATOR_OUTPUT_STATUS (6 in 4 s before) and
ESC_TELEMETRY (3) stopped on the link until a restart. Now a rate faster than the configured one
is DENIED with the reason; slowing a stream down is still accepted.
"""

from __future__ import annotations

import os
import time
from typing import Any

from pymavlink import mavutil

from mavservo.app.bridge import Bridge
from mavservo.config.loader import load_config_text
from tests.support.waiting import free_udp_port

os.environ.setdefault("MAVLINK20", "1")

SET_MESSAGE_INTERVAL = 511
NAMED_VALUE_FLOAT = 251
MAV_RESULT_ACCEPTED, MAV_RESULT_DENIED = 0, 2


def _config(port: int) -> str:
    return f"""
mavlink:
  url: udpin:127.0.0.1:{port}
  system_id: 1
  heartbeat_timeout_s: 30
  link_budget_bytes_s: 1000
can:
  buses:
    - {{name: bus0, interface: aa55, channel: sim, protocol: variable}}
servos:
  - {{name: left, profile: rmd-x, can_id: 1, limits_deg: [-30, 30], telemetry_hz: 5}}
channels:
  - {{servo: left, source: servo_output, channel: 1, input: {{min: 1000, max: 2000}},
     output_deg: [-30, 30]}}
"""


def _peer(port: int, source: tuple[int, int]) -> Any:
    conn = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{port}",
        source_system=source[0],
        source_component=source[1],
        dialect="ardupilotmega",
    )
    conn.mav.heartbeat_send(6, 8, 0, 0, 4)
    return conn


def _ack(conn: Any) -> Any:
    for _ in range(40):  # bounded: 40 x 0.1 s
        msg = conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.1)
        if msg is not None and msg.command == SET_MESSAGE_INTERVAL:
            return msg
    return None


def _count(conn: Any, kind: str, seconds: float, enough: int) -> int:
    """How many ``kind`` from the bridge's component arrive within ``seconds``, counted no
    further than ``enough`` (a test asking for at least that many need not sit it out)."""
    count, deadline = 0, time.monotonic() + seconds
    for _ in range(5000):  # bounded
        if time.monotonic() >= deadline or count >= enough:
            break
        msg = conn.recv_match(blocking=True, timeout=0.1)
        if msg is not None and msg.get_type() == kind and msg.get_srcComponent() == 140:
            count += 1
    return count


def test_a_strangers_fast_interval_is_denied_and_the_telemetry_keeps_flowing() -> None:
    port = free_udp_port()
    bridge = Bridge(load_config_text(_config(port)), log_dir=False).start()
    peers = []
    try:
        gcs = _peer(port, (255, 190))
        rogue = _peer(port, (66, 190))
        peers += [gcs, rogue]
        time.sleep(0.5)
        rogue.mav.command_long_send(
            1, 140, SET_MESSAGE_INTERVAL, 0, NAMED_VALUE_FLOAT, 1, 0, 0, 0, 0, 0
        )
        ack = _ack(rogue)
        assert ack is not None and ack.result == MAV_RESULT_DENIED
        time.sleep(0.3)
        assert _count(gcs, "ACTUATOR_OUTPUT_STATUS", 3.0, enough=2) >= 2
        assert bridge.mavlink is not None
        assert bridge.mavlink.stats()["core"]["interval_refused"] == 1
        rogue.mav.command_long_send(  # slower than configured: still a peer's right
            1, 140, SET_MESSAGE_INTERVAL, 0, NAMED_VALUE_FLOAT, 1_000_000, 0, 0, 0, 0, 0
        )
        ack = _ack(rogue)
        assert ack is not None and ack.result == MAV_RESULT_ACCEPTED
    finally:
        for conn in peers:
            conn.close()
        bridge.stop()


def test_only_minus_one_stops_a_stream() -> None:
    """MAV_CMD_SET_MESSAGE_INTERVAL: -1 disables, 0 restores the default; -0.5 was taken as
    a stop (any negative did) and ACCEPTED; now it is DENIED and the stream keeps going."""
    from mavservo.mavlink.mavlink_core import MavlinkCore
    from mavservo.mavlink.settings import MavlinkSettings
    from tests.support.mavlink_doubles import RecordingBackend, command_long, wire

    core = MavlinkCore(MavlinkSettings(system_id=1), RecordingBackend())
    before = core.telemetry.rates_hz()["named_value_float_hz"]
    command = command_long((1, 140), SET_MESSAGE_INTERVAL, NAMED_VALUE_FLOAT, -0.5)
    out = core.on_message(wire(command, (255, 190)), 1.0)
    assert [m.result for _, m in out if m.get_type() == "COMMAND_ACK"] == [MAV_RESULT_DENIED]
    assert core.telemetry.rates_hz()["named_value_float_hz"] == before > 0
