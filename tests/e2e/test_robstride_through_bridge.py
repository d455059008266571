"""Robstride motors through the whole bridge and back, on the ``aa55`` interface over the adapter
emulator's pty.

A GCS-side pymavlink peer sends DO_SET_SERVO over UDP; the bridge starts the motors (private
protocol: stop/clear, CSP mode, canTimeout, report period, enable, limit_spd, active reports;
MIT protocol: the same in MIT frames), the simulated motors move and push their state, the
telemetry comes back over MAVLink. Checked: they follow with nothing lost; a position outside the
model's range is DENIED and counted and never reaches the bus; a motor that falls silent goes
offline and comes back; a fault bit in a report reaches STATUSTEXT and the gimbal failure flags;
a motor that answers in the other protocol, or never answers, is named with the likely cause.
"""

from __future__ import annotations

import math
import struct

import pytest

from mavservo.mavlink.connection import mavlink2
from mavservo.servos.robstride.profile import PARAM_LOC_REF, RobstrideOptions
from mavservo.servos.robstride.sim import RsMotorDevice
from tests.support.bridge import (
    MAV_CMD_DO_SET_SERVO,
    MAV_RESULT_ACCEPTED,
    MAV_RESULT_DENIED,
    Peer,
    Recorder,
    assert_fault_reaches_statustext_and_gimbal_flags,
    assert_nothing_lost,
    gimbal_config,
    named_values,
    pwm_to_angle,
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
  - {name: rs_private, profile: robstride, can_id: 1, limits_deg: [-800, 800], telemetry_hz: 20,
     max_speed_dps: 720, options: {model: RS01, comm_timeout_ms: 500}}
  - {name: rs_mit, profile: robstride, can_id: 2, limits_deg: [-90, 90], telemetry_hz: 20,
     options: {model: RS03, protocol: mit, kp: 60.0, kd: 2.0, comm_timeout_ms: 500}}
# a reply counts as lost only when it never comes: timing on a loaded machine is not judged here
scheduler: {reply_timeout_s: 0.5}
channels:
  - {servo: rs_private, source: servo_output, channel: 1, input: {min: 1000, max: 2000},
     output_deg: [-800, 800]}
  - {servo: rs_mit, source: servo_output, channel: 2, input: {min: 1000, max: 2000},
     output_deg: [-90, 90]}
"""

#: servo -> (NAMED_VALUE_FLOAT index, channel, PWM range of the channel's output)
SERVOS = {"rs_private": (1, 1, (-800.0, 800.0)), "rs_mit": (2, 2, (-90.0, 90.0))}
RESOLUTION_DEG = math.degrees(8 * math.pi / 65535)
"""One count of the private feedback's angle (+-4 pi); the MIT one (+-12.57 rad) is as fine."""


def test_both_protocols_follow_report_and_lose_nothing() -> None:
    recorder = Recorder()
    with running(CONFIG, observers=[recorder]) as (bridge, port):
        peer = Peer(port)
        try:
            for pwm in (1540, 1470):
                targets = {
                    name: pwm_to_angle(pwm, 1000, 2000, out) for name, (_, _, out) in SERVOS.items()
                }
                for name, (_, channel, _) in SERVOS.items():
                    result = peer.command(MAV_CMD_DO_SET_SERVO, [channel, pwm])
                    assert result == MAV_RESULT_ACCEPTED, name
                servos = {name: sim_servo(bridge, name) for name in SERVOS}
                assert wait_until(
                    lambda s=servos, t=targets: all(
                        abs(x.position_deg - t[n]) < 0.1 and abs(x.velocity_dps) < 0.5
                        for n, x in s.items()
                    ),
                    WAIT_S,
                ), {n: s.position_deg for n, s in servos.items()}
                mark = peer.count()
                assert wait_until(
                    lambda m=mark: all(
                        len(named_values(peer.since(m), f"s{n}_pos")) >= 3
                        for n, _, _ in SERVOS.values()
                    ),
                    WAIT_S,
                )
                for name, (n, _, _) in SERVOS.items():
                    for value in named_values(peer.since(mark), f"s{n}_pos")[-2:]:
                        assert abs(value - servos[name].position_deg) <= RESOLUTION_DEG + 0.05
        finally:
            peer.close()
        summary = bridge.stop()
    assert_nothing_lost(summary, SERVOS)


def test_a_position_outside_the_models_range_is_denied_counted_and_never_sent() -> None:
    """736 deg is inside limits_deg but outside the +-4 pi rad (720 deg) the motor reports:
    DENIED, counted under the profile's name, and no loc_ref for it goes out."""
    recorder = Recorder()
    with running(CONFIG, observers=[recorder]) as (bridge, port):
        peer = Peer(port)
        try:
            assert peer.command(MAV_CMD_DO_SET_SERVO, [1, 1960]) == MAV_RESULT_DENIED
            assert peer.command(MAV_CMD_DO_SET_SERVO, [1, 1600]) == MAV_RESULT_ACCEPTED
            assert wait_until(lambda: loc_refs(recorder), WAIT_S)
        finally:
            peer.close()
        summary = bridge.stop()
    assert recorder.angles("rs_private") == [pytest.approx(160.0)]
    sent = loc_refs(recorder)
    assert sent and all(a == pytest.approx(160.0, abs=1e-3) for a in sent), sent
    commands = summary["mavlink"]["commands"]
    assert commands["result_denied"] == 1, commands
    assert commands["reason_robstride"] == 1, commands


def loc_refs(recorder: Recorder) -> list[float]:
    """Angles of the loc_ref writes that went to the private-protocol motor (decoded here)."""
    out = []
    for kind, arbitration_id, data in recorder.frames("rs_private"):
        if kind.startswith("command") and arbitration_id >> 24 == 0x12 and len(data) == 8:
            index, _, value = struct.unpack("<HHf", data)
            if index == PARAM_LOC_REF:
                out.append(math.degrees(value))
    return out


@pytest.mark.parametrize("name", ["rs_private", "rs_mit"])
def test_a_silent_motor_goes_offline_and_comes_back(name: str) -> None:
    with running(CONFIG) as (bridge, port):
        peer = Peer(port)
        try:
            peer.gcs_heartbeat()  # a GCS: answer me
            _, channel, _ = SERVOS[name]
            assert peer.command(MAV_CMD_DO_SET_SERVO, [channel, 1500]) == MAV_RESULT_ACCEPTED
            assert wait_until(lambda: status(bridge, name).online, WAIT_S)
            device = sim_servo(bridge, name)
            mark = peer.count()
            device.faults.silent = True
            assert wait_until(lambda: not status(bridge, name).online, WAIT_S)
            assert wait_until(lambda: f"servo {name} offline" in peer.statustexts(mark), WAIT_S)
            device.faults.silent = False
            assert wait_until(lambda: status(bridge, name).online, WAIT_S)
        finally:
            peer.close()


def test_a_motor_stopped_by_its_own_timeout_is_enabled_again() -> None:
    """The motor's canTimeout fires while the bridge sends nothing (a stalled host): it stops,
    its reports say "reset mode", and the bridge enables it again; the next command moves it."""
    with running(CONFIG) as (bridge, port):
        peer = Peer(port)
        try:
            assert peer.command(MAV_CMD_DO_SET_SERVO, [1, 1510]) == MAV_RESULT_ACCEPTED
            device = sim_servo(bridge, "rs_private")
            assert wait_until(lambda: device.enabled, WAIT_S)
            device.disable(device.time or 0.0)  # what the timeout does (the host never stalls)
            assert wait_until(lambda: device.enabled, WAIT_S)  # re-enabled by the bridge
            target = pwm_to_angle(1530, 1000, 2000, (-800.0, 800.0))
            assert peer.command(MAV_CMD_DO_SET_SERVO, [1, 1530]) == MAV_RESULT_ACCEPTED
            assert wait_until(lambda: abs(device.position_deg - target) < 0.1, WAIT_S)
        finally:
            peer.close()


def test_a_motor_speaking_the_other_protocol_is_named_with_the_cause() -> None:
    """The config says private; the motor was switched to MIT and reports in it: the bridge
    says so once (log, event, STATUSTEXT) instead of showing a silent servo."""
    with running(CONFIG) as (bridge, port):
        peer = Peer(port)
        try:
            peer.gcs_heartbeat()
            mark = peer.count()
            device = sim_servo(bridge, "rs_private")
            mit_motor = RsMotorDevice(device, 1, RobstrideOptions(protocol="mit"))
            mit_motor.reporting = True  # left on by an earlier session
            device._device = mit_motor  # noqa: SLF001 - the motor switched protocol
            assert peer.command(MAV_CMD_DO_SET_SERVO, [1, 1510]) == MAV_RESULT_ACCEPTED
            assert wait_until(
                lambda: any(
                    t.startswith("servo rs_private: answers in the MIT")
                    for t in peer.statustexts(mark)
                ),
                WAIT_S,
            ), peer.statustexts(mark)
            assert any("options.protocol: mit" in text for _, text in bridge.events)
            assert status(bridge, "rs_private").state is None  # never taken for its answer
        finally:
            peer.close()


def test_a_motor_that_never_answers_is_named_with_what_to_check() -> None:
    with running(CONFIG) as (bridge, port):
        peer = Peer(port)
        try:
            peer.gcs_heartbeat()
            mark = peer.count()
            device = sim_servo(bridge, "rs_mit")
            device._device = RsMotorDevice(device, 2, RobstrideOptions())  # noqa: SLF001
            assert peer.command(MAV_CMD_DO_SET_SERVO, [2, 1510]) == MAV_RESULT_ACCEPTED
            assert wait_until(
                lambda: any(
                    t.startswith("servo rs_mit: robstride motor id 2 never")
                    for t in peer.statustexts(mark)
                ),
                WAIT_S,
            ), peer.statustexts(mark)
            assert any("switched to the private protocol" in t for _, t in bridge.events)
        finally:
            peer.close()


GIMBAL = gimbal_config("robstride", "robstride", "{model: RS00}")


@pytest.mark.parametrize(
    ("axis", "fault", "text"),
    [("pitch", "over_current", "over_current"), ("yaw", "over_temperature", "over_temperature")],
)
def test_a_fault_bit_reaches_statustext_and_gimbal_failure_flags(
    axis: str, fault: str, text: str
) -> None:
    with running(GIMBAL) as (bridge, port):
        peer = Peer(port)
        try:
            peer.gcs_heartbeat()
            # a pushing motor reports once started, and it is started before its first command
            attitude = mavlink2.MAVLink_gimbal_device_set_attitude_message(
                1, 154, 0, [1.0, 0.0, 0.0, 0.0], math.nan, math.nan, math.nan
            )
            assert wait_until(
                lambda: peer.send(attitude) or status(bridge, axis).state is not None, WAIT_S
            )
            assert_fault_reaches_statustext_and_gimbal_flags(
                bridge, peer, axis, fault, text, WAIT_S
            )
        finally:
            peer.close()
