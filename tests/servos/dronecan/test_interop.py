"""Interop: the bridge's DroneCAN side against an independent node written here, directly with
the ``dronecan`` package (its ``Node``, handlers and requests; none of the project's DroneCAN
classes), on a python-can ``virtual`` bus and on the project's ``aa55`` interface over the
adapter emulator.

The independent node plays a servo node (node id 50, actuator 3) next to a second servo the
bridge commands in unitless mode. It must receive the bridge's ArrayCommand with the expected
actuator ids, command types and values (float16), see the bridge's NodeStatus and get its
GetNodeInfo answer; its own Status and NodeStatus must be decoded by the bridge. Every loop is
bounded in count and time.
"""

from __future__ import annotations

import math
import time
import uuid
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import can
import dronecan
import pytest
from dronecan.driver.common import AbstractDriver, CANFrame

from mavservo.scheduling.runner import Scheduler, ServoSpec, TimingConfig
from mavservo.servos.dronecan.node import NodeOptions
from mavservo.servos.dronecan.profile import DroneCanServo
from mavservo.sim.adapter import AdapterEmulator

pytestmark = pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")

BRIDGE_ID = 100
NODE_ID = 50
ACTUATOR = 3
TIMING = TimingConfig(command_period_s=0.02, telemetry_period_s=0.05, reply_timeout_s=0.5)


def specs() -> list[ServoSpec]:
    return [
        ServoSpec("independent", DroneCanServo(NODE_ID, actuator_id=ACTUATOR), telemetry_hz=10),
        ServoSpec(
            "unitless",
            DroneCanServo(
                11, actuator_id=1, command="unitless", unitless_min_deg=-90, unitless_max_deg=90
            ),
            telemetry_hz=10,
        ),
    ]


def scheduler_profiles(scheduler: Scheduler) -> list[DroneCanServo]:
    return [spec.profile for spec in scheduler._specs.values()]  # noqa: SLF001


class Observations:
    """What the independent node saw, filled by its handlers."""

    def __init__(self, node: Any) -> None:
        self.commands: list[tuple[int, int, int, float]] = []
        self.node_status_from: set[int] = set()
        self.node_info: Any = None
        node.add_handler(dronecan.uavcan.equipment.actuator.ArrayCommand, self._on_command)
        node.add_handler(dronecan.uavcan.protocol.NodeStatus, self._on_status)

    def _on_command(self, event: Any) -> None:
        source = event.transfer.source_node_id
        for c in event.message.commands:
            self.commands.append(
                (source, int(c.actuator_id), int(c.command_type), float(c.command_value))
            )

    def _on_status(self, event: Any) -> None:
        self.node_status_from.add(event.transfer.source_node_id)

    def on_info(self, event: Any) -> None:
        if event is not None:
            self.node_info = event.response


def exercise(
    node: Any,
    spin: Callable[[float], None],
    scheduler: Scheduler,
    call: Callable[[Callable[[], Any]], None] = lambda fn: fn(),
) -> None:
    """The checks, whatever carries the frames: ``spin(seconds)`` runs the independent node,
    ``call(fn)`` runs ``fn`` in the node's thread."""
    seen = Observations(node)
    assert scheduler.set_setpoint("independent", 30.0, "test").accepted
    assert scheduler.set_setpoint("unitless", 45.0, "test").accepted
    status = dronecan.uavcan.equipment.actuator.Status(
        actuator_id=ACTUATOR, position=0.25, force=math.nan, speed=-0.5, power_rating_pct=40
    )
    asked = False
    deadline = time.monotonic() + 10.0
    for _ in range(400):
        spin(0.02)
        call(lambda: node.broadcast(status))
        if not asked and BRIDGE_ID in seen.node_status_from:
            request = dronecan.uavcan.protocol.GetNodeInfo.Request()
            call(lambda r=request: node.request(r, BRIDGE_ID, seen.on_info))
            asked = True
        state = scheduler.state("independent")
        done = (
            seen.node_info is not None
            and all(
                p.node_health is not None
                for p in scheduler_profiles(scheduler)
                if p.can_id == NODE_ID
            )
            and len(seen.commands) >= 4
            and state is not None
            and not math.isnan(state.position_deg)
        )
        if done or time.monotonic() > deadline:
            break
    assert BRIDGE_ID in seen.node_status_from, "the bridge's NodeStatus never came"
    assert seen.node_info is not None, "no GetNodeInfo answer"
    assert seen.node_info.name.decode() == "org.mavservo.bridge"
    assert seen.node_info.status.mode == 0  # operational
    commands = {(s, a, t) for s, a, t, _ in seen.commands}
    assert (BRIDGE_ID, ACTUATOR, 1) in commands  # POSITION
    assert (BRIDGE_ID, 1, 0) in commands  # UNITLESS
    for source, actuator, kind, value in seen.commands:
        assert source == BRIDGE_ID
        if actuator == ACTUATOR:
            assert value == pytest.approx(math.radians(30.0), abs=1e-3)  # float16
        else:
            assert kind == 0 and value == pytest.approx(0.5, abs=1e-3)
    # both servos' commands travel in one transfer: equal counts, never one without the other
    per_actuator = [sum(1 for c in seen.commands if c[1] == a) for a in (ACTUATOR, 1)]
    assert abs(per_actuator[0] - per_actuator[1]) <= 1
    state = scheduler.state("independent")
    assert state is not None
    assert state.position_deg == pytest.approx(math.degrees(0.25), abs=0.05)
    assert state.velocity_dps == pytest.approx(math.degrees(-0.5), abs=0.05)
    assert scheduler.is_online("independent")
    assert not state.faults  # its NodeStatus says healthy (the library's node: OK)
    [profile] = [p for p in scheduler_profiles(scheduler) if p.can_id == NODE_ID]
    assert (profile.node_health, profile.node_mode) == (0, 0)  # decoded from its NodeStatus


def test_independent_library_node_on_a_virtual_bus() -> None:
    channel = f"dronecan-{uuid.uuid4().hex}"
    driver = VirtualBusDriver(channel)
    node = dronecan.node.Node(
        driver,
        node_id=NODE_ID,
        mode=dronecan.uavcan.protocol.NodeStatus().MODE_OPERATIONAL,
    )
    bus = can.Bus(interface="virtual", channel=channel)
    scheduler = Scheduler(
        bus, specs(), TIMING, name="vbus", node_options={"dronecan": NodeOptions(node_id=BRIDGE_ID)}
    )
    try:
        with scheduler:
            exercise(node, lambda s: node.spin(s), scheduler)
    finally:
        node.close()
        bus.shutdown()


class VirtualBusDriver(AbstractDriver):
    """A dronecan driver on a python-can virtual bus (the package's own python-can driver
    flushes the transmit buffer on a timeout, which the virtual interface does not have)."""

    def __init__(self, channel: str) -> None:
        super().__init__()
        self.bus = can.Bus(interface="virtual", channel=channel)

    def receive(self, timeout: float | None = None) -> CANFrame | None:
        msg = self.bus.recv(timeout)
        if msg is None or not msg.is_extended_id:
            return None
        return CANFrame(msg.arbitration_id, bytearray(msg.data), True)

    def send(self, message_id: int, message: bytes, extended: bool = False, canfd: bool = False):
        self.bus.send(
            can.Message(arbitration_id=message_id, is_extended_id=True, data=bytes(message))
        )

    def close(self) -> None:
        self.bus.shutdown()


class SimBusDriver(AbstractDriver):
    """A dronecan driver for a node that sits on the emulator's simulated CAN bus: frames the
    bus delivers are queued for ``Node.spin``; frames the node sends are collected."""

    def __init__(self) -> None:
        super().__init__()
        self.rx: deque[CANFrame] = deque()
        self.tx: deque[can.Message] = deque()

    def receive(self, timeout: float | None = None) -> CANFrame | None:
        return self.rx.popleft() if self.rx else None

    def send(self, message_id: int, message: bytes, extended: bool = False, canfd: bool = False):
        msg = can.Message(arbitration_id=message_id, is_extended_id=True, data=bytes(message))
        self.tx.append(msg)

    def close(self) -> None:
        return None


class LibraryNodeOnSimBus:
    """The independent node as a participant of :class:`mavservo.sim.canbus.SimCanBus` (the
    duck type the bus drives: ``receive``, ``poll``, ``next_push_time``)."""

    def __init__(self, node: Any, driver: SimBusDriver) -> None:
        self.node = node
        self.driver = driver
        self._next: float | None = None
        self.calls: deque[Callable[[], Any]] = deque()

    def receive(self, msg: can.Message, now: float) -> list[tuple[float, can.Message]]:
        self.driver.rx.append(CANFrame(msg.arbitration_id, bytearray(msg.data), True))
        self.node.spin(0)
        return self._drain(now)

    def poll(self, now: float) -> list[tuple[float, can.Message]]:
        while self.calls:
            self.calls.popleft()()
        self.node.spin(0)
        self._next = now + 0.005
        return self._drain(now)

    def next_push_time(self) -> float | None:
        return self._next

    def _drain(self, now: float) -> list[tuple[float, can.Message]]:
        out = [(now, msg) for msg in self.driver.tx]
        self.driver.tx.clear()
        return out


@contextmanager
def library_node_behind_an_adapter() -> Iterator[tuple[LibraryNodeOnSimBus, AdapterEmulator]]:
    driver = SimBusDriver()
    node = dronecan.node.Node(
        driver, node_id=NODE_ID, mode=dronecan.uavcan.protocol.NodeStatus().MODE_OPERATIONAL
    )
    participant = LibraryNodeOnSimBus(node, driver)
    emulator = AdapterEmulator([participant]).start()  # type: ignore[list-item]
    try:
        yield participant, emulator
    finally:
        emulator.stop()


def test_independent_library_node_over_aa55_and_the_adapter_emulator() -> None:
    with library_node_behind_an_adapter() as (participant, emulator):
        bus = can.Bus(interface="aa55", channel=emulator.path, bitrate=1_000_000)
        scheduler = Scheduler(
            bus,
            specs(),
            TIMING,
            name="aa55",
            node_options={"dronecan": NodeOptions(node_id=BRIDGE_ID)},
        )
        try:
            with scheduler:
                # the node runs in the emulator's thread; the test only sends through it and
                # waits (its broadcasts go out on the emulator's next poll)
                def spin(seconds: float) -> None:
                    time.sleep(seconds)

                exercise(participant.node, spin, scheduler, participant.calls.append)
        finally:
            bus.shutdown()
