"""Servo health end to end (issue 33): each simulated fault on the built-in simulation, seen by
a MAVLink peer over real UDP.

The gimbal's pitch axis is an RMD-X (it reports current, temperature and, every few polls, its
supply voltage) driven by DO_SET_SERVO on channel 2; the peer sees the bridge's ``s1_hlt``
health bits, its STATUSTEXTs and GIMBAL_DEVICE_ATTITUDE_STATUS. For each fault: the bit, one
onset text for the episode, the gimbal's failure flag, and, once the fault is removed, all of
it cleared with exactly one clearing text. The four faults the simulated servo learns
(an obstruction, a slipped coupling, a supply sag, overheating under a held load) and a servo
too slow for its speed limit (not following).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from mavservo.mavlink.backend import Health
from mavservo.mavlink.connection import mavlink2
from mavservo.sim.servo import SimServo
from tests.support.bridge import (
    MAV_CMD_DO_SET_SERVO,
    MAV_RESULT_ACCEPTED,
    MAV_RESULT_TEMPORARILY_REJECTED,
    Peer,
    named_values,
    running,
    sim_servo,
    status,
)
from tests.support.waiting import WAIT_S, wait_until

MOTOR_ERROR = mavlink2.GIMBAL_DEVICE_ERROR_FLAGS_MOTOR_ERROR
POWER_ERROR = mavlink2.GIMBAL_DEVICE_ERROR_FLAGS_POWER_ERROR
CRITICAL, WARNING, NOTICE = 2, 4, 5  # MAV_SEVERITY

BODY = """
  telemetry: {gimbal_attitude_status_hz: 20, named_value_float_hz: 10, esc_telemetry_hz: 0,
              actuator_output_status_hz: 0}
  mirror: {servo_output_raw: false}
  link_budget_bytes_s: null
servos:
  - {name: pitch, profile: rmd-x, can_id: 1, limits_deg: [-90, 30], telemetry_hz: 20,
     options: {fault_poll_every: 4},
     health: {temperature_warning_c: 40, temperature_limit_c: 50, temperature_action: hold}}
channels:
  - {servo: pitch, source: servo_output, channel: 2, input: {min: 1000, max: 2000},
     output_deg: [-90, 30]}
gimbals:
  - {name: gimbal, component_id: 154, pitch: pitch, limits_deg: {pitch: [-90, 30]}}
scheduler: {reply_timeout_s: 0.5}
"""


def pwm_for(angle_deg: float) -> float:
    """DO_SET_SERVO value for ``angle_deg`` on channel 2 (1000..2000 us onto -90..30 deg)."""
    return 1000.0 + (angle_deg + 90.0) / 120.0 * 1000.0


def weaken(servo: SimServo) -> None:
    """A servo far slower than its speed limit (a stiff linkage, a failing motor): 5 deg/s."""
    servo.physics.max_speed_dps = 5.0


def strengthen(servo: SimServo) -> None:
    servo.physics.max_speed_dps = 720.0


def jam(servo: SimServo) -> None:
    servo.faults.jammed_at_deg = -10.0


def unjam(servo: SimServo) -> None:
    servo.faults.jammed_at_deg = None


def slip(servo: SimServo) -> None:
    servo.faults.slipping = True


def grip(servo: SimServo) -> None:
    servo.faults.slipping = False


def sag(servo: SimServo) -> None:
    servo.faults.supply_v = 18.0


def restore(servo: SimServo) -> None:
    servo.faults.supply_v = None


def heat(servo: SimServo) -> None:
    """A held load the winding cannot carry for long (40 degC/s at 2 A)."""
    servo.physics.load_current = 2.0
    servo.physics.heating_c_per_a2s = 10.0


def cool(servo: SimServo) -> None:
    servo.physics.load_current = 0.0
    servo.physics.heating_c_per_a2s = 0.0
    servo.physics.cooling_per_s = 1.0


Action = Callable[[SimServo], None]

CASES = {
    # fault: (inject, remove, health bit, onset text, clearing text, gimbal flag)
    "tracking": (weaken, strengthen, Health.TRACKING, "pitch: not following, ",
                 "pitch: following again", MOTOR_ERROR),
    "jammed": (jam, unjam, Health.JAMMED, "pitch: jammed at -10.0 deg", "pitch: moving again",
               MOTOR_ERROR),
    "slipping": (slip, grip, Health.SLIPPING, "pitch: slipping, motor", "pitch: no longer slipping",
                 MOTOR_ERROR),
    "supply": (sag, restore, Health.SUPPLY, "pitch: supply 18.0 V outside 20.4-27.6 V",
               "pitch: supply back in range", POWER_ERROR),
    "overheated": (heat, cool, Health.OVERHEATED, "pitch: overheated",
                   "pitch: temperature back below limit", MOTOR_ERROR),
}  # fmt: skip


def texts_with(peer: Peer, fragment: str, start: int) -> list[str]:
    return [t for t in peer.statustexts(start) if fragment in t]


def health_bits(peer: Peer, start: int) -> list[int]:
    return [int(v) for v in named_values(peer.since(start), "s1_hlt")]


def failure_flags(peer: Peer, start: int) -> list[int]:
    return [m.failure_flags for m in peer.since(start, "GIMBAL_DEVICE_ATTITUDE_STATUS")]


@pytest.mark.parametrize("fault", list(CASES))
def test_an_injected_fault_is_reported_once_and_cleared(fault: str) -> None:
    inject, remove, bit, onset, cleared, flag = CASES[fault]
    with running(BODY) as (bridge, port):
        peer = Peer(port)
        try:
            peer.gcs_heartbeat()
            assert wait_until(lambda: status(bridge, "pitch").online, WAIT_S)
            assert peer.command(MAV_CMD_DO_SET_SERVO, [2, pwm_for(0.0)]) == MAV_RESULT_ACCEPTED
            servo = sim_servo(bridge, "pitch")
            assert wait_until(lambda: abs(servo.position_deg) < 0.5, WAIT_S)
            mark = peer.count()
            assert not texts_with(peer, "pitch: ", 0), peer.statustexts(0)

            inject(servo)
            assert peer.command(MAV_CMD_DO_SET_SERVO, [2, pwm_for(-30.0)]) == MAV_RESULT_ACCEPTED
            assert wait_until(lambda: texts_with(peer, onset, mark), WAIT_S), peer.statustexts(mark)
            assert wait_until(lambda: any(b & bit.value for b in health_bits(peer, mark)), WAIT_S)
            assert wait_until(lambda: any(f & flag for f in failure_flags(peer, mark)), WAIT_S)
            assert bit in status(bridge, "pitch").health
            if fault == "overheated":  # the limit's action: hold, new setpoints refused
                result = peer.command(MAV_CMD_DO_SET_SERVO, [2, pwm_for(10.0)])
                assert result == MAV_RESULT_TEMPORARILY_REJECTED

            remove(servo)
            after = peer.count()
            assert wait_until(lambda: texts_with(peer, cleared, mark), WAIT_S), peer.statustexts(
                mark
            )
            assert wait_until(lambda: not status(bridge, "pitch").health, WAIT_S)
            # what the peer hears from now on is clear: no bit, no failure flag
            settled = peer.count()
            assert wait_until(
                lambda: (
                    len(health_bits(peer, settled)) >= 3 and len(failure_flags(peer, settled)) >= 5
                ),
                WAIT_S,
            )
            assert set(health_bits(peer, settled)) == {0}
            assert not any(f & (MOTOR_ERROR | POWER_ERROR) for f in failure_flags(peer, settled))
            assert after <= settled
            # exactly one onset text and one clearing text for the episode
            assert len(texts_with(peer, onset, mark)) == 1, peer.statustexts(mark)
            assert len(texts_with(peer, cleared, mark)) == 1, peer.statustexts(mark)
            severities = {
                m.text: m.severity for m in peer.since(mark, "STATUSTEXT") if m.text[:6] == "pitch:"
            }  # first chunks: the texts start with the servo's name
            critical = (Health.JAMMED, Health.SLIPPING, Health.OVERHEATED)
            onset_severity = CRITICAL if bit in critical else WARNING
            assert [v for k, v in severities.items() if onset in k] == [onset_severity]
            assert [v for k, v in severities.items() if cleared in k] == [NOTICE]
            if fault == "overheated":
                assert peer.command(MAV_CMD_DO_SET_SERVO, [2, pwm_for(10.0)]) == (
                    MAV_RESULT_ACCEPTED
                )
            summary: dict[str, Any] = bridge.summary()["health"]
            assert summary["episodes"]["pitch"][bit.name.lower()] == 1  # type: ignore[union-attr]
        finally:
            peer.close()
