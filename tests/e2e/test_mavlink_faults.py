"""MAVLink-side faults: autopilot gone, link flapping, clock jumps, a high-rate command flood.

The core is pure (time comes in as an argument), so clock jumps and flapping are driven exactly
with a recording backend; "autopilot gone and back" is also run end to end through the Bridge
over UDP to the simulated servos.
"""

from __future__ import annotations

import os
import time

import pytest
from pymavlink import mavutil

from mavservo.app.bridge import Bridge
from mavservo.config.loader import load_config_text
from mavservo.mavlink.mavlink_core import MavlinkCore
from tests.support.mavlink_doubles import (
    RecordingBackend,
    command_long,
    heartbeat,
    make_mavlink_core,
    servo_output_raw,
    wire,
)
from tests.support.waiting import free_udp_port, wait_until

os.environ.setdefault("MAVLINK20", "1")

AUTOPILOT = (1, 1)
GCS = (255, 190)
TIMEOUT_S = 2.0


def core() -> tuple[MavlinkCore, RecordingBackend]:
    return make_mavlink_core(boot_time=100.0, heartbeat_timeout_s=TIMEOUT_S)


def test_flapping_link_enters_and_leaves_failsafe_once_per_gap() -> None:
    mav, backend = core()
    now = 100.0
    gaps = 0
    for cycle in range(5):
        for _ in range(10):  # 1 s of heartbeats at 10 Hz
            mav.on_message(wire(heartbeat(), AUTOPILOT), now)
            mav.tick(now)
            now += 0.1
        silence = TIMEOUT_S * (1.5 if cycle % 2 == 0 else 0.5)  # every other gap is too short
        gaps += cycle % 2 == 0
        for _ in range(int(silence / 0.1)):
            mav.tick(now)
            now += 0.1
    mav.on_message(wire(heartbeat(), AUTOPILOT), now)
    assert mav.watchdog.failsafe_count == gaps == 3
    assert backend.failsafe_events.count("enter") == 3
    assert not mav.watchdog.in_failsafe
    mav.on_message(wire(servo_output_raw(servo1=1600), AUTOPILOT), now)
    assert backend.servo_calls()[-1][:3] == ("servo", 1, 1600.0)


def test_clock_jumps_backwards_and_forwards_do_not_confuse_the_watchdog_or_commands() -> None:
    mav, backend = core()
    mav.on_message(wire(heartbeat(), AUTOPILOT), 100.0)
    mav.tick(100.5)
    for now in (50.0, 0.0, -1e6):  # backwards: never a failsafe, never an exception
        mav.tick(now)
        assert not mav.watchdog.in_failsafe
    out = mav.on_message(wire(command_long((1, 140), 183, 1, 1700), GCS), 10.0)
    assert [m.result for _, m in out if m.get_type() == "COMMAND_ACK"] == [0]
    mav.tick(1e9)  # forwards (a stalled process, a resumed machine): one failsafe
    assert mav.watchdog.in_failsafe and mav.watchdog.failsafe_count == 1
    mav.tick(2e9)
    assert mav.watchdog.failsafe_count == 1
    mav.on_message(wire(heartbeat(), AUTOPILOT), 2e9)
    assert not mav.watchdog.in_failsafe
    out = mav.on_message(wire(command_long((1, 140), 183, 1, 1200), GCS), 2e9 + 1)
    assert [m.result for _, m in out if m.get_type() == "COMMAND_ACK"] == [0]
    assert [c[2] for c in backend.servo_calls()] == [1700.0, 1200.0]


def test_command_flood_is_acked_once_each_and_retries_are_not_reapplied() -> None:
    mav, backend = core()
    mav.on_message(wire(heartbeat(), AUTOPILOT), 100.0)
    acks = 0
    for k in range(2000):  # 2000 commands in 2 s of simulated time, each sent twice
        j = k // 2
        pwm = 1100 + j % 800 + (j // 800) * 0.5  # all distinct
        out = mav.on_message(wire(command_long((1, 140), 183, 1, pwm), GCS), 100.0 + k * 0.001)
        acks += sum(1 for _, m in out if m.get_type() == "COMMAND_ACK")
        mav.tick(100.0 + k * 0.001)
    counters = mav.commands.counters
    assert acks == 2000
    assert len(backend.servo_calls()) == 1000
    assert counters["retry_not_reapplied"] == 1000


# -- end to end ----------------------------------------------------------------------------


@pytest.fixture
def bridge_and_autopilot():
    port = free_udp_port()
    text = f"""
mavlink: {{url: "udpin:127.0.0.1:{port}", system_id: 1, heartbeat_timeout_s: 0.6}}
can:
  buses: [{{name: bus0, interface: aa55, channel: sim}}]
servos:
  - {{name: s1, profile: rmd-x, can_id: 1, limits_deg: [-30, 30], neutral_deg: 5,
     failsafe: {{action: neutral, timeout_s: 0.2}}}}
channels:
  - {{servo: s1, source: servo_output, channel: 1, input: {{min: 1000, max: 2000}},
     output_deg: [-30, 30]}}
logging: {{dir: runs}}
"""
    bridge = Bridge(load_config_text(text), log_dir=False).start()
    autopilot = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{port}", source_system=1, source_component=1, dialect="ardupilotmega"
    )
    yield bridge, autopilot
    autopilot.close()
    bridge.stop()


def test_autopilot_gone_sends_servos_to_failsafe_and_fresh_stream_drives_them_again(
    bridge_and_autopilot,
) -> None:
    bridge, autopilot = bridge_and_autopilot
    servo = bridge.emulators["bus0"].servos[0]

    def stream(pwm: int, seconds: float) -> None:
        for _ in range(int(seconds / 0.05)):
            autopilot.mav.heartbeat_send(1, 3, 0, 0, 4)
            autopilot.mav.servo_output_raw_send(0, 0, pwm, *([0] * 15))
            time.sleep(0.05)

    stream(1900, 0.5)  # +24 deg
    assert wait_until(lambda: servo.target_deg == pytest.approx(24.0))
    # the autopilot goes silent: failsafe neutral (5 deg)
    assert wait_until(lambda: bridge.mavlink.stats()["in_failsafe"])
    assert wait_until(lambda: servo.target_deg == pytest.approx(5.0))
    stream(1100, 0.5)  # back: -24 deg
    assert wait_until(lambda: servo.target_deg == pytest.approx(-24.0))
    assert bridge.mavlink.stats()["failsafe_count"] >= 1
