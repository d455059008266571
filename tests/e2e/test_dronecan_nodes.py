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

import dataclasses
import math
import time
from typing import Any

import can
import pytest
from dronecan.transport import Frame, Transfer

from mavservo.app.bridge import Bridge
from mavservo.mavlink.connection import mavlink2
from mavservo.servos.base import Fault
from mavservo.sim.servo import SimServo
from tests.app.test_run_cli import REPO, run_mavservo
from tests.support.bridge import (
    MAV_CMD_DO_SET_SERVO,
    MAV_RESULT_ACCEPTED,
    Peer,
    Recorder,
    pwm_to_angle,
    running,
    status,
)
from tests.support.waiting import wait_until

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


def says(peer: Peer, mark: int, text: str, wait_s: float = WAIT_S) -> None:
    """The ground station hears ``text`` (STATUSTEXT, chunks joined) within ``wait_s``."""
    assert wait_until(lambda: text in peer.joined_statustexts(mark), wait_s), peer.statustexts(mark)


def position(bridge: Bridge, name: str) -> float:
    """The bridge's last reported position of ``name`` (NaN before its first report)."""
    state = status(bridge, name).state
    return math.nan if state is None else float(state.position_deg)


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
                    lambda n=name, a=target: abs(position(bridge, n) - a) < 0.3,
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


def ardupilot_board(safety: str, command: str = "unitless", firmware: str = "ardupilot") -> str:
    """Two outputs of an ArduPilot peripheral (node 20, actuators 1 and 2), bridge node 100."""
    return f"""
  telemetry: {{actuator_output_status_hz: 10, named_value_float_hz: 20, esc_telemetry_hz: 0}}
can:
  buses:
    - {{name: bus0, interface: aa55, channel: sim,
       node: {{dronecan: {{node_id: 100, safety_state: {safety}}}}}}}
servos:
  - {{name: s1, profile: dronecan, can_id: 20, limits_deg: [-40, 40], telemetry_hz: 10,
     options: {{actuator_id: 1, firmware: {firmware}, command: {command}}}}}
  - {{name: s2, profile: dronecan, can_id: 20, limits_deg: [-40, 40], telemetry_hz: 10,
     options: {{actuator_id: 2, firmware: {firmware}, command: {command}}}}}
scheduler: {{reply_timeout_s: 0.5}}
channels:
  - {{servo: s1, source: servo_output, channel: 1, input: {{min: 1000, max: 2000}},
     output_deg: [-40, 40]}}
  - {{servo: s2, source: servo_output, channel: 2, input: {{min: 1000, max: 2000}},
     output_deg: [-40, 40]}}
"""


@pytest.mark.parametrize("command", ["unitless", "pwm"])
def test_an_ardupilot_peripheral_moves_with_the_bridges_safety_state(command: str) -> None:
    """SAFETY_OFF every 500 ms from the bridge: the peripheral's outputs drive the servos, and
    its Status (norm x 45 deg, ArduPilot's preset) reads back the angle commanded."""
    wire_log = Wire()
    with running(ardupilot_board("safety_off", command), observers=[wire_log]) as (bridge, port):
        peer = Peer(port)
        try:
            peer.send(mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
            for channel, pwm in ((1, 1800), (2, 1300)):
                assert peer.command(MAV_CMD_DO_SET_SERVO, [channel, pwm]) == MAV_RESULT_ACCEPTED
            for name, pwm in (("s1", 1800), ("s2", 1300)):
                target = pwm_to_angle(pwm, 1000, 2000, (-40, 40))
                sim = node_servo(bridge, name)
                assert wait_until(lambda s=sim, a=target: abs(s.position_deg - a) < 0.5, WAIT_S)
                assert wait_until(
                    lambda n=name, a=target: abs(position(bridge, n) - a) < 0.5,
                    WAIT_S,
                ), (name, status(bridge, name))
            [node] = bridge.schedulers["bus0"].nodes
            assert wait_until(lambda: node.counters["safety_off"] >= 3, WAIT_S)  # every 500 ms
        finally:
            peer.close()
    # the bridge stopped: its last SafetyState written is SAFETY_ON (safety_on: stop)
    states = [
        data[0] for arb, data in wire_log.written if (arb >> 8) & 0xFFFF == 20000
    ]  # ardupilot.indication.SafetyState: one byte and the tail
    assert states[0] == 255 and states[-1] == 0 and states.count(0) == 1, states


def test_without_the_safety_state_an_ardupilot_peripheral_stays_off_and_the_bridge_says_why() -> (
    None
):
    with running(ardupilot_board("none")) as (bridge, port):
        peer = Peer(port)
        try:
            peer.send(mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
            mark = peer.count()
            assert peer.command(MAV_CMD_DO_SET_SERVO, [1, 1800]) == MAV_RESULT_ACCEPTED
            target = pwm_to_angle(1800, 1000, 2000, (-40, 40))
            # the node reports the commanded norm (as AP_Periph does) ...
            assert wait_until(lambda: abs(position(bridge, "s1") - target) < 0.5, WAIT_S)
            # ... while its output stays off: the servo never moved
            sim = node_servo(bridge, "s1")
            assert abs(sim.position_deg) < 0.5 and sim.commands == 0
            wanted = "SAFETY_OFF"
            says(peer, mark, wanted, WAIT_S)
        finally:
            peer.close()


def test_a_node_that_ignores_the_command_type_is_warned_about_once_within_seconds() -> None:
    """The bridge sends POSITION (generic firmware in its config) to a node that acts on
    UNITLESS and PWM only: the node stays alive on NodeStatus, no Status ever comes for the
    actuator; one warning per servo, within a few seconds."""
    body = ardupilot_board("safety_off", command="position", firmware="generic")
    with running(body) as (bridge, port):
        for sim in bridge.emulators["bus0"].servos:  # the real node runs ArduPilot firmware
            device = sim._device  # noqa: SLF001 - the simulated node's firmware is the fixture
            device.options = dataclasses.replace(device.options, firmware="ardupilot")
            device.node.firmware, device.node.safety_off = "ardupilot", False
        peer = Peer(port)
        try:
            peer.send(mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
            mark = peer.count()
            started = time.monotonic()
            for channel in (1, 2):
                assert peer.command(MAV_CMD_DO_SET_SERVO, [channel, 1800]) == MAV_RESULT_ACCEPTED
            wanted = "check the command type"
            says(peer, mark, wanted, WAIT_S + 2)
            assert time.monotonic() - started < 6.0
            assert status(bridge, "s1").online  # alive on NodeStatus alone
            time.sleep(1.5)
            [node] = bridge.schedulers["bus0"].nodes
            assert node.counters["silent_actuators"] == 2  # once per servo, not again
        finally:
            peer.close()


# config/dronecan-pwm.yaml run as shipped: tests/app/test_run_family_configs.py, beside the
# other examples' runs.


def test_check_prints_the_safety_plan_the_id_convention_and_each_familys_stop() -> None:
    proc = run_mavservo("check", str(REPO / "config" / "dronecan-pwm.yaml"))
    assert proc.returncode == 0, proc.stderr + proc.stdout
    out = proc.stdout
    assert "SafetyState: SAFETY_OFF every 500 ms from start" in out
    assert "SAFETY_ON when the bridge stops" in out
    assert "zeroes its PWM output 200 ms after the last ArrayCommand" in out


def test_measured_load_over_max_load_is_warned_naming_other_nodes_traffic() -> None:
    """A sensor node broadcasting 300 frames/s on a 250 kbit/s bus (about 19 %): the bridge's
    plan is far below max_load 0.12, the measured load is not; one warning that says the most
    is other nodes' traffic."""
    body = """
  telemetry: {actuator_output_status_hz: 10, named_value_float_hz: 5, esc_telemetry_hz: 0}
can:
  buses:
    - {name: bus0, interface: aa55, channel: sim, bitrate: 250000, max_load: 0.12,
       node: {dronecan: {node_id: 100}}}
servos:
  - {name: s1, profile: dronecan, can_id: 11, limits_deg: [-40, 40], telemetry_hz: 10,
     options: {actuator_id: 1}}
scheduler: {reply_timeout_s: 0.5}
channels:
  - {servo: s1, source: servo_output, channel: 1, input: {min: 1000, max: 2000},
     output_deg: [-40, 40]}
"""
    sensor = can.Message(
        arbitration_id=(24 << 24) | (1028 << 8) | 50, is_extended_id=True, data=bytes(8)
    )
    with running(body) as (bridge, port):
        peer = Peer(port)
        try:
            peer.send(mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
            mark = peer.count()
            emulator = bridge.emulators["bus0"]
            wanted = "most is other nodes' traffic"
            deadline = time.monotonic() + WAIT_S
            for _ in range(200):  # 30 frames every 100 ms, until the warning (bounded)
                emulator.inject([sensor] * 30)
                time.sleep(0.1)
                if wanted in peer.joined_statustexts(mark) or time.monotonic() > deadline:
                    break
            texts = peer.joined_statustexts(mark)
            assert wanted in texts, texts
            assert "is over max_load 12%" in texts
        finally:
            peer.close()
