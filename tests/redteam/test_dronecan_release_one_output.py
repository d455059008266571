"""Red-team finding (review of issue 28): releasing one output of an ArduPilot peripheral.

AP_Periph zeroes its outputs only when no valid ArrayCommand at all has come for
SRV_CMD_TIME_OUT (``Tools/AP_Periph/can.cpp`` ``handle_act_command`` stamps
``actuator.last_command_ms`` for any UNITLESS/PWM entry, whatever its actuator id;
``rc_out.cpp`` ``rcout_update``). Releasing one servo of the board by no longer commanding it
(failsafe ``release``, the health monitor's ``release``) while its siblings are still commanded
left its output driving at its last pulse: "released", and still holding. The bridge now sends
that actuator PWM 0 (what the board's own timeout writes), through the bus node's ArrayCommand.
Simulated ArduPilot-style node on the adapter emulator's bus, MAVLink over UDP on 127.0.0.1.
"""

from __future__ import annotations

import time

import pytest

from mavservo.mavlink.connection import mavlink2
from tests.e2e.test_dronecan_nodes import WAIT_S, Wire, ardupilot_board, node_servo
from tests.support.bridge import MAV_CMD_DO_SET_SERVO, MAV_RESULT_ACCEPTED, Peer, running
from tests.support.waiting import wait_until

pytestmark = pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")


@pytest.mark.parametrize("command", ["unitless", "pwm"])
def test_a_released_output_of_a_board_goes_limp_while_its_sibling_is_commanded(
    command: str,
) -> None:
    with running(ardupilot_board("safety_off", command)) as (bridge, port):
        peer = Peer(port)
        try:
            peer.send(mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
            for channel, pwm in ((1, 1800), (2, 1300)):
                assert peer.command(MAV_CMD_DO_SET_SERVO, [channel, pwm]) == MAV_RESULT_ACCEPTED
            released, sibling = node_servo(bridge, "s1"), node_servo(bridge, "s2")
            # the board's output state (the simulated node is the fixture; the motor behind
            # it goes limp when the output stops)
            output = released._device  # noqa: SLF001
            assert wait_until(lambda: output.output_on and sibling._device.output_on, WAIT_S)  # noqa: SLF001
            bridge.schedulers["bus0"].release("s1")
            # the sibling's refreshes go on (every slot): the board's own timeout never fires
            assert wait_until(lambda: not output.output_on and not released.enabled, WAIT_S)
            assert sibling._device.output_on and sibling.enabled  # noqa: SLF001
            # a fresh command drives it again
            assert peer.command(MAV_CMD_DO_SET_SERVO, [1, 1700]) == MAV_RESULT_ACCEPTED
            assert wait_until(lambda: output.output_on and released.enabled, WAIT_S)
        finally:
            peer.close()


BOARD_IN_FAILSAFE = ardupilot_board("safety_off", "pwm").replace(
    "safety_state: safety_off", "safety_state: safety_off, safety_on: failsafe_and_stop"
)


@pytest.mark.parametrize("action", ["neutral", "hold"])
def test_safety_goes_on_in_failsafe_whatever_the_servos_failsafe_action(action: str) -> None:
    """``safety_on: failsafe_and_stop`` (``check``: "SAFETY_ON while every servo of the bus is
    in failsafe"): with ``failsafe: hold`` the held setpoints kept their MAVLink source, the
    node never saw the bus in failsafe and kept broadcasting SAFETY_OFF (3 of 3 in 1.5 s),
    outputs driving."""
    failsafe = f"failsafe: {{action: {action}, timeout_s: 0.2}},"
    body = BOARD_IN_FAILSAFE.replace("telemetry_hz: 10,", f"telemetry_hz: 10, {failsafe}")
    wire_log = Wire()
    with running(body, observers=[wire_log]) as (bridge, port):
        peer = Peer(port)
        try:
            peer.send(mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
            for channel, pwm in ((1, 1800), (2, 1300)):
                assert peer.command(MAV_CMD_DO_SET_SERVO, [channel, pwm]) == MAV_RESULT_ACCEPTED
            outputs = [node_servo(bridge, name)._device for name in ("s1", "s2")]  # noqa: SLF001
            assert wait_until(lambda: all(o.output_on for o in outputs), WAIT_S)
            mark = len(wire_log.written)
            assert bridge.backend is not None
            bridge.backend.enter_failsafe("test", time.monotonic())
            assert wait_until(lambda: not any(o.output_on for o in outputs), WAIT_S)
            with wire_log._lock:  # noqa: SLF001
                written = wire_log.written[mark:]
            states = [data[0] for arb, data in written if (arb >> 8) & 0xFFFF == 20000]
            assert states and states[-1] == 0, states  # SAFETY_ON
        finally:
            peer.close()
