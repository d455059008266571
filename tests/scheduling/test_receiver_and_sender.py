"""The two sides of the scheduler alone, without their threads: the receive side books a reply
(scheduling/receiver.py), the write side books what the bus did with a step's frames
(scheduling/sender.py). Both are built on the same real parts the Scheduler gives them."""

from __future__ import annotations

import threading

import can
import pytest

from mavservo.records import SchedulerMetrics
from mavservo.scheduling.advice import ServoAdvice
from mavservo.scheduling.bus_book import BusBook
from mavservo.scheduling.bus_nodes import BusNodes
from mavservo.scheduling.observers import ObserverFanout, SchedulerObserver
from mavservo.scheduling.outage_log import OnlineLog
from mavservo.scheduling.receiver import FrameReceiver
from mavservo.scheduling.schedule_core import FrameKind, ScheduleCore, ServoSpec, TimingConfig
from mavservo.scheduling.sender import FrameWriter
from mavservo.servos import Fault, RmdX, ServoState
from tests.support.scheduler_doubles import Clock, RecordingBus

TIMING = TimingConfig(command_period_s=0.05, telemetry_period_s=0.1)
REPLY = can.Message(
    arbitration_id=0x241, data=bytes([0xA4, 30, 0, 0, 0, 0, 0, 0]), is_extended_id=False
)


class Recorder(SchedulerObserver):
    def __init__(self) -> None:
        self.events: list[tuple[str, str, object]] = []

    def on_tx(
        self, bus: str, msg: can.Message, t: float, kind: FrameKind, servo: str, seq: int | None
    ) -> None:
        self.events.append(("tx", servo, kind))

    def on_written(self, bus: str, t: float, kind: FrameKind, servo: str, seq: int | None) -> None:
        self.events.append(("written", servo, seq))

    def on_rx(
        self, bus: str, msg: can.Message, t: float, servo: str, state: ServoState | None
    ) -> None:
        self.events.append(("rx", servo, state))


class Sides:
    """One servo's scheduler parts, wired as the Scheduler wires them."""

    def __init__(self) -> None:
        self.clock = Clock()
        self.bus = RecordingBus()
        specs = [ServoSpec("s1", RmdX(1), telemetry_hz=0)]
        self.core = ScheduleCore(specs, TIMING, start=self.clock.now)
        self.metrics = SchedulerMetrics({s.name: s for s in specs}, 0.05, 0.1, 1_000_000, 1.0)
        self.states: dict[str, ServoState] = {}
        self.recorder = Recorder()
        self.fanout = ObserverFanout(self.recorder)
        self.heard: list[tuple[str, ServoState]] = []
        self.fanout.subscribe(lambda servo, state: self.heard.append((servo, state)))
        nodes = BusNodes("bus0", specs, TIMING, {}, self.clock.now)
        book = BusBook(threading.Lock(), self.core, self.metrics, self.states, OnlineLog(), nodes)
        parts = {"clock": self.clock, "book": book, "fanout": self.fanout}
        parts["advice"] = ServoAdvice("bus0", specs)
        self.writer = FrameWriter("bus0", self.bus, **parts)
        self.receiver = FrameReceiver(
            "bus0", self.bus, specs, TIMING, wake=threading.Event(), **parts
        )

    def slot(self) -> None:
        self.writer.send_all(self.writer.step())
        self.clock.now += TIMING.command_period_s


@pytest.fixture
def sides():
    made = Sides()
    yield made
    made.bus.shutdown()


def test_a_written_command_is_booked_and_told_and_its_reply_timed(sides: Sides):
    sides.core.submit("s1", 10.0, "test", sides.clock.now)
    sides.slot()
    assert [m.data[0] for m in sides.bus.sent] == [0xB3, 0xA4]  # start-up, then the command
    servo = sides.metrics.servos["s1"]
    assert servo.commands_sent == 1 and servo.lifecycle_sent == 1
    assert ("written", "s1", 1) in sides.recorder.events
    state = sides.receiver.handle_frame(REPLY, sides.clock.now - 0.048)
    assert state is not None and sides.states["s1"] == state
    assert servo.received == 1 and servo.latency.count == 1
    assert ("rx", "s1", state) in sides.recorder.events and sides.heard == [("s1", state)]


def test_an_unclaimed_frame_is_nobodys_state(sides: Sides):
    foreign = can.Message(arbitration_id=0x7FF, data=bytes(8), is_extended_id=False)
    assert sides.receiver.handle_frame(foreign, sides.clock.now) is None
    assert sides.states == {} and sides.heard == []
    assert sides.metrics.servos["s1"].received == 0


def test_refused_sends_take_a_heard_servo_offline_with_no_reply_in_its_state(sides: Sides):
    sides.core.submit("s1", 10.0, "test", sides.clock.now)
    sides.slot()
    sides.receiver.handle_frame(REPLY, sides.clock.now)
    sides.bus.refuse = True
    for _ in range(TIMING.offline_after_missed):
        sides.slot()
    assert not sides.core.is_online("s1")
    assert sides.writer.failures.total >= TIMING.offline_after_missed
    assert sides.states["s1"].faults & Fault.NO_REPLY
    assert sides.heard[-1][1].faults & Fault.NO_REPLY  # subscribers are told
