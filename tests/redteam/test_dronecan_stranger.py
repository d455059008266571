"""DroneCAN against a stranger on the bus (issue 32, item 7), over the adapter emulator's
simulated CAN bus with the whole bridge, MAVLink on UDP 127.0.0.1:

* allocation: made-up unique ids get at most ``allocation_max_entries`` ids and at most six
  a minute; an id whose node never speaks is free again after 10 s, and never saved; when no id
  can be handed out the ground station hears it (STATUSTEXT); node ids heard on the bus (one
  NodeStatus per id) stop blocking allocation when they fall silent;
* an ArrayCommand carrying the bridge's own node id is a stranger's (CAN does not echo the
  bridge's frames): counted and reported;
* spoofed NodeStatus frames with a servo's node id keep nobody's latency: only the servo's own
  Status (a whole transfer, its actuator) answers a command.

The attacker's frames are built by the ``dronecan`` package and put on the simulated bus as a
foreign node's (``AdapterEmulator.inject``). Pure-node checks of the same rules run on fake
time. Every wait is bounded.
"""

from __future__ import annotations

import time
from typing import Any

import can
import dronecan
import pytest
from dronecan.transport import Transfer

from mavservo.app.bridge import Bridge
from mavservo.mavlink.connection import mavlink2
from mavservo.servos.dronecan import wire
from mavservo.servos.dronecan.alloc import AllocationServer
from mavservo.servos.dronecan.profile import DroneCanServo
from tests.e2e.test_dronecan_nodes import says
from tests.support.bridge import MAV_CMD_DO_SET_SERVO, MAV_RESULT_ACCEPTED, Peer, running, status
from tests.support.waiting import wait_until

pytestmark = pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")

WAIT_S = 6.0
Allocation = dronecan.uavcan.protocol.dynamic_node_id.Allocation


def frames(payload: Any, source: int, tid: int, **kw: Any) -> list[can.Message]:
    transfer = Transfer(transfer_id=tid & 0x1F, source_node_id=source, payload=payload, **kw)
    return [
        can.Message(arbitration_id=f.message_id, is_extended_id=True, data=bytes(f.bytes))
        for f in transfer.to_frames()
    ]


def allocation_parts(unique_id: bytes, tid: int) -> list[list[can.Message]]:
    """The three anonymous requests of one allocation exchange for ``unique_id``."""
    out = []
    for stage, (start, end) in enumerate(((0, 6), (6, 12), (12, 16))):
        allocation = Allocation(node_id=0, first_part_of_unique_id=stage == 0)
        allocation.unique_id.from_bytes(unique_id[start:end])
        out.append(frames(allocation, 0, tid + stage, discriminator=0x2222, transfer_priority=30))
    return out


def made_up(n: int) -> bytes:
    return bytes([0xE0, n & 0xFF]) + bytes(range(14))


def attack_allocations(bridge: Bridge, count: int, first: int = 0) -> None:
    """``count`` exchanges with made-up unique ids, each part 200 ms after the previous (the
    allocator answers six requests a second: two whole exchanges)."""
    emulator = bridge.emulators["bus0"]
    for n in range(first, first + count):
        for part in allocation_parts(made_up(n), 3 * n):
            emulator.inject(part)
            time.sleep(0.2)


BODY = """
  telemetry: {actuator_output_status_hz: 10, named_value_float_hz: 5, esc_telemetry_hz: 0}
can:
  buses:
    - {name: bus0, interface: aa55, channel: sim,
       node: {dronecan: {node_id: 100, allocator: true, allocation_max_entries: 2,
                         allocation_expire_s: 5}}}
servos:
  - {name: s1, profile: dronecan, can_id: 11, limits_deg: [-40, 40], telemetry_hz: 10,
     options: {actuator_id: 1}}
scheduler: {reply_timeout_s: 0.5}
channels:
  - {servo: s1, source: servo_output, channel: 1, input: {min: 1000, max: 2000},
     output_deg: [-40, 40]}
"""


PLAIN = BODY.replace(
    "allocator: true, allocation_max_entries: 2,\n                         allocation_expire_s: 5",
    "allocator: false",
)
"""The same bus without the allocator: what every release of the bridge can run."""


def test_made_up_unique_ids_get_a_bounded_pool_and_the_ground_station_hears_when_it_is_empty(
    tmp_path: Any,
) -> None:
    with running(BODY) as (bridge, port):
        peer = Peer(port)
        try:
            peer.send(mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
            mark = peer.count()
            [node] = bridge.schedulers["bus0"].nodes
            server = node.allocator
            for n in range(8):  # one exchange at a time until one is refused (bounded)
                attack_allocations(bridge, 1, first=n)
                if server.refused:
                    break
            assert len(server.table) == 2, server.table  # the cap
            assert server.refused >= 1
            wanted = "no free node id left"
            says(peer, mark, wanted, WAIT_S)
            # the made-up ids never speak: nothing of them is saved (and they are free again
            # UNCONFIRMED_EXPIRE_S after they were handed out: the fake-time test below)
            assert node.persistent_state() == (server.version, {"allocation_table": {}})
        finally:
            peer.close()


def test_node_ids_heard_once_stop_blocking_allocation_when_they_fall_silent() -> None:
    """125 NodeStatus frames, one per id, filled the "seen" set for good; now it empties
    ``allocation_expire_s`` (5 s here) after they stop, and a new node gets an id."""
    with running(BODY) as (bridge, port):
        emulator = bridge.emulators["bus0"]
        status_msg = dronecan.uavcan.protocol.NodeStatus(uptime_sec=10)
        for node_id in range(1, 128):
            if node_id != 100:
                emulator.inject(frames(status_msg, node_id, 0, transfer_priority=30))
        [node] = bridge.schedulers["bus0"].nodes
        server = node.allocator
        assert wait_until(lambda: len(server.seen_ids) >= 120, WAIT_S)
        attack_allocations(bridge, 1)
        assert not server.table  # nothing free while they all look alive
        # only the config's servo (node 11, reserved anyway) keeps speaking
        assert wait_until(lambda: set(server.seen_ids) <= {11}, 5.0 + 3.0), server.seen_ids
        for n in range(1, 4):  # an exchange may meet the answer limit on a loaded machine
            attack_allocations(bridge, 1, first=n)
            if wait_until(lambda: len(server.table) == 1, 1.0):
                break
        assert len(server.table) == 1, server.table


def test_an_array_command_with_the_bridges_own_node_id_is_a_strangers_and_reported() -> None:
    with running(PLAIN) as (bridge, port):
        peer = Peer(port)
        try:
            peer.send(mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
            mark = peer.count()
            actuator = dronecan.uavcan.equipment.actuator
            command = actuator.ArrayCommand(
                commands=[actuator.Command(actuator_id=1, command_type=1, command_value=0.5)]
            )
            for tid in range(3):
                bridge.emulators["bus0"].inject(frames(command, 100, tid))
            [node] = bridge.schedulers["bus0"].nodes
            assert wait_until(lambda: node.counters["own_id_commands"] == 3, WAIT_S)
            wanted = "with the bridge's own node id 100"
            says(peer, mark, wanted, WAIT_S)
        finally:
            peer.close()


def test_spoofed_node_status_frames_are_no_servos_replies_for_its_latency() -> None:
    """The servo's node is silent; a stranger sends NodeStatus with its node id after every
    command: the servo looks alive (it cannot be told apart), but no latency is measured from
    those frames, and neither command round trip closes."""
    with running(PLAIN) as (bridge, port):
        peer = Peer(port)
        try:
            peer.send(mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
            scheduler = bridge.schedulers["bus0"]
            assert wait_until(lambda: status(bridge, "s1").online, WAIT_S)
            sim = next(iter(bridge.emulators["bus0"].servos))
            sim.faults.silent = True
            before = scheduler.metrics()["servos"]["s1"]["latency_s"]["n"]
            assert peer.command(MAV_CMD_DO_SET_SERVO, [1, 1700]) == MAV_RESULT_ACCEPTED
            heartbeat = dronecan.uavcan.protocol.NodeStatus(uptime_sec=100)
            for tid in range(20):
                heartbeat.uptime_sec = 100 + tid
                bridge.emulators["bus0"].inject(frames(heartbeat, 11, tid, transfer_priority=30))
                time.sleep(0.05)
            after = scheduler.metrics()["servos"]["s1"]["latency_s"]["n"]
            assert after == before, (before, after)
            assert status(bridge, "s1").online  # a sign of life it is, an answer it is not
        finally:
            peer.close()


# ---------------------------------------------------------------------- the rules, fake time
def exchange(server: AllocationServer, unique_id: bytes, now: float) -> int:
    """One whole exchange; the node id handed out (0: none)."""
    given = 0
    answers = wire.Reassembler()
    for index, part in enumerate(allocation_parts(unique_id, 0)):
        received = wire.Reassembler().push(part[0], now)
        assert received is not None
        server.receive(received, now + index * 0.01)
        for msg in server.due(now + index * 0.01):
            answer = answers.push(msg, now)
            if answer is not None and len(bytes(answer.payload.unique_id.to_bytes())) == 16:
                given = int(answer.payload.node_id)
    return given


def test_allocation_rate_cap_and_expiry_on_fake_time() -> None:
    server = AllocationServer(100, {}, set(), 125, max_entries=16, expire_s=600.0)
    ids = [exchange(server, made_up(n), n * 1.0) for n in range(10)]  # 10 in 10 s
    assert sum(1 for i in ids if i) == 6 and server.rate_limited == 4  # six a minute
    assert not server.table_hex()  # none of them has spoken: nothing to save
    # a real node speaks: its entry stays (and is saved), the others go 10 s after allocation
    server.seen(ids[0], 5.0)
    server.due(20.0)
    assert list(server.table.values()) == [ids[0]]
    assert list(server.table_hex().values()) == [ids[0]]
    # silent for expire_s: it goes too, and a minute on new ids are handed out again
    server.due(5.0 + 601.0)
    assert not server.table
    assert exchange(server, made_up(50), 700.0) != 0


def test_a_servo_of_the_config_keeps_its_id_whatever_the_bounds() -> None:
    uid = bytes(range(16))
    server = AllocationServer(100, {uid: 42}, set(), 125, max_entries=0)
    assert exchange(server, uid, 0.0) == 42
    assert exchange(server, made_up(1), 1.0) == 0


def test_seen_ids_are_bounded_and_expire() -> None:
    server = AllocationServer(100, {}, set(), 125, expire_s=5.0)
    for node_id in range(1, 128):
        server.seen(node_id, 0.0)
    assert exchange(server, made_up(1), 1.0) == 0 and server.pool_empty_noted()
    assert not server.pool_empty_noted()  # once per time it runs empty
    server.due(6.0)
    assert exchange(server, made_up(2), 6.5) == 125


def test_a_status_closes_a_round_trip_and_a_node_status_does_not() -> None:
    profile = DroneCanServo(11)
    heartbeat = frames(dronecan.uavcan.protocol.NodeStatus(uptime_sec=1), 11, 0)[0]
    status_frames = frames(
        dronecan.uavcan.equipment.actuator.Status(actuator_id=1, position=0.1), 11, 1
    )
    assert profile.is_liveness_only(heartbeat)
    assert not any(profile.is_liveness_only(m) for m in status_frames)
