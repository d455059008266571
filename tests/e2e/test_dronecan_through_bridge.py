"""DroneCAN servos through the whole bridge and back, and ``config/dronecan.yaml`` as shipped.

A GCS-side pymavlink peer sends DO_SET_SERVO over UDP; the bridge drives the aa55 interface on
the adapter emulator's pty; simulated DroneCAN servo nodes (made with the ``dronecan`` package)
take their entry of the bridge's ArrayCommand, move, and report Status and NodeStatus, which
come back over MAVLink. A servo node that falls silent goes offline once it has missed three
NodeStatus (never sooner, whatever its Status rate): STATUSTEXT, DO_SET_SERVO
TEMPORARILY_REJECTED; it comes back when it speaks. How fast is a timing goal, not judged here.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import can
import pytest

from mavservo.mavlink.connection import mavlink2
from mavservo.scheduling.runner import SchedulerObserver
from mavservo.servos.base import Fault
from tests.app.test_run_cli import REPO, run_mavservo
from tests.support.bridge import (
    MAV_CMD_DO_SET_SERVO,
    MAV_RESULT_ACCEPTED,
    MAV_RESULT_TEMPORARILY_REJECTED,
    Peer,
    named_values,
    pwm_to_angle,
    running,
    sim_servo,
)
from tests.support.waiting import wait_until

pytestmark = pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")

WAIT_S = 5.0
CONFIG = """
  telemetry: {actuator_output_status_hz: 10, named_value_float_hz: 20, esc_telemetry_hz: 0}
can:
  buses:
    - {name: bus0, interface: aa55, channel: sim, node: {dronecan: {node_id: 100}}}
servos:
  - {name: left, profile: dronecan, can_id: 11, limits_deg: [-45, 45], telemetry_hz: 10,
     options: {actuator_id: 1}}
  - {name: right, profile: dronecan, can_id: 12, limits_deg: [-45, 45], telemetry_hz: 10,
     options: {actuator_id: 2, command: unitless, unitless_min_deg: -45, unitless_max_deg: 45}}
scheduler: {reply_timeout_s: 0.5}
channels:
  - {servo: left, source: servo_output, channel: 1, input: {min: 1000, max: 2000},
     output_deg: [-45, 45]}
  - {servo: right, source: servo_output, channel: 2, input: {min: 1000, max: 2000},
     output_deg: [-45, 45]}
"""


#: How long the bridge keeps a silent DroneCAN servo online: offline_after_missed (default 3)
#: NodeStatus periods (1 s: uavcan.protocol.NodeStatus MAX_BROADCASTING_PERIOD_MS = 1000) plus
#: CONFIG's reply_timeout_s. The servo's Status at 10 Hz would give 3 x 0.1 + 0.5 s instead.
NODE_SILENCE_LIMIT_S = 3 * 1.0 + 0.5


def status(bridge, name: str):  # type: ignore[no-untyped-def]
    return next(s for s in bridge.backend.servo_statuses() if s.name == name)


@dataclass
class LastHeard(SchedulerObserver):
    """Scheduler observer: when the bridge last decoded a frame from each servo (its clock)."""

    at: dict[str, float] = field(default_factory=dict)

    def on_rx(self, bus: str, msg: Any, t: float, servo: str, state: Any) -> None:
        self.at[servo] = max(t, self.at.get(servo, t))


def test_dronecan_servos_follow_and_a_node_missing_its_node_status_goes_offline_and_back() -> None:
    heard = LastHeard()
    with running(CONFIG, observers=[heard]) as (bridge, port):
        peer = Peer(port)
        try:
            peer.send(mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))  # a GCS: answer me
            for pwm in (1700, 1300):
                target = pwm_to_angle(pwm, 1000, 2000, (-45, 45))
                for channel in (1, 2):
                    assert peer.command(MAV_CMD_DO_SET_SERVO, [channel, pwm]) == MAV_RESULT_ACCEPTED
                for name in ("left", "right"):
                    sim = sim_servo(bridge, name)
                    assert wait_until(lambda s=sim, a=target: abs(s.position_deg - a) < 0.3, WAIT_S)
                    assert wait_until(
                        lambda n=name, a=target: (
                            abs(status(bridge, n).state.position_deg - a) < 0.3
                        ),
                        WAIT_S,
                    ), status(bridge, name)
            # both commands went in one ArrayCommand per slot from the bridge's node
            scheduler = bridge.schedulers["bus0"]
            [node] = scheduler.nodes
            assert node.counters["command_transfers"] > 0
            assert node.counters["node_status"] >= 1

            left = sim_servo(bridge, "left")
            mark = peer.count()
            left.faults.silent = True
            assert wait_until(
                lambda: not status(bridge, "left").online, NODE_SILENCE_LIMIT_S + WAIT_S
            )
            seen_offline = time.monotonic()
            # offline by the NodeStatus rule: not before three heartbeats were missed (the
            # bridge's own receive times; a loaded machine only makes this later)
            silent_for = seen_offline - heard.at["left"]
            assert silent_for > NODE_SILENCE_LIMIT_S, silent_for
            assert Fault.NO_REPLY in status(bridge, "left").state.faults
            assert status(bridge, "right").online
            assert wait_until(lambda: "servo left offline" in peer.statustexts(mark), WAIT_S)
            assert peer.command(MAV_CMD_DO_SET_SERVO, [1, 1500]) == MAV_RESULT_TEMPORARILY_REJECTED
            left.faults.silent = False
            assert wait_until(lambda: status(bridge, "left").online, WAIT_S)
            assert peer.command(MAV_CMD_DO_SET_SERVO, [1, 1500]) == MAV_RESULT_ACCEPTED
            assert wait_until(lambda: abs(left.position_deg) < 0.3, WAIT_S)
        finally:
            peer.close()


#: DroneCAN Status carries position as float16 radians: one step of it at 0.5..1 rad
STATUS_RESOLUTION_DEG = math.degrees(2.0**-11)


def test_dronecan_position_and_status_reach_mavlink_telemetry() -> None:
    """What the DroneCAN servos report reaches a ground station over a real UDP MAVLink link:
    each servo's actuator Status position as NAMED_VALUE_FLOAT ``s<n>_pos`` (equal to where the
    simulated servo is, within float16) and as its ACTUATOR_OUTPUT_STATUS slot (normalised on
    the channel's +-45 deg, ``active`` bit set); its NodeStatus health as ``s<n>_flt``: 0 while
    OK, the OTHER bit (and a STATUSTEXT) once the node reports a warning, the other node's 0."""
    targets = {"left": (1, 1700), "right": (2, 1300)}  # servo -> (channel = n, PWM)
    # every name several times within WAIT_S: a wider link than a radio's default 1,000 B/s
    wide = "  link_budget_bytes_s: 20000\n"
    with running(CONFIG, extra_mavlink=wide) as (bridge, port):
        peer = Peer(port)
        try:
            peer.gcs_heartbeat()
            for channel, pwm in targets.values():
                assert peer.command(MAV_CMD_DO_SET_SERVO, [channel, pwm]) == MAV_RESULT_ACCEPTED
            sims = {name: sim_servo(bridge, name) for name in targets}
            for name, (_, pwm) in targets.items():
                target = pwm_to_angle(pwm, 1000, 2000, (-45, 45))
                assert wait_until(
                    lambda s=sims[name], a=target: (
                        abs(s.position_deg - a) < 0.3 and abs(s.velocity_dps) < 0.1
                    ),
                    WAIT_S,
                ), (name, sims[name].position_deg)
            mark = peer.count()
            assert wait_until(
                lambda: all(
                    len(named_values(peer.since(mark), f"s{n}_pos")) >= 3
                    and peer.since(mark, "ACTUATOR_OUTPUT_STATUS")
                    for n, _ in targets.values()
                ),
                WAIT_S,
            )
            received = peer.since(mark)
            [latest] = peer.since(mark, "ACTUATOR_OUTPUT_STATUS")[-1:]
            for name, (n, _) in targets.items():
                where = sims[name].position_deg
                for value in named_values(received, f"s{n}_pos")[-2:]:
                    assert abs(value - where) <= STATUS_RESOLUTION_DEG, (name, value, where)
                assert latest.active & (1 << (n - 1)), (name, latest.active)
                assert latest.actuator[n - 1] == pytest.approx(where / 45, abs=1e-3), name
                assert named_values(received, f"s{n}_flt")[-1] == 0, name

            mark = peer.count()
            sims["left"].faults.over_temperature = True  # the node's NodeStatus: WARNING
            other = float(Fault.OTHER.value)
            assert wait_until(lambda: other in named_values(peer.since(mark), "s1_flt"), WAIT_S), (
                named_values(peer.since(mark), "s1_flt")
            )
            assert wait_until(lambda: "servo left fault" in peer.joined_statustexts(mark), WAIT_S)
            assert set(named_values(peer.since(mark), "s2_flt")) == {0.0}
        finally:
            peer.close()


def test_shipped_dronecan_config_passes_check() -> None:
    proc = run_mavservo("check", str(REPO / "config" / "dronecan.yaml"))
    assert proc.returncode == 0, proc.stderr + proc.stdout


# config/dronecan.yaml run as shipped: tests/app/test_run_family_configs.py, beside the other
# examples' runs.


def test_another_array_command_sender_is_reported_once_by_statustext() -> None:
    """An autopilot commanding the same actuators on the bus: STATUSTEXT once, naming it."""
    import dronecan
    from dronecan.transport import Transfer

    with running(CONFIG) as (bridge, port):
        peer = Peer(port)
        try:
            peer.send(mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))  # a GCS: answer me
            actuator = dronecan.uavcan.equipment.actuator
            command = actuator.ArrayCommand(
                commands=[actuator.Command(actuator_id=2, command_type=1, command_value=0.1)]
            )
            scheduler = bridge.schedulers["bus0"]
            mark = peer.count()
            for tid in range(5):  # the frames the receive thread would hand over
                transfer = Transfer(transfer_id=tid, source_node_id=10, payload=command)
                for frame in transfer.to_frames():
                    msg = can.Message(
                        arbitration_id=frame.message_id, is_extended_id=True, data=frame.bytes
                    )
                    scheduler.handle_frame(msg, time.monotonic())
            # STATUSTEXT carries 50 characters: a longer text comes in chunks
            wanted = "DroneCAN node 10 also sends ArrayCommand for actuators 2"
            assert wait_until(lambda: wanted in peer.joined_statustexts(mark), WAIT_S), (
                peer.statustexts(mark)
            )
            time.sleep(0.5)
            assert peer.joined_statustexts(mark).count(wanted) == 1
        finally:
            peer.close()


ALLOCATING = """
  telemetry: {actuator_output_status_hz: 10, named_value_float_hz: 20, esc_telemetry_hz: 0}
can:
  buses:
    - {name: bus0, interface: aa55, channel: sim,
       node: {dronecan: {node_id: 100, allocator: true}}}
servos:
  - {name: fixed, profile: dronecan, can_id: 11, limits_deg: [-45, 45], telemetry_hz: 10,
     options: {actuator_id: 1}}
  - {name: asking, profile: dronecan, can_id: 42, limits_deg: [-45, 45], telemetry_hz: 10,
     options: {actuator_id: 2, unique_id: 000102030405060708090a0b0c0d0e0f}}
scheduler: {reply_timeout_s: 0.5}
channels:
  - {servo: fixed, source: servo_output, channel: 1, input: {min: 1000, max: 2000},
     output_deg: [-45, 45]}
  - {servo: asking, source: servo_output, channel: 2, input: {min: 1000, max: 2000},
     output_deg: [-45, 45]}
"""


def test_a_simulated_servo_without_an_id_gets_it_from_the_bridge_and_follows() -> None:
    with running(ALLOCATING) as (bridge, port):
        peer = Peer(port)
        try:
            asking = sim_servo(bridge, "asking")
            assert wait_until(lambda: asking._device.node_id == 42, WAIT_S)  # noqa: SLF001
            assert wait_until(lambda: status(bridge, "asking").online, WAIT_S)
            assert peer.command(MAV_CMD_DO_SET_SERVO, [2, 1750]) == MAV_RESULT_ACCEPTED
            target = pwm_to_angle(1750, 1000, 2000, (-45, 45))
            assert wait_until(lambda: abs(asking.position_deg - target) < 0.3, WAIT_S)
            [node] = bridge.schedulers["bus0"].nodes
            assert list(node.allocator.allocations) == [("000102030405060708090a0b0c0d0e0f", 42)]
        finally:
            peer.close()
