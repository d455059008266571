"""Replay real ArduPlane SITL traffic (tests/data/plane-servos.tlog) through the MAVLink core:
every SERVO_OUTPUT_RAW change on a mapped channel reaches the backend, zeros never do."""

from __future__ import annotations

import os

from tests.support.paths import TEST_DATA

os.environ.setdefault("MAVLINK20", "1")

from pymavlink import mavutil  # noqa: E402

from mavservo.mavlink.mavlink_core import MavlinkCore  # noqa: E402
from mavservo.mavlink.settings import MavlinkSettings  # noqa: E402
from tests.support.mavlink_doubles import RecordingBackend  # noqa: E402

TLOG = TEST_DATA / "plane-servos.tlog"
MAPPED = (1, 9)  # RecordingBackend maps servo channels 1 (aileron) and 9 (DO_SET_SERVO target)


def read_tlog():
    log = mavutil.mavlink_connection(str(TLOG), dialect="ardupilotmega")
    messages = []
    for _ in range(10000):  # the file holds 4,462 messages
        msg = log.recv_match()
        if msg is None:
            break
        messages.append(msg)
    log.close()
    return messages


def test_replay_every_mapped_change_reaches_backend_and_zeros_are_ignored():
    messages = read_tlog()
    assert len(messages) == 4462
    expected = []
    previous: dict[int, int] = {}
    for msg in messages:
        if msg.get_type() != "SERVO_OUTPUT_RAW":
            continue
        for channel in MAPPED:
            value = getattr(msg, f"servo{channel}_raw")
            if value != 0 and previous.get(channel) != value:
                expected.append(("servo", channel, float(value), "servo_output_raw"))
                previous[channel] = value

    backend = RecordingBackend()
    core = MavlinkCore(MavlinkSettings(system_id="follow"), backend, boot_time=0.0)
    t0 = messages[0]._timestamp
    for msg in messages:
        now = msg._timestamp - t0
        core.on_message(msg, now)
        core.tick(now)
    assert backend.servo_calls() == expected
    servo9 = [c[2] for c in backend.servo_calls() if c[1] == 9]
    assert set(servo9) == {1100.0, 1500.0, 1900.0} and servo9[-1] == 1500.0
    assert core.system_id == 1
    assert core.mirror.counters["zero_pwm_ignored"] > 0
    assert backend.failsafe_events == []  # 1 Hz heartbeats all the way
