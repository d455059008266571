"""Who the scheduler calls, and that it never calls them holding its lock.

Since the split of the Scheduler (issue 31 item 4) its observer and subscribers are called by
the write side (``sender.FrameWriter``), the receive side (``receiver.FrameReceiver``), the advice
(``advice.ServoAdvice``) and the scheduler itself. The rule all of them keep from before the
split: the scheduler's one lock is released before anyone outside is called, so an observer or
subscriber may read the scheduler (``state``, ``is_online``, ``metrics``) and a slow one holds
up neither thread. Driven here without the threads, on one thread, so ``lock.locked()`` during
a call means the caller holds it (a call with the lock held would deadlock on the read).
"""

from __future__ import annotations

import can

from mavservo.scheduling.runner import Scheduler, SchedulerObserver, ServoSpec, TimingConfig
from mavservo.servos import get_profile
from mavservo.sim.servo import SimServo
from tests.support.scheduler_doubles import Clock, RecordingBus


class Watcher(SchedulerObserver):
    """Every hook notes its name and whether the scheduler's lock was held, then reads the
    scheduler (only when it is free: a read under a held lock would hang the test)."""

    def __init__(self) -> None:
        self.scheduler: Scheduler | None = None
        self.calls: list[tuple[str, bool]] = []

    def note(self, hook: str) -> None:
        scheduler = self.scheduler
        assert scheduler is not None
        held = scheduler._lock.locked()  # noqa: SLF001 - the rule under test
        self.calls.append((hook, held))
        if not held:
            scheduler.state("s0")
            scheduler.is_online("s0")

    def on_setpoint(self, servo, seq, angle_deg, source, t):
        self.note("setpoint")

    def on_tx(self, bus, msg, t, kind, servo, seq):
        self.note("tx")

    def on_written(self, bus, t, kind, servo, seq):
        self.note("written")

    def on_rx(self, bus, msg, t, servo, state):
        self.note("rx")

    def on_lost(self, bus, servo, t):
        self.note("lost")

    def on_reject(self, bus, reason, raw_bytes, t):
        self.note("reject")


def test_no_observer_subscriber_or_event_is_called_with_the_scheduler_lock_held() -> None:
    clock, bus, watcher = Clock(), RecordingBus(), Watcher()
    profile = get_profile("robstride")  # it can say why a servo is silent (advice, on_event)
    specs = [ServoSpec(f"s{i}", profile(i + 1, profile.Options())) for i in range(2)]
    timing = TimingConfig(command_period_s=0.02, telemetry_period_s=0.05, reply_timeout_s=0.03)
    scheduler = Scheduler(bus, specs, timing, clock=clock, observer=watcher, name="b")
    watcher.scheduler = scheduler
    scheduler.on_event = lambda text: watcher.note("event")
    scheduler.subscribe(lambda servo, state: watcher.note("state"))
    servo = SimServo("robstride", 1, options=profile.Options())
    writer = scheduler._writer  # noqa: SLF001 - the runner's turn, without its thread

    def turn(answering: bool) -> None:
        before = len(bus.sent)
        writer.send_all(writer.step())
        for msg in bus.sent[before:]:
            for _, reply in servo.receive(msg, clock.now) if answering else ():
                scheduler.handle_frame(reply, clock.now)

    for angle in (10.0, 20.0):  # commanded and answered
        scheduler.set_setpoint("s0", angle, "mav")
        scheduler.set_setpoint("s1", angle, "mav")
        clock.now += 0.02
        turn(answering=True)
    for _ in range(20):  # s0 falls silent, s1 never answered: lost, offline, advice
        clock.now += 0.02
        turn(answering=False)
    bus.refuse = True  # the adapter is unplugged: refused sends take them offline
    scheduler.set_setpoint("s0", 30.0, "mav")
    for _ in range(10):
        clock.now += 0.02
        turn(answering=False)
    scheduler.report_reject("bad_checksum", b"\xaa\x55")
    scheduler.handle_frame(can.Message(arbitration_id=0x7FF, is_extended_id=False), clock.now)
    bus.shutdown()
    hooks = {hook for hook, _ in watcher.calls}
    assert {"setpoint", "tx", "written", "rx", "lost", "reject", "state", "event"} <= hooks
    assert [call for call in watcher.calls if call[1]] == []
