"""A value a ground station read is accepted when it writes it back (float32 round trip).

Red team (review3) of issue 32's envelope, real UDP sockets on 127.0.0.1. PARAM_VALUE carries a
float32: SRV1_MAX of a servo whose YAML limits are [-30.1, 30.1] reads as 30.100000381..., and a
ground station that writes back what it read ("save all", or restoring the YAML's value after
narrowing) sent that float32. Before: compared in float64 with the YAML's 30.1 it left the
envelope and was refused ("limits -30.1..30.1 deg ... leave the config file's -30.1..30.1 deg").
Now a value that is, as a float32, the current value or the config file's is that value.
"""

from __future__ import annotations

import os
import struct
import time
from typing import Any

from pymavlink import mavutil

from mavservo.app.bridge import Bridge
from mavservo.config.loader import load_config_text
from tests.support.waiting import free_udp_port

os.environ.setdefault("MAVLINK20", "1")
MAV_PARAM_TYPE_REAL32 = 9


def _config(port: int) -> str:
    return f"""
mavlink:
  url: udpin:127.0.0.1:{port}
  system_id: 1
  heartbeat_timeout_s: 30
  allowed_sources: [{{system: 255, component: 190}}]
can:
  buses:
    - {{name: bus0, interface: aa55, channel: sim, protocol: variable}}
servos:
  - {{name: left, profile: rmd-x, can_id: 1, limits_deg: [-30.1, 30.1]}}
channels:
  - {{servo: left, source: servo_output, channel: 1, input: {{min: 1000, max: 2000}}}}
"""


def _value(conn: Any, name: str) -> float | None:
    for _ in range(40):  # bounded: 40 x 0.1 s
        msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.1)
        if msg is not None and msg.param_id == name:
            return float(msg.param_value)
    return None


def test_a_value_read_is_accepted_when_written_back() -> None:
    port = free_udp_port()
    bridge = Bridge(load_config_text(_config(port)), log_dir=False).start()
    gcs = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{port}", source_system=255, source_component=190
    )
    try:
        gcs.mav.heartbeat_send(6, 8, 0, 0, 4)
        time.sleep(0.3)
        gcs.mav.param_request_read_send(1, 140, b"SRV1_MAX", -1)
        read = _value(gcs, "SRV1_MAX")
        assert read is not None and read == struct.unpack("<f", struct.pack("<f", 30.1))[0]
        gcs.mav.param_set_send(1, 140, b"SRV1_MAX", 20.0, MAV_PARAM_TYPE_REAL32)  # narrow
        assert _value(gcs, "SRV1_MAX") == 20.0
        gcs.mav.param_set_send(1, 140, b"SRV1_MAX", read, MAV_PARAM_TYPE_REAL32)  # restore
        assert _value(gcs, "SRV1_MAX") == read
        assert bridge.parameters is not None
        assert bridge.parameters.value("SRV1_MAX") == 30.1
        gcs.mav.param_set_send(1, 140, b"SRV1_MAX", read, MAV_PARAM_TYPE_REAL32)  # unchanged
        assert _value(gcs, "SRV1_MAX") == read
        assert bridge.mavlink is not None
        assert bridge.mavlink.stats()["parameters"].get("set_refused", 0) == 0
    finally:
        gcs.close()
        bridge.stop()
