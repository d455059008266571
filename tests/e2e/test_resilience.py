"""Issue 5 end to end: the bridge survives a pulled USB cable, a silent autopilot, a dead servo.

Real parts throughout: a pymavlink peer over UDP (as the autopilot 1/1 for heartbeats and as a
GCS 255/190 for commands), the bridge, aa55 on the adapter emulator's pty, simulated servos.
Assertions are on events, STATUSTEXT texts, ACK results, positions and frame counts; every wait
is bounded.
"""

from __future__ import annotations

import pytest

from tests.support.bridge import (
    MAV_CMD_DO_SET_SERVO,
    MAV_RESULT_ACCEPTED,
    MAV_RESULT_TEMPORARILY_REJECTED,
    Peer,
    running,
    sim_servo,
)
from tests.support.waiting import wait_until

# a bridge thread dying (an exception nobody catches) fails the test, not just warns
pytestmark = pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")


def pwm_for(angle: float, span: float = 90.0) -> float:
    """PWM (1100..1900 onto -span..span) for ``angle``."""
    return 1500 + angle / span * 400


def near(bridge, name: str, angle: float, tol: float = 0.05):
    return lambda: abs(sim_servo(bridge, name).position_deg - angle) < tol


def all_got_more(servos: list, marks: list[int], more: int) -> bool:
    """Every servo received ``more`` commands (refreshes included) since its mark."""
    return all(s.commands >= m + more for s, m in zip(servos, marks, strict=True))


def sends_failed(bridge, name: str) -> int:
    """Frames for servo ``name`` the scheduler could not write (the adapter was gone)."""
    return bridge.schedulers["bus0"].metrics()["servos"][name]["frames"]["send_failed"]


# ------------------------------------------------------------------------------ USB unplug

ONE = """
servos:
  - {name: s1, profile: rmd-x, can_id: 1, limits_deg: [-90, 90], telemetry_hz: 10}
channels:
  - {servo: s1, source: servo_output, channel: 1, output_deg: [-90, 90]}
"""


def test_usb_unplug_and_replug_mid_run_is_reported_and_recovered() -> None:
    with running(ONE) as (bridge, port):
        peer = Peer(port)
        try:
            assert peer.command(MAV_CMD_DO_SET_SERVO, [1, pwm_for(30)]) == MAV_RESULT_ACCEPTED
            assert wait_until(near(bridge, "s1", 30), 5)
            emulator = bridge.emulators["bus0"]
            servo = sim_servo(bridge, "s1")
            mark = peer.count()
            frames_before = bridge.summary()["buses"]["bus0"]["transport"]["frames"]
            assert frames_before > 0
            emulator.unplug()
            assert wait_until(lambda: any("lost" in t for _, t in bridge.events), 5), bridge.events
            frames_while_away = servo.commands + servo.requests
            # the bridge keeps trying to send into the void: three failed sends later (no
            # fixed sleep), none of its frames has reached the servo
            failed = sends_failed(bridge, "s1")
            assert wait_until(lambda: sends_failed(bridge, "s1") >= failed + 3, 5)
            assert servo.commands + servo.requests == frames_while_away
            emulator.replug()
            assert wait_until(lambda: any("back" in t for _, t in bridge.events), 8), bridge.events
            # the decoder counters carry on across the reconnect (the new device starts at zero)
            assert bridge.summary()["buses"]["bus0"]["transport"]["frames"] >= frames_before
            # the scheduler's refresh reaches the servo again without any new MAVLink command
            assert wait_until(
                lambda: (
                    servo.commands > 0 and servo.commands + servo.requests > frames_while_away + 3
                ),
                5,
            )
            assert peer.command(MAV_CMD_DO_SET_SERVO, [1, pwm_for(-45)]) == MAV_RESULT_ACCEPTED
            assert wait_until(near(bridge, "s1", -45), 5)
            texts = " | ".join(peer.statustexts(mark))
            assert wait_until(lambda: "back" in " | ".join(peer.statustexts(mark)), 3), texts
            texts = peer.statustexts(mark)
            lost_at = next(i for i, t in enumerate(texts) if "lost" in t)
            back_at = next(i for i, t in enumerate(texts) if "back" in t)
            assert lost_at < back_at  # announced in the order it happened
        finally:
            peer.close()
        summary = bridge.stop()
    transport = summary["buses"]["bus0"]["transport"]
    assert transport["disconnects"] == 1 and transport["reconnects"] == 1
    assert transport["connected"] is True
    assert transport["frames"] > frames_before


# -------------------------------------------------------------------- autopilot heartbeat

FAILSAFE = """
  heartbeat_timeout_s: 0.6
servos:
  - {name: held, profile: rmd-x, can_id: 1, limits_deg: [-90, 90], telemetry_hz: 5,
     failsafe: {action: hold}}
  - {name: centred, profile: rmd-x, can_id: 2, limits_deg: [-90, 90], telemetry_hz: 5,
     neutral_deg: -5, failsafe: {action: neutral}}
  - {name: parked, profile: rmd-x, can_id: 3, limits_deg: [-90, 90], telemetry_hz: 5,
     failsafe: {action: position, position_deg: 12}}
  - {name: limp, profile: rmd-x, can_id: 4, limits_deg: [-90, 90], telemetry_hz: 5,
     failsafe: {action: release}}
channels:
  - {servo: held, source: servo_output, channel: 1, output_deg: [-90, 90]}
  - {servo: centred, source: servo_output, channel: 2, output_deg: [-90, 90]}
  - {servo: parked, source: servo_output, channel: 3, output_deg: [-90, 90]}
  - {servo: limp, source: servo_output, channel: 4, output_deg: [-90, 90]}
"""
NAMES = ("held", "centred", "parked", "limp")


def test_silent_autopilot_puts_each_servo_in_its_failsafe_and_recovery_waits_for_commands():
    with running(FAILSAFE) as (bridge, port):
        peer = Peer(port)
        try:
            peer.start_heartbeats(0.1)
            for channel in range(1, 5):
                result = peer.command(MAV_CMD_DO_SET_SERVO, [channel, pwm_for(40)])
                assert result == MAV_RESULT_ACCEPTED
            assert wait_until(lambda: all(near(bridge, n, 40)() for n in NAMES), 5)
            mark = peer.count()
            peer.stop_heartbeats()
            assert wait_until(
                lambda: any("autopilot lost" in t for t in peer.statustexts(mark)), 5
            ), peer.statustexts(mark)
            expected = {"held": 40.0, "centred": -5.0, "parked": 12.0, "limp": 40.0}
            assert wait_until(lambda: all(near(bridge, n, a)() for n, a in expected.items()), 5), {
                n: sim_servo(bridge, n).position_deg for n in NAMES
            }
            # release: nothing more goes to that servo; hold: the last command keeps refreshing
            limp, held = sim_servo(bridge, "limp"), sim_servo(bridge, "held")
            limp_before, held_before = limp.commands, held.commands
            assert wait_until(lambda: held.commands >= held_before + 2, 3)
            assert limp.commands == limp_before
            # the servo component's HEARTBEAT (1 Hz) says MAV_STATE_CRITICAL while in failsafe
            assert wait_until(
                lambda: any(m.system_status == 5 for m in peer.since(mark, "HEARTBEAT")), 3
            )

            mark = peer.count()
            peer.start_heartbeats(0.1)
            assert wait_until(
                lambda: any("autopilot back" in t for t in peer.statustexts(mark)), 5
            ), peer.statustexts(mark)
            # nothing moves on its own after recovery. No fixed sleep: the servos that keep
            # their failsafe setpoint get two more refreshes each, so command slots went by in
            # which a stray command would have gone out; none changed a target or woke limp
            keeping = [sim_servo(bridge, n) for n in NAMES if n != "limp"]
            marks = [servo.commands for servo in keeping]
            assert wait_until(lambda: all_got_more(keeping, marks, 2), 3)
            for name, angle in expected.items():
                assert sim_servo(bridge, name).target_deg == pytest.approx(angle, abs=0.01)
                assert sim_servo(bridge, name).position_deg == pytest.approx(angle, abs=0.05)
            assert limp.commands == limp_before
            # a fresh command moves them again
            for channel in range(1, 5):
                result = peer.command(MAV_CMD_DO_SET_SERVO, [channel, pwm_for(-20)])
                assert result == MAV_RESULT_ACCEPTED
            assert wait_until(lambda: all(near(bridge, n, -20)() for n in NAMES), 5), {
                n: sim_servo(bridge, n).position_deg for n in NAMES
            }
        finally:
            peer.close()
        summary = bridge.stop()
    assert summary["mavlink"]["failsafe_count"] == 1
    assert any("failsafe: autopilot heartbeat lost" in e for e in summary["events"])


# --------------------------------------------------------------------------- dead servo

TWO = """
servos:
  - {name: alive, profile: rmd-x, can_id: 1, limits_deg: [-90, 90], telemetry_hz: 10}
  - {name: mute, profile: lk, can_id: 2, limits_deg: [-90, 90], telemetry_hz: 10}
channels:
  - {servo: alive, source: servo_output, channel: 1, output_deg: [-90, 90]}
  - {servo: mute, source: servo_output, channel: 2, output_deg: [-90, 90]}
"""


def test_a_servo_that_stops_answering_goes_offline_and_its_commands_are_refused():
    with running(TWO) as (bridge, port):
        peer = Peer(port)
        try:
            assert peer.command(MAV_CMD_DO_SET_SERVO, [2, pwm_for(10)]) == MAV_RESULT_ACCEPTED
            assert wait_until(near(bridge, "mute", 10), 5)
            mark = peer.count()
            sim_servo(bridge, "mute").faults.silent = True
            scheduler = bridge.schedulers["bus0"]
            assert wait_until(lambda: not scheduler.is_online("mute"), 5)
            assert scheduler.is_online("alive")
            # said at once, or (a start-up flap within 10 s before) 2 s later as a lasting
            # repeat, "servo mute offline (x2 in ...)" (mavservo/records/repeats.py)
            assert wait_until(
                lambda: any("mute offline" in t for t in peer.statustexts(mark)), 5
            ), peer.statustexts(mark)
            row = next(r for r in bridge.status_rows() if r["servo"] == "mute")
            assert row["online"] is False and "NO_REPLY" in row["faults"]
            result = peer.command(MAV_CMD_DO_SET_SERVO, [2, pwm_for(50)])
            assert result == MAV_RESULT_TEMPORARILY_REJECTED
            # the other servo on the same bus is unaffected
            assert peer.command(MAV_CMD_DO_SET_SERVO, [1, pwm_for(-30)]) == MAV_RESULT_ACCEPTED
            assert wait_until(near(bridge, "alive", -30), 5)
            assert sim_servo(bridge, "mute").target_deg == pytest.approx(10, abs=0.01)
            # it answers again: back online, commands accepted again
            sim_servo(bridge, "mute").faults.silent = False
            assert wait_until(lambda: scheduler.is_online("mute"), 5)
            assert wait_until(
                lambda: any("mute back online" in t for t in peer.statustexts(mark)), 5
            )
            assert peer.command(MAV_CMD_DO_SET_SERVO, [2, pwm_for(50)]) == MAV_RESULT_ACCEPTED
            assert wait_until(near(bridge, "mute", 50), 5)
        finally:
            peer.close()
        bridge.stop()
