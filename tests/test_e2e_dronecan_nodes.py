"""DroneCAN nodes as they are built (issue 28), through the whole bridge and back over MAVLink.

* One node with four actuators (an AP_Periph servo board style node id with four outputs):
  one ArrayCommand carries all four, each servo follows its own Status, nobody counts a
  sibling's Status as rejected, and the node dying takes all four offline together and back.
* A simulated ArduPilot-style peripheral (``firmware: ardupilot``; the simulator's behaviour is
  written from AP_Periph, see ``mavservo/servos/dronecan_sim.py``): with the bridge's
  SafetyState its outputs move, without it they stay off and the bridge says why.
* A node that ignores the command type: one warning, within a few seconds.
* ``config/dronecan-pwm.yaml``: the PWM command type on the built-in simulation, MAVLink
  telemetry back.

The CAN side is the adapter emulator's simulated bus (a pty, the aa55 protocol); the MAVLink
side a pymavlink peer over UDP on 127.0.0.1. Every wait is bounded.
"""

from __future__ import annotations

import time
from typing import Any

import pytest
from conftest import wait_until
from dronecan.transport import Frame, Transfer
from e2e_support import (
    MAV_CMD_DO_SET_SERVO,
    MAV_RESULT_ACCEPTED,
    Peer,
    Recorder,
    pwm_to_angle,
    running,
    status,
)

from mavservo.app.bridge import Bridge
from mavservo.servos.base import Fault
from mavservo.sim.autopilot.link import mavlink2
from mavservo.sim.servo import SimServo

pytestmark = pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")

WAIT_S = 6.0
NAMES = ("s1", "s2", "s3", "s4")
FOUR_ON_ONE_NODE = (
    """
  telemetry: {actuator_output_status_hz: 10, named_value_float_hz: 20, esc_telemetry_hz: 0}
can:
  buses:
    - {name: bus0, interface: aa55, channel: sim, node: {dronecan: {node_id: 100}}}
servos:
"""
    + "".join(
        f"""  - {{name: s{n}, profile: dronecan, can_id: 11, limits_deg: [-40, 40],
     telemetry_hz: 10, options: {{actuator_id: {n}}}}}
"""
        for n in range(1, 5)
    )
    + """scheduler: {reply_timeout_s: 0.5}
channels:
"""
    + "".join(
        f"""  - {{servo: s{n}, source: servo_output, channel: {n}, input: {{min: 1000, max: 2000}},
     output_deg: [-40, 40]}}
"""
        for n in range(1, 5)
    )
)


def node_servo(bridge: Bridge, name: str) -> SimServo:
    """The simulated servo behind ``name``, told apart by its actuator id as well (the four
    share node id 11)."""
    cfg = bridge.config.servo(name)
    for servo in bridge.emulators["bus0"].servos:
        if servo.can_id == cfg.can_id and servo.options == cfg.profile_options():
            return servo
    raise KeyError(name)


class Wire(Recorder):
    """Every frame the bridge wrote, in order, whatever servo the scheduler tied it to."""

    def __init__(self) -> None:
        super().__init__()
        self.written: list[tuple[int, bytes]] = []

    def on_tx(self, bus: str, msg: Any, t: float, kind: str, servo: str, seq: int | None) -> None:
        with self._lock:
            self.written.append((msg.arbitration_id, bytes(msg.data)))

    def array_commands(self) -> list[list[int]]:
        """The actuator ids of every ArrayCommand transfer written, decoded by the
        ``dronecan`` package."""
        with self._lock:
            written = list(self.written)
        out: list[list[int]] = []
        pending: list[Frame] = []
        for arb, data in written:
            if (arb >> 8) & 0xFFFF != 1010:  # uavcan.equipment.actuator.ArrayCommand
                continue
            pending.append(Frame(arb, data))
            if data[-1] & 0x40:  # end of transfer
                transfer = Transfer()
                transfer.from_frames(pending)
                pending = []
                out.append(sorted(int(c.actuator_id) for c in transfer.payload.commands))
        return out


def when_each(bridge: Bridge, names: tuple[str, ...], online: bool, limit_s: float) -> list[float]:
    """When each servo's online flag became ``online`` (polled every 10 ms, bounded)."""
    seen: dict[str, float] = {}
    deadline = time.monotonic() + limit_s
    for _ in range(int(limit_s / 0.01) + 1):
        now = time.monotonic()
        for name in names:
            if name not in seen and status(bridge, name).online == online:
                seen[name] = now
        if len(seen) == len(names) or now > deadline:
            break
        time.sleep(0.01)
    assert len(seen) == len(names), (online, seen)
    return [seen[name] for name in names]


def test_four_actuators_on_one_node_each_follow_their_own_status_and_go_offline_together() -> None:
    recorder = Wire()
    with running(FOUR_ON_ONE_NODE, observers=[recorder]) as (bridge, port):
        peer = Peer(port)
        try:
            peer.send(mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))  # a GCS: answer me
            pwms = {1: 1200, 2: 1400, 3: 1600, 4: 1800}
            for channel, pwm in pwms.items():
                assert peer.command(MAV_CMD_DO_SET_SERVO, [channel, pwm]) == MAV_RESULT_ACCEPTED
            for channel, pwm in pwms.items():
                name, target = f"s{channel}", pwm_to_angle(pwm, 1000, 2000, (-40, 40))
                sim = node_servo(bridge, name)
                assert wait_until(lambda s=sim, a=target: abs(s.position_deg - a) < 0.3, WAIT_S)
                assert wait_until(
                    lambda n=name, a=target: abs(status(bridge, n).state.position_deg - a) < 0.3,
                    WAIT_S,
                ), (name, status(bridge, name))
            # one ArrayCommand per slot carries all four
            transfers = recorder.array_commands()
            assert transfers and all(t == [1, 2, 3, 4] for t in transfers), transfers
            # each servo took its own Status (10 Hz); none counted a sibling's as rejected
            time.sleep(1.0)
            servos = {
                n: s["frames"] for n, s in bridge.schedulers["bus0"].metrics()["servos"].items()
            }
            for name in NAMES:
                assert servos[name]["received"] >= 10, servos[name]
                assert servos[name]["rejected"] == 0, (name, servos[name])

            # the node dies: all four offline together, and back together
            sims = [node_servo(bridge, name) for name in NAMES]
            for sim in sims:
                sim.faults.silent = True
            went = when_each(bridge, NAMES, False, WAIT_S)
            assert max(went) - min(went) < 0.3, went
            assert all(Fault.NO_REPLY in status(bridge, n).state.faults for n in NAMES)
            for sim in sims:
                sim.faults.silent = False
            back = when_each(bridge, NAMES, True, WAIT_S)
            assert max(back) - min(back) < 0.3, back
        finally:
            peer.close()
