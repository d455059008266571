"""The trial's outage end to end: while the USB-CAN adapter is unplugged the servos read offline
and commands to them are refused, and nothing commanded during the outage runs after it.

The trial: with the adapter away the console showed ``aileron online ... age 15030 ms``,
ACTUATOR_OUTPUT_STATUS kept the frozen position active, and a DO_SET_SERVO sent during the
outage was ACCEPTED and moved the payload servo ~12 s after its ACK, when the adapter came back.
Real parts: a pymavlink GCS over UDP, the bridge, aa55 on the adapter emulator's pty, simulated
servos; every wait is bounded.
"""

from __future__ import annotations

import math

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

pytestmark = pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")

HOOK = """
servos:
  - {name: hook, profile: rmd-x, can_id: 1, limits_deg: [-90, 90], telemetry_hz: 10}
channels:
  - {servo: hook, source: servo_output, channel: 1, output_deg: [-90, 90]}
"""
WAIT_S = 5.0


def pwm_for(angle: float) -> float:
    return 1500 + angle / 90.0 * 400


def status(bridge, name: str):
    return next(s for s in bridge.backend.servo_statuses() if s.name == name)


def test_commands_during_an_adapter_outage_are_refused_and_never_run_after_it() -> None:
    with running(HOOK) as (bridge, port):
        peer = Peer(port)
        try:
            assert peer.command(MAV_CMD_DO_SET_SERVO, [1, pwm_for(30)]) == MAV_RESULT_ACCEPTED
            servo = sim_servo(bridge, "hook")
            assert wait_until(lambda: abs(servo.position_deg - 30) < 0.05, WAIT_S)
            emulator = bridge.emulators["bus0"]
            mark = peer.count()

            emulator.unplug()
            assert wait_until(lambda: not status(bridge, "hook").online, WAIT_S)
            assert wait_until(
                lambda: any("offline" in t for t in peer.statustexts(mark)), WAIT_S
            ), peer.statustexts(mark)
            aos_mark = peer.count()
            assert wait_until(lambda: peer.since(aos_mark, "ACTUATOR_OUTPUT_STATUS"), WAIT_S)
            aos = peer.since(aos_mark, "ACTUATOR_OUTPUT_STATUS")[-1]
            assert aos.active & 1 == 0 and math.isnan(aos.actuator[0])  # no frozen position
            refused = peer.command(MAV_CMD_DO_SET_SERVO, [1, pwm_for(-60)])
            assert refused == MAV_RESULT_TEMPORARILY_REJECTED

            emulator.replug()
            assert wait_until(lambda: status(bridge, "hook").online, 8.0)
            commands = servo.commands
            assert wait_until(lambda: servo.commands > commands + 5, WAIT_S)  # refreshes again
            assert servo.target_deg == pytest.approx(30.0)  # the refused command never ran
            assert peer.command(MAV_CMD_DO_SET_SERVO, [1, pwm_for(-45)]) == MAV_RESULT_ACCEPTED
            assert wait_until(lambda: abs(servo.position_deg + 45) < 0.05, WAIT_S)
        finally:
            peer.close()
