"""The observer fan-out alone (scheduling/observers.py): a failing observer or subscriber
never reaches the loop that called it, and the write capability is asked once."""

from __future__ import annotations

import logging

import can

from mavservo.scheduling.observers import ObserverFanout, SchedulerObserver
from mavservo.scheduling.schedule_core import FrameKind
from mavservo.servos import NO_FAULT, ServoState

MSG = can.Message(arbitration_id=0x141, data=bytes(8), is_extended_id=False)
STATE = ServoState(1.0, 0.0, 0.0, 25.0, NO_FAULT, 2.0)


class Failing(SchedulerObserver):
    def on_tx(
        self, bus: str, msg: can.Message, t: float, kind: FrameKind, servo: str, seq: int | None
    ) -> None:
        raise RuntimeError("observer broke")


class Writing(SchedulerObserver):
    def __init__(self) -> None:
        self.written: list[tuple[str, float, FrameKind, str, int | None]] = []

    def on_written(self, bus: str, t: float, kind: FrameKind, servo: str, seq: int | None) -> None:
        self.written.append((bus, t, kind, servo, seq))


def test_an_observer_that_raises_is_logged_and_the_caller_goes_on(caplog):
    fanout = ObserverFanout(Failing())
    with caplog.at_level(logging.ERROR, logger="mavservo.scheduling.runner"):
        fanout.tx("bus0", MSG, 1.0, "command", "s1", 3)
        fanout.rx("bus0", MSG, 1.0, "s1", STATE)  # its no-op hooks still work
    assert [r.getMessage() for r in caplog.records] == ["scheduler observer on_tx failed"]


def test_subscribers_hear_every_state_even_after_one_fails_and_can_unsubscribe(caplog):
    fanout = ObserverFanout(None)
    heard: list[tuple[str, ServoState]] = []

    def broken(servo: str, state: ServoState) -> None:
        raise ValueError("subscriber broke")

    fanout.subscribe(broken)
    unsubscribe = fanout.subscribe(lambda servo, state: heard.append((servo, state)))
    with caplog.at_level(logging.ERROR, logger="mavservo.scheduling.runner"):
        fanout.state("s1", STATE)
    assert heard == [("s1", STATE)]
    assert "scheduler subscriber failed for s1" in caplog.text
    unsubscribe()
    unsubscribe()  # twice is harmless
    fanout.state("s1", STATE)
    assert heard == [("s1", STATE)]


def test_written_reaches_only_an_observer_with_the_write_capability():
    writing = Writing()
    fanout = ObserverFanout(writing)
    assert fanout.writes
    fanout.written("bus0", 1.5, "command", "s1", 7)
    assert writing.written == [("bus0", 1.5, "command", "s1", 7)]
    plain = ObserverFanout(Failing())
    assert not plain.writes
    plain.written("bus0", 1.5, "command", "s1", 7)  # nobody to tell: nothing happens
