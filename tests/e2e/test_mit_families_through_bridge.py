"""Damiao DM-J and CubeMars AK MIT-mode servos through the whole bridge and back.

A GCS-side pymavlink peer sends DO_SET_SERVO over UDP; the bridge drives the aa55 interface on
the adapter emulator's pty; simulated Damiao motors (MIT and position-velocity mode) and a
CubeMars AK driver in MIT mode move and answer; their telemetry comes back over MAVLink.
Checked: the servos follow within the reply's resolution with nothing lost; a position outside
a model's range is DENIED and counted and never reaches the bus; a servo that falls silent goes
offline (STATUSTEXT) and comes back; a fault status in a reply reaches STATUSTEXT and the gimbal
failure flags.
"""

from __future__ import annotations

import math

import pytest

from mavservo.servos.cubemars.mit_mode import CubeMarsAKMit
from mavservo.servos.damiao.profile import DamiaoDM
from mavservo.servos.mit import is_special, unpack_command
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
  - {name: dm_mit, profile: damiao-dm, can_id: 1, limits_deg: [-90, 90], telemetry_hz: 10,
     options: {comm_timeout_ms: 500}}
  - {name: dm_pv, profile: damiao-dm, can_id: 2, limits_deg: [-90, 90], telemetry_hz: 10,
     max_speed_dps: 720, options: {mode: position-velocity, comm_timeout_ms: 500}}
  - {name: ak_mit, profile: cubemars-ak-mit, can_id: 3, limits_deg: [-90, 90], telemetry_hz: 10}
  - {name: dm_small, profile: damiao-dm, can_id: 4, limits_deg: [-90, 90], telemetry_hz: 10,
     options: {p_max_rad: 1.0}}
  - {name: ak_small, profile: cubemars-ak-mit, can_id: 5, limits_deg: [-90, 90], telemetry_hz: 10,
     options: {p_max_rad: 1.0}}
# a reply counts as lost only when it never comes: timing on a loaded machine is not judged here
scheduler: {reply_timeout_s: 0.5}
channels:
  - {servo: dm_mit, source: servo_output, channel: 1, input: {min: 1000, max: 2000},
     output_deg: [-90, 90]}
  - {servo: dm_pv, source: servo_output, channel: 2, input: {min: 1000, max: 2000},
     output_deg: [-90, 90]}
  - {servo: ak_mit, source: servo_output, channel: 3, input: {min: 1000, max: 2000},
     output_deg: [-90, 90]}
  - {servo: dm_small, source: servo_output, channel: 4, input: {min: 1000, max: 2000},
     output_deg: [-90, 90]}
  - {servo: ak_small, source: servo_output, channel: 5, input: {min: 1000, max: 2000},
     output_deg: [-90, 90]}
"""

RESOLUTION_DEG = math.degrees(25.0 / 65535)
"""One count of the 16-bit position field over +-12.5 rad (both families' default range)."""
#: servo -> (NAMED_VALUE_FLOAT index, channel)
SERVOS = {"dm_mit": (1, 1), "dm_pv": (2, 2), "ak_mit": (3, 3)}


#: servo with a +-1 rad (57.3 deg) model range -> (profile, channel, PWM whose angle is outside it)
OUT_OF_RANGE = {
    "dm_small": (DamiaoDM(4, p_max_rad=1.0), 4, 1900),  # +72 deg
    "ak_small": (CubeMarsAKMit(5, p_max_rad=1.0), 5, 1050),  # -81 deg
}


def test_mit_families_follow_report_and_refuse_out_of_range() -> None:
    """Both MIT families follow and report; an angle inside limits_deg but outside the model's
    range is DENIED by each family, counted under its profile, and no command for it (nor any
    other setpoint) reaches that servo while the others go on following."""
    recorder = Recorder()
    # five servos' positions, three each, within WAIT_S: a wider link than a radio's
    # default 1,000 B/s (whose decimation leaves one position per servo every several seconds)
    wide = "  link_budget_bytes_s: 20000\n"
    with running(CONFIG, observers=[recorder], extra_mavlink=wide) as (bridge, port):
        peer = Peer(port)
        try:
            for _, channel, pwm in OUT_OF_RANGE.values():
                assert peer.command(MAV_CMD_DO_SET_SERVO, [channel, pwm]) == MAV_RESULT_DENIED
            for pwm in (1650, 1210):
                assert_servos_follow_pwm(bridge, peer, SERVOS, pwm, RESOLUTION_DEG, WAIT_S)
        finally:
            peer.close()
        summary = bridge.stop()
    assert_nothing_lost(summary, SERVOS)
    for name, (profile, _, _) in OUT_OF_RANGE.items():
        assert recorder.angles(name) == [], name
        assert commanded_angles(recorder, name, profile) == [], name
    commands = summary["mavlink"]["commands"]
    assert commands["result_denied"] == 2, commands
    assert commands["reason_damiao-dm"] == 1, commands
    assert commands["reason_cubemars-ak-mit"] == 1, commands


def test_a_position_outside_the_models_range_is_denied_counted_and_never_sent() -> None:
    """72 deg is inside limits_deg but outside this model's +-1 rad (57.3 deg): DENIED, counted
    in the summary, and no frame for it goes out; the next valid command does."""
    recorder = Recorder()
    small = DamiaoDM(4, p_max_rad=1.0)
    with running(CONFIG, observers=[recorder]) as (bridge, port):
        peer = Peer(port)
        try:
            assert peer.command(MAV_CMD_DO_SET_SERVO, [4, 1900]) == MAV_RESULT_DENIED
            assert peer.command(MAV_CMD_DO_SET_SERVO, [4, 1600]) == MAV_RESULT_ACCEPTED
            assert wait_until(lambda: 18.0 in recorder.angles("dm_small"), WAIT_S)
            assert wait_until(lambda: commanded_angles(recorder, "dm_small", small), WAIT_S)
        finally:
            peer.close()
        summary = bridge.stop()
    assert recorder.angles("dm_small") == [pytest.approx(18.0)]
    sent = commanded_angles(recorder, "dm_small", small)
    assert sent and all(a == pytest.approx(18.0, abs=0.05) for a in sent), sent
    commands = summary["mavlink"]["commands"]
    assert commands["result_denied"] == 1, commands
    assert commands["reason_damiao-dm"] == 1, commands  # counted under the profile's name


def commanded_angles(
    recorder: Recorder, name: str, profile: DamiaoDM | CubeMarsAKMit
) -> list[float]:
    """Angles of the MIT position commands written to servo ``name`` (decoded here)."""
    out = []
    for kind, arbitration_id, data in recorder.frames(name):
        if kind.startswith("command") and arbitration_id == profile.can_id and not is_special(data):
            out.append(math.degrees(unpack_command(data, profile.ranges).position_rad))
    return out


@pytest.mark.parametrize("name", ["dm_mit", "ak_mit"])
def test_a_silent_servo_goes_offline_and_comes_back(name: str) -> None:
    with running(CONFIG) as (bridge, port):
        peer = Peer(port)
        try:
            peer.gcs_heartbeat()  # a GCS: answer me
            assert wait_until(lambda: status(bridge, name).online, WAIT_S)
            device = sim_servo(bridge, name)
            mark = peer.count()
            device.faults.silent = True
            assert wait_until(lambda: not status(bridge, name).online, WAIT_S)
            assert wait_until(lambda: f"servo {name} offline" in peer.statustexts(mark), WAIT_S)
            assert status(bridge, "dm_pv").online  # the others keep answering
            device.faults.silent = False
            assert wait_until(lambda: status(bridge, name).online, WAIT_S)
        finally:
            peer.close()


GIMBAL = gimbal_config("cubemars-ak-mit", "damiao-dm")


@pytest.mark.parametrize(
    ("axis", "fault", "text"),
    [("pitch", "over_current", "over_current"), ("yaw", "over_temperature", "over_temperature")],
)
def test_a_fault_status_reaches_statustext_and_gimbal_failure_flags(
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
