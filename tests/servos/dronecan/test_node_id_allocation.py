"""DroneCAN dynamic node id allocation: the bridge's allocator (``node.dronecan.allocator``),
against an independent anonymous node written here with the ``dronecan`` package (its
``Transfer`` for the anonymous requests, its passive ``Node`` for the answers), against the
simulated servo node that starts without an id, and the table kept next to the config across
restarts. Every loop is bounded in count and time."""

from __future__ import annotations

import json
import math
import time
import uuid
from pathlib import Path
from typing import Any

import can
import dronecan
import pytest
from dronecan.transport import Transfer

from mavservo.app.bridge import Bridge
from mavservo.config import load_config
from mavservo.scheduling.runner import Scheduler, ServoSpec, TimingConfig
from mavservo.servos.dronecan import wire
from mavservo.servos.dronecan.alloc import AllocationServer
from mavservo.servos.dronecan.node import BridgeNode, NodeOptions
from mavservo.servos.dronecan.profile import DroneCanOptions, DroneCanServo
from mavservo.sim.servo import SimServo
from tests.servos.dronecan.test_interop import VirtualBusDriver

pytestmark = pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")

Allocation = dronecan.uavcan.protocol.dynamic_node_id.Allocation
UID = bytes(range(0x10, 0x20))
OTHER_UID = bytes(range(0xA0, 0xB0))


def anonymous_request(part: bytes, first: bool, preferred: int = 0, tid: int = 0) -> can.Message:
    """An anonymous Allocation frame, built by the package."""
    allocation = Allocation(node_id=preferred, first_part_of_unique_id=first)
    allocation.unique_id.from_bytes(part)
    transfer = Transfer(
        transfer_id=tid,
        source_node_id=0,
        payload=allocation,
        discriminator=0x1234,
        transfer_priority=30,
    )
    [frame] = transfer.to_frames()
    return can.Message(
        arbitration_id=frame.message_id, is_extended_id=True, data=bytes(frame.bytes)
    )


def node_status_frame(node_id: int, tid: int = 0) -> can.Message:
    """A NodeStatus from ``node_id``, built by the package: what a node sends once it has an id."""
    transfer = Transfer(
        transfer_id=tid,
        source_node_id=node_id,
        payload=dronecan.uavcan.protocol.NodeStatus(uptime_sec=1),
        transfer_priority=30,
    )
    [frame] = transfer.to_frames()
    return can.Message(
        arbitration_id=frame.message_id, is_extended_id=True, data=bytes(frame.bytes)
    )


def decode(frames: list[can.Message]) -> Any:
    transfer = Transfer()
    transfer.from_frames(
        [dronecan.transport.Frame(m.arbitration_id, bytes(m.data)) for m in frames]
    )
    return transfer


def answer(node: BridgeNode, now: float) -> Any:
    """The allocator's answer among the node's frames (its NodeStatus may be due as well)."""
    return decode([m for m in node.due(now, "ok") if wire.message_dtid(m) == wire.DTID_ALLOCATION])


def exchange(node: BridgeNode, uid: bytes, now: float, preferred: int = 0) -> Any:
    """The three stages against ``node``; the last answer."""
    last = None
    for start, length in ((0, 6), (6, 6), (12, 4)):
        assert node.receive(
            anonymous_request(uid[start : start + length], start == 0, preferred), now
        )
        last = answer(node, now)
    return last


def test_allocator_hands_out_configured_then_free_ids_in_three_stages() -> None:
    servos = [
        DroneCanServo(20, actuator_id=1, unique_id=UID.hex()),
        DroneCanServo(125, actuator_id=2),
    ]
    options = NodeOptions(node_id=100, allocator=True)
    node = BridgeNode(servos, options, (0, 1), 0.0)
    node.due(0.0, "ok")  # the first NodeStatus
    # stage by stage: the echo carries what the server has so far
    assert node.receive(anonymous_request(UID[:6], True), 1.0)
    echo = answer(node, 1.0).payload
    assert (echo.node_id, bytes(echo.unique_id.to_bytes())) == (0, UID[:6])
    assert node.receive(anonymous_request(UID[6:12], False), 1.1)
    assert bytes(answer(node, 1.1).payload.unique_id.to_bytes()) == UID[:12]
    assert node.receive(anonymous_request(UID[12:], False), 1.2)
    final = answer(node, 1.2)
    assert final.source_node_id == 100
    assert (final.payload.node_id, bytes(final.payload.unique_id.to_bytes())) == (20, UID)
    # an unknown unique id: its preferred id if free, else the highest free one (125 is a servo's)
    assert exchange(node, OTHER_UID, 2.0, preferred=11).payload.node_id == 11
    third = bytes(range(16))
    assert exchange(node, third, 3.0, preferred=100).payload.node_id == 124  # 100 is the bridge
    # kept across restarts once the nodes speak (a made-up unique id never does)
    assert node.persistent_state() == (2, {"allocation_table": {}})
    for tid, node_id in enumerate((11, 124)):
        node.receive(node_status_frame(node_id, tid), 3.5)
    assert node.persistent_state() == (
        4,
        {"allocation_table": {OTHER_UID.hex(): 11, third.hex(): 124}},
    )
    # asking again gets the same id
    assert exchange(node, OTHER_UID, 4.0).payload.node_id == 11


def test_allocator_ignores_out_of_order_parts_and_forgets_stale_queries() -> None:
    server = AllocationServer(100, {}, set(), 125)
    node = BridgeNode([DroneCanServo(5)], NodeOptions(allocator=True), (0, 1), 0.0)
    node.allocator = server
    assert not node.receive(anonymous_request(UID[6:12], False), 0.0)  # no first part yet
    assert node.receive(anonymous_request(UID[:6], True), 1.0)
    node.due(1.0, "ok")
    assert not node.receive(anonymous_request(UID[12:], False), 1.1)  # 4 bytes at stage 2
    assert not node.receive(anonymous_request(UID[6:12], False), 2.0)  # after the timeout
    assert server.ignored == 3
    # a node heard on the bus keeps its id
    server.seen(125, 3.0)
    assert exchange(node, UID, 3.0).payload.node_id == 124


def test_a_servo_with_a_unique_id_needs_the_allocator() -> None:
    with pytest.raises(ValueError, match="allocator"):
        BridgeNode([DroneCanServo(5, unique_id=UID.hex())], NodeOptions(), (0, 1), 0.0)


def test_the_simulated_servo_starts_without_an_id_and_asks() -> None:
    options = DroneCanOptions(actuator_id=1, unique_id=UID.hex())
    sim = SimServo("dronecan", 20, options=options, reply_latency_s=0.0)
    profile = DroneCanServo(20, options)
    node = BridgeNode([profile], NodeOptions(node_id=100, allocator=True), (0, 1), 0.0)
    device = sim._device  # noqa: SLF001 - the device's id is what is under test
    assert device.node_id is None
    states = []
    for step in range(300):  # 3 s of simulated time in 10 ms steps
        now = step * 0.01
        frames = [msg for _, msg in sim.poll(now)]
        for msg in frames:
            assert wire.source_node(msg) in (0, 20)  # anonymous until it has its id
            if wire.source_node(msg) == 0:
                assert wire.message_dtid(msg) == wire.DTID_ALLOCATION
            node.receive(msg, now)
            if profile.is_reply(msg):
                states.append(profile.decode(msg, now))
        for answer in node.due(now, "ok"):
            for _, reply in sim.receive(answer, now):
                node.receive(reply, now)
    assert device.node_id == 20
    assert any(s is not None and not math.isnan(s.position_deg) for s in states)


def passive_client(driver: VirtualBusDriver, uid: bytes) -> tuple[Any, dict[str, int]]:
    """An independent node without an id: the package's passive Node hears the allocator's
    answers; the anonymous requests go out as the package's Transfers."""
    node = dronecan.node.Node(driver, node_id=None)
    got: dict[str, int] = {}

    def send(part: bytes, first: bool) -> None:
        driver.send(*_frame(anonymous_request(part, first)), extended=True)

    def on_allocation(event: Any) -> None:
        echoed = bytes(event.message.unique_id.to_bytes())
        if not uid.startswith(echoed) or event.transfer.source_node_id == 0 or "id" in got:
            return
        if len(echoed) == 16:
            got["id"] = int(event.message.node_id)
        else:
            send(uid[len(echoed) : len(echoed) + 6], False)

    node.add_handler(Allocation, on_allocation)
    got_send = send
    node.start_allocation = lambda: got_send(uid[:6], True)  # type: ignore[attr-defined]
    return node, got


def _frame(msg: can.Message) -> tuple[int, bytes]:
    return msg.arbitration_id, bytes(msg.data)


def run_client(node: Any, got: dict[str, int], limit_s: float = 8.0) -> int | None:
    deadline = time.monotonic() + limit_s
    next_request = 0.0
    for _ in range(2000):
        if "id" in got or time.monotonic() > deadline:
            break
        if time.monotonic() >= next_request:
            node.start_allocation()
            next_request = time.monotonic() + 1.0
        node.spin(0.01)
    return got.get("id")


def allocating_scheduler(bus: can.BusABC) -> Scheduler:
    """The bridge's scheduler as node 100 with the allocator on, for one servo (node 42) known
    only by its unique id: both independent-client tests run against this, on different buses."""
    spec = ServoSpec("servo", DroneCanServo(42, actuator_id=1, unique_id=UID.hex()), telemetry_hz=1)
    return Scheduler(
        bus,
        [spec],
        TimingConfig(reply_timeout_s=0.5),
        node_options={"dronecan": NodeOptions(node_id=100, allocator=True)},
    )


def test_independent_anonymous_node_gets_its_id_from_the_bridges_allocator() -> None:
    channel = f"dronecan-alloc-{uuid.uuid4().hex}"
    driver = VirtualBusDriver(channel)
    node, got = passive_client(driver, UID)
    bus = can.Bus(interface="virtual", channel=channel)
    scheduler = allocating_scheduler(bus)
    try:
        with scheduler:
            assert run_client(node, got) == 42
            node.node_id = got["id"]  # it now speaks as node 42: NodeStatus at 1 Hz
            node.mode = dronecan.uavcan.protocol.NodeStatus().MODE_OPERATIONAL
            deadline = time.monotonic() + 5.0
            for _ in range(500):
                node.spin(0.01)
                if scheduler.state("servo") is not None or time.monotonic() > deadline:
                    break
            assert scheduler.state("servo") is not None
            assert scheduler.is_online("servo")
    finally:
        node.close()
        bus.shutdown()


CONFIG = """
mavlink: {url: sim}
can:
  buses:
    - {name: bus0, interface: virtual, channel: CHANNEL,
       node: {dronecan: {node_id: 100, allocator: true}}}
servos:
  - {name: s, profile: dronecan, can_id: 30, telemetry_hz: 1, options: {actuator_id: 1}}
channels: [{servo: s, source: servo_output, channel: 1}]
logging: {dir: LOGS}
"""


def test_the_allocation_table_is_kept_next_to_the_config_across_restarts(tmp_path: Path) -> None:
    channel = f"dronecan-keep-{uuid.uuid4().hex}"
    path = tmp_path / "rig.yaml"
    path.write_text(CONFIG.replace("CHANNEL", channel).replace("LOGS", str(tmp_path / "runs")))
    state_file = tmp_path / "rig.yaml.nodes.json"
    for run in range(2):
        driver = VirtualBusDriver(channel)
        node, got = passive_client(driver, OTHER_UID)
        bridge = Bridge(load_config(path), config_path=path, log_dir=False).start()
        try:
            assert run_client(node, got) == 125  # the same id both times
            driver.send(*_frame(node_status_frame(125)), extended=True)  # it speaks
            deadline = time.monotonic() + 3.0
            while not state_file.exists() and time.monotonic() < deadline:
                time.sleep(0.05)
        finally:
            bridge.stop()
            node.close()
        saved = json.loads(state_file.read_text())
        assert saved == {"bus0": {"dronecan": {"allocation_table": {OTHER_UID.hex(): 125}}}}
        assert state_file.stat().st_mode & 0o777 == 0o600
        if run == 0:
            # the next start must remember: make the free pool hand out another id first
            path.write_text(
                path.read_text().replace(
                    "allocator: true", "allocator: true, allocation_first_id: 90"
                )
            )


def test_a_corrupt_table_is_reported_and_ignored(tmp_path: Path) -> None:
    channel = f"dronecan-bad-{uuid.uuid4().hex}"
    path = tmp_path / "rig.yaml"
    path.write_text(CONFIG.replace("CHANNEL", channel).replace("LOGS", str(tmp_path / "runs")))
    state_file = tmp_path / "rig.yaml.nodes.json"
    for text in (
        "{not json",
        json.dumps({"bus0": {"dronecan": {"allocation_table": {"zz": 500}}}}),
    ):
        state_file.write_text(text)
        bridge = Bridge(load_config(path), config_path=path, log_dir=False).start()
        try:
            [node] = bridge.schedulers["bus0"].nodes
            assert node.persistent_state() == (0, {"allocation_table": {}})
        finally:
            bridge.stop()


def test_independent_anonymous_node_gets_its_id_over_aa55_and_the_adapter_emulator() -> None:
    from mavservo.sim.adapter import AdapterEmulator
    from tests.servos.dronecan.test_interop import LibraryNodeOnSimBus, SimBusDriver

    driver = SimBusDriver()
    node, got = passive_client(driver, UID)  # type: ignore[arg-type]
    participant = LibraryNodeOnSimBus(node, driver)
    emulator = AdapterEmulator([participant]).start()  # type: ignore[list-item]
    try:
        bus = can.Bus(interface="aa55", channel=emulator.path, bitrate=1_000_000)
        scheduler = allocating_scheduler(bus)
        try:
            with scheduler:
                deadline = time.monotonic() + 8.0
                next_request = 0.0
                for _ in range(800):  # the node runs in the emulator's thread; we only ask
                    if "id" in got or time.monotonic() > deadline:
                        break
                    if time.monotonic() >= next_request:
                        participant.calls.append(node.start_allocation)
                        next_request = time.monotonic() + 1.0
                    time.sleep(0.01)
                assert got.get("id") == 42
        finally:
            bus.shutdown()
    finally:
        emulator.stop()
