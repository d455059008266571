"""ODrive axes through the whole bridge and back, over the ``aa55`` interface on the adapter
emulator's pty.

A GCS-side pymavlink peer sends DO_SET_SERVO over UDP; the bridge enters closed loop on each
simulated ODrive and drives it with Set_Input_Pos; the axes push encoder estimates and
heartbeats, and their telemetry comes back over MAVLink. Checked: the axes follow with nothing
lost; a position outside an axis' own range is DENIED and counted and never reaches the bus; a
silent axis goes offline (STATUSTEXT) and comes back; an axis error reaches STATUSTEXT and the
gimbal failure flags; an axis its own watchdog disarmed is reported and re-armed by the bridge.
"""

from __future__ import annotations

import struct

import pytest

from mavservo.servos.odrive.profile import (
    CMD_SET_INPUT_POS,
    STATE_CLOSED_LOOP,
    WATCHDOG_TIMER_EXPIRED,
    ODrive,
)
from tests.support.bridge import (
    MAV_CMD_DO_SET_SERVO,
    MAV_RESULT_ACCEPTED,
    MAV_RESULT_DENIED,
    Peer,
    Recorder,
    assert_fault_reaches_statustext_and_gimbal_flags,
    assert_nothing_lost,
    assert_servos_follow_pwm,
    gimbal_config,
    named_values,
    running,
    sim_servo,
    status,
)
from tests.support.waiting import wait_until

pytestmark = pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")

WAIT_S = 5.0

CONFIG = """
  telemetry: {actuator_output_status_hz: 10, named_value_float_hz: 20, esc_telemetry_hz: 0}
servos:
  - {name: direct, profile: odrive, can_id: 1, limits_deg: [-90, 90], telemetry_hz: 20,
     options: {watchdog_timeout_s: 0.5, aux_rate_ms: 100}}
  - {name: geared, profile: odrive, can_id: 2, limits_deg: [-90, 90], telemetry_hz: 20,
     options: {input_mode: trap-traj, motor_turns_per_rev: 8.0, velocity_limit_turns_s: 8.0,
               traj_accel_turns_s2: 40.0}}
  - {name: narrow, profile: odrive, can_id: 3, limits_deg: [-90, 90], telemetry_hz: 20,
     options: {min_position_deg: -45, max_position_deg: 45}}
# a reply counts as lost only when it never comes: timing on a loaded machine is not judged here
scheduler: {reply_timeout_s: 0.5, refresh_interval_s: 0.1}
channels:
  - {servo: direct, source: servo_output, channel: 1, input: {min: 1000, max: 2000},
     output_deg: [-90, 90]}
  - {servo: geared, source: servo_output, channel: 2, input: {min: 1000, max: 2000},
     output_deg: [-90, 90]}
  - {servo: narrow, source: servo_output, channel: 3, input: {min: 1000, max: 2000},
     output_deg: [-90, 90]}
"""

#: servo -> (NAMED_VALUE_FLOAT index, channel)
SERVOS = {"direct": (1, 1), "geared": (2, 2)}
RESOLUTION_DEG = 0.01
"""Float32 turns carry far finer steps; this is the reading's travel between two pushes."""


def test_odrive_axes_follow_and_report_with_nothing_lost() -> None:
    with running(CONFIG) as (bridge, port):
        peer = Peer(port)
        try:
            for pwm in (1650, 1210):
                assert_servos_follow_pwm(bridge, peer, SERVOS, pwm, RESOLUTION_DEG, WAIT_S)
            # the auxiliary messages bring temperature back too
            assert wait_until(
                lambda: any(v == v for v in named_values(peer.messages(), "s1_tmp")), WAIT_S
            )
        finally:
            peer.close()
        summary = bridge.stop()
    assert_nothing_lost(summary, SERVOS)


def commanded_angles(recorder: Recorder, name: str, profile: ODrive) -> list[float]:
    """Angles of the Set_Input_Pos frames written to ``name`` (decoded here)."""
    out = []
    for kind, arbitration_id, data in recorder.frames(name):
        if kind.startswith("command") and arbitration_id == profile.can_id << 5 | CMD_SET_INPUT_POS:
            (turns,) = struct.unpack_from("<f", data)
            out.append(turns * 360 / profile.options.motor_turns_per_rev)
    return out


def test_a_position_outside_the_axis_range_is_denied_counted_and_never_sent() -> None:
    """72 deg is inside limits_deg but outside this axis' +-45 deg: DENIED, counted under the
    profile's name, and no frame for it goes out; the next valid command does."""
    recorder = Recorder()
    narrow = ODrive(3, min_position_deg=-45.0, max_position_deg=45.0)
    with running(CONFIG, observers=[recorder]) as (bridge, port):
        peer = Peer(port)
        try:
            assert peer.command(MAV_CMD_DO_SET_SERVO, [3, 1900]) == MAV_RESULT_DENIED
            assert peer.command(MAV_CMD_DO_SET_SERVO, [3, 1600]) == MAV_RESULT_ACCEPTED
            assert wait_until(lambda: 18.0 in recorder.angles("narrow"), WAIT_S)
            assert wait_until(lambda: commanded_angles(recorder, "narrow", narrow), WAIT_S)
            assert wait_until(
                lambda: abs(sim_servo(bridge, "narrow").position_deg - 18.0) < 0.05, WAIT_S
            )
        finally:
            peer.close()
        summary = bridge.stop()
    assert recorder.angles("narrow") == [pytest.approx(18.0)]
    sent = commanded_angles(recorder, "narrow", narrow)
    assert sent and all(a == pytest.approx(18.0, abs=1e-3) for a in sent), sent
    commands = summary["mavlink"]["commands"]
    assert commands["result_denied"] == 1, commands
    assert commands["reason_odrive"] == 1, commands


def test_a_silent_axis_goes_offline_and_comes_back() -> None:
    with running(CONFIG) as (bridge, port):
        peer = Peer(port)
        try:
            peer.gcs_heartbeat()  # a GCS: answer me
            assert wait_until(lambda: status(bridge, "direct").online, WAIT_S)
            device = sim_servo(bridge, "direct")
            mark = peer.count()
            device.faults.silent = True
            assert wait_until(lambda: not status(bridge, "direct").online, WAIT_S)
            assert wait_until(lambda: "servo direct offline" in peer.statustexts(mark), WAIT_S)
            assert status(bridge, "geared").online  # the others keep pushing
            device.faults.silent = False
            assert wait_until(lambda: status(bridge, "direct").online, WAIT_S)
        finally:
            peer.close()


def test_an_axis_its_watchdog_disarmed_is_reported_and_rearmed() -> None:
    """The axis disarms as if its watchdog had expired: the heartbeat says IDLE with
    WATCHDOG_TIMER_EXPIRED, STATUSTEXT names it, and the bridge's start-up (clear errors,
    closed loop) arms it again, so the next set point moves it."""
    with running(CONFIG) as (bridge, port):
        peer = Peer(port)
        try:
            peer.gcs_heartbeat()
            assert peer.command(MAV_CMD_DO_SET_SERVO, [1, 1600]) == MAV_RESULT_ACCEPTED
            servo = sim_servo(bridge, "direct")
            assert wait_until(lambda: abs(servo.position_deg - 18.0) < 0.05, WAIT_S)
            mark = peer.count()
            device = servo._device  # the simulated ODrive behind the motor
            device._disarm(WATCHDOG_TIMER_EXPIRED, servo.time)
            assert wait_until(
                lambda: "servo direct fault communication_lost" in peer.statustexts(mark),
                WAIT_S,
            ), peer.statustexts(mark)
            assert wait_until(lambda: device.state == STATE_CLOSED_LOOP, WAIT_S)
            assert peer.command(MAV_CMD_DO_SET_SERVO, [1, 1300]) == MAV_RESULT_ACCEPTED
            assert wait_until(lambda: abs(servo.position_deg + 36.0) < 0.05, WAIT_S)
        finally:
            peer.close()


GIMBAL = gimbal_config("odrive", "odrive")


@pytest.mark.parametrize(
    ("axis", "fault", "text"),
    [("pitch", "over_current", "over_current"), ("yaw", "over_temperature", "over_temperature")],
)
def test_an_axis_error_reaches_statustext_and_gimbal_failure_flags(
    axis: str, fault: str, text: str
) -> None:
    with running(GIMBAL) as (bridge, port):
        peer = Peer(port)
        try:
            peer.gcs_heartbeat()
            assert_fault_reaches_statustext_and_gimbal_flags(
                bridge, peer, axis, fault, text, WAIT_S
            )
        finally:
            peer.close()
