"""The MAVLink output never stops: unknown (NaN, inf) servo values encode in every telemetry
message, and a failing part of the tick costs only that part's messages, never the heartbeats.

The trial's failure: the first reply of an RMD-X servo was its 9A status reply, so the state's
current was NaN; ``int(NaN)`` in ESC_TELEMETRY killed the tick thread and with it the heartbeats.
"""

from __future__ import annotations

import math
import os
import struct

os.environ.setdefault("MAVLINK20", "1")

import can  # noqa: E402
import pytest  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mavlink2  # noqa: E402

from mavservo.mavlink.mavlink_core import MavlinkCore  # noqa: E402
from mavservo.mavlink.settings import MavlinkSettings, TelemetryRates  # noqa: E402
from tests.mavlink.test_udp_peers import peer  # noqa: E402
from tests.support.mavlink_doubles import RecordingBackend, state  # noqa: E402
from tests.support.waiting import free_udp_port, wait_for_message, wait_until  # noqa: E402

ESC_FROM_1 = TelemetryRates(esc_first_index=1)  # servo n is ESC n: group 1_TO_4
from mavservo.mavlink.side import MavlinkSide  # noqa: E402
from mavservo.mavlink.telemetry import Telemetry  # noqa: E402
from mavservo.servos.rmdx.profile import CMD_STATUS_1, RmdX  # noqa: E402

TELEMETRY_TYPES = {"ACTUATOR_OUTPUT_STATUS", "ESC_TELEMETRY_1_TO_4", "NAMED_VALUE_FLOAT"}


def first_reply_is_9a() -> object:
    """The state an RMD-X servo has after its 9A status reply came first (current unknown)."""
    servo = RmdX(can_id=1)
    data = struct.pack("<BbBBHH", CMD_STATUS_1, 38, 0, 0, 240, 0)
    reply = can.Message(arbitration_id=servo.reply_id, data=data, is_extended_id=False)
    decoded = servo.decode(reply, 1.0)
    assert decoded is not None and math.isnan(decoded.current_a)
    return decoded


def roundtrip(messages: list) -> list:
    """Pack each message as the link would, and parse it back (raises if one cannot encode)."""
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=140)
    out = []
    for msg in messages:
        out.append(mav.decode(bytearray(msg.pack(mav))))
    return out


@pytest.mark.parametrize(
    "servo_state",
    [
        first_reply_is_9a(),
        state(math.nan, velocity=math.nan, current=math.nan, temperature=math.nan),
        state(
            math.inf, velocity=-math.inf, current=math.inf, temperature=-math.inf, voltage=math.nan
        ),
    ],
    ids=["rmdx-9a-first", "all-nan", "infinities"],
)
def test_unknown_values_encode_in_every_telemetry_message(servo_state):
    backend = RecordingBackend()
    backend.states["aileron"] = servo_state
    backend.states["flap"] = state(6.0, current=1.5)
    core = MavlinkCore(MavlinkSettings(system_id=1, telemetry=ESC_FROM_1), backend)
    for msg_id in (375, 11030, 251):
        assert core.telemetry.request(msg_id, 0.0), msg_id
    decoded = roundtrip([m for _, m in core.tick(0.0)])
    assert {m.get_type() for m in decoded} >= TELEMETRY_TYPES
    assert core.counters["tick_errors"] == 0 and not core.telemetry.counters["build_errors"]
    esc = next(m for m in decoded if m.get_type() == "ESC_TELEMETRY_1_TO_4")
    assert esc.current[2] == 150  # the healthy servo is still reported
    if math.isnan(servo_state.current_a):
        assert esc.current[0] == 0  # ESC_TELEMETRY has no "unknown": 0 like an empty slot
    named = {m.name: m.value for m in decoded if m.get_type() == "NAMED_VALUE_FLOAT"}
    assert math.isnan(named["s1_cur"]) == math.isnan(servo_state.current_a)
    aos = next(m for m in decoded if m.get_type() == "ACTUATOR_OUTPUT_STATUS")
    assert aos.active & 1 == (1 if math.isfinite(servo_state.position_deg) else 0)


def test_a_failing_message_is_left_out_counted_and_logged_once(monkeypatch, caplog):
    def broken(self, statuses, group):
        raise ValueError("cannot convert float NaN to integer")

    monkeypatch.setattr(Telemetry, "_esc_telemetry", broken)
    backend = RecordingBackend()
    backend.states["aileron"] = state(3.0)
    core = MavlinkCore(MavlinkSettings(system_id=1, telemetry=ESC_FROM_1), backend)
    kinds = [m.get_type() for step in range(301) for _, m in core.tick(step * 0.01)]
    assert kinds.count("HEARTBEAT") == 4
    assert "NAMED_VALUE_FLOAT" in kinds and "ACTUATOR_OUTPUT_STATUS" in kinds
    assert not any(k.startswith("ESC_TELEMETRY") for k in kinds)
    assert core.telemetry.counters["build_errors"] > 1
    logged = [r for r in caplog.records if "building message 11030 failed" in r.getMessage()]
    assert len(logged) == 1 and logged[0].exc_info is not None


class ExplodingBackend(RecordingBackend):
    """Every telemetry snapshot fails, as a bug anywhere below the MAVLink side would."""

    def servo_statuses(self):
        raise ValueError("cannot convert float NaN to integer")


def test_heartbeats_keep_coming_over_udp_when_telemetry_raises():
    port = free_udp_port()
    side = MavlinkSide(
        MavlinkSettings(url=f"udpin:127.0.0.1:{port}", system_id=1), ExplodingBackend()
    )
    gcs = peer(port, 255, 190)
    side.start()
    try:
        gcs.mav.heartbeat_send(6, 8, 0, 0, 4)
        assert wait_until(lambda: side.stats()["core"].get("tick_errors", 0) > 0)
        seen: list = []

        def ours(msg) -> bool:
            return msg.get_type() == "HEARTBEAT" and msg.get_srcComponent() == 140

        wait_for_message(gcs, lambda m: sum(map(ours, seen)) >= 3, timeout=6.0, keep=seen)
        assert sum(map(ours, seen)) >= 3
        assert side.stats()["core"]["tick_errors"] > 1  # still ticking, still failing
    finally:
        side.stop()
        gcs.close()
