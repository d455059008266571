"""A bus that keeps failing is logged once per outage, and every failure is still counted.

The new-user trial unplugged the adapter for 5 s and got ~400 ``send to aileron failed``
warnings (~80 a second, even with ``--quiet``). Real buses throughout: the project's
:class:`ResilientBus` over python-can ``virtual`` buses that the test closes under it (the
device vanishing) and lets it reopen (the replug), and a plain ``virtual`` bus closed for good.
A thin subclass counts what the bus refused, the truth the scheduler's counters are held to.
"""

from __future__ import annotations

import errno
import logging
import uuid

import can
import pytest
from can.interfaces.virtual import VirtualBus

from mavservo.scheduling.runner import (
    FailureRun,
    Scheduler,
    SchedulerObserver,
    ServoSpec,
    TimingConfig,
)
from mavservo.servos import Fault, RmdX, ServoState
from mavservo.sim.servo import SimServo
from mavservo.sim.virtual import VirtualServoBus
from mavservo.transport.resilient_bus import ResilientBus
from tests.support.waiting import wait_until

FAST = TimingConfig(command_period_s=0.02, telemetry_period_s=0.03, reply_timeout_s=0.05)
WAIT_LIMIT_S = 5.0
SCHEDULER_LOG = "mavservo.scheduling.runner"


def specs(n: int = 2) -> list[ServoSpec]:
    return [ServoSpec(f"s{i}", RmdX(i)) for i in range(1, n + 1)]


class Adapter:
    """The device behind the factory: opens a virtual bus while plugged in."""

    def __init__(self, channel: str) -> None:
        self.channel = channel
        self.plugged = True
        self.opened: list[can.BusABC] = []

    def open(self) -> can.BusABC:
        if not self.plugged:
            raise OSError(errno.ENOENT, "No such file or directory", "/dev/ttyUSB0")
        bus = can.Bus(interface="virtual", channel=self.channel, receive_own_messages=False)
        self.opened.append(bus)
        return bus

    def unplug(self) -> None:
        self.plugged = False
        self.opened[-1].shutdown()  # the open bus now fails every send and receive

    def close_all(self) -> None:
        for bus in self.opened:
            bus.shutdown()


class CountingResilientBus(ResilientBus):
    """The project's reconnecting bus, counting the sends it refused."""

    refused = 0
    sent = 0

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        try:
            super().send(msg, timeout)
        except can.CanError:
            self.refused += 1
            raise
        self.sent += 1


class CountingVirtualBus(VirtualBus):
    """python-can's virtual bus, counting the sends and receives that raised."""

    refused_sends = 0
    refused_receives = 0

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        try:
            super().send(msg, timeout)
        except can.CanError:
            self.refused_sends += 1
            raise

    def recv(self, timeout: float | None = None) -> can.Message | None:
        try:
            return super().recv(timeout)
        except can.CanError:
            self.refused_receives += 1
            raise


class ReceiveFailingBus(VirtualBus):
    """python-can's virtual bus whose receives fail while ``receives_fail`` is set."""

    receives_fail = True
    refused_receives = 0

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if self.receives_fail:
            self.refused_receives += 1
            raise can.CanOperationError("receive refused")
        return super().recv(timeout)


def records(caplog: pytest.LogCaptureFixture, level: int, *words: str) -> list[str]:
    return [
        r.getMessage()
        for r in caplog.records
        if r.name == SCHEDULER_LOG
        and r.levelno == level
        and all(w in r.getMessage() for w in words)
    ]


def test_an_unplugged_adapter_logs_one_warning_and_one_recovery_and_counts_every_failed_send(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO)
    channel = f"outage-{uuid.uuid4().hex}"
    adapter = Adapter(channel)
    sims = [SimServo("rmd-x", i) for i in (1, 2)]
    with VirtualServoBus(sims, channel=channel):
        bus = CountingResilientBus(
            adapter.open, name="bus0", initial_backoff_s=0.01, max_backoff_s=0.05
        )
        scheduler = Scheduler(bus, specs(), FAST, name="bus0")
        try:
            with scheduler:
                for spec in specs():
                    assert scheduler.set_setpoint(spec.name, 10.0, "test").accepted
                assert wait_until(lambda: bus.sent >= 10)
                adapter.unplug()
                assert wait_until(lambda: bus.refused >= 20)  # many slots fail while it is away
                sent_while_away = bus.sent
                adapter.plugged = True
                assert wait_until(lambda: bus.reconnects == 1 and bus.sent > sent_while_away + 5)
            metrics = scheduler.metrics()
        finally:
            bus.shutdown()
            adapter.close_all()

    failed = bus.refused
    warnings = records(caplog, logging.WARNING, "send to")
    assert len(warnings) == 1, warnings[:5]
    # with the reason (the adapter lost, or disconnected while it is away)
    assert "failed: bus0: CAN adapter lost" in warnings[0] or "bus0: device" in warnings[0]
    recovered = records(caplog, logging.INFO, "sends work again")
    assert len(recovered) == 1
    assert f"{failed} failed over" in recovered[0]
    assert records(caplog, logging.INFO, "stopped while") == []  # the outage had ended
    assert metrics["send_failures"]["total"] == failed
    assert metrics["send_failures"]["outages"] == 1
    assert metrics["send_failures"]["failing_for_s"] is None
    assert sum(s["frames"]["send_failed"] for s in metrics["servos"].values()) == failed
    # a refused frame never counts as sent
    assert sum(s["frames"]["sent"] for s in metrics["servos"].values()) == bus.sent


def test_a_bus_gone_for_good_logs_one_send_and_one_receive_warning_and_the_totals_at_stop(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO)
    channel = f"gone-{uuid.uuid4().hex}"
    bus = CountingVirtualBus(channel=channel, receive_own_messages=False)
    scheduler = Scheduler(bus, specs(), FAST, name="bus0")
    try:
        with scheduler:
            for spec in specs():
                assert scheduler.set_setpoint(spec.name, 5.0, "test").accepted
            assert wait_until(lambda: scheduler.metrics()["servos"]["s1"]["frames"]["sent"] > 3)
            bus.shutdown()
            assert wait_until(lambda: bus.refused_sends >= 20 and bus.refused_receives >= 5)
            failing = scheduler.metrics()
        metrics = scheduler.metrics()
    finally:
        bus.shutdown()

    assert failing["send_failures"]["failing_for_s"] > 0  # shown while it lasts
    assert len(records(caplog, logging.WARNING, "send to", "failed")) == 1
    assert len(records(caplog, logging.WARNING, "receive failed")) == 1
    assert records(caplog, logging.INFO, "work again") == []
    stopped = records(caplog, logging.INFO, "stopped while")
    assert len(stopped) == 2
    assert any(f"sends were failing: {bus.refused_sends} failed" in line for line in stopped)
    assert any(f"receives were failing: {bus.refused_receives} failed" in line for line in stopped)
    assert metrics["send_failures"]["total"] == bus.refused_sends
    assert metrics["receive_failures"]["total"] == bus.refused_receives
    assert metrics["send_failures"]["outages"] == metrics["receive_failures"]["outages"] == 1
    # stop() logged the totals but the bus never worked again: still failing in the metrics
    assert metrics["send_failures"]["failing_for_s"] > 0
    assert metrics["receive_failures"]["failing_for_s"] > 0


def test_failure_run_reports_each_outage_once_with_its_count_and_length() -> None:
    run = FailureRun()
    assert run.succeeded(0.5) is None  # working all along: nothing to report
    assert run.failed(1.0) is True
    assert [run.failed(1.0 + i / 10) for i in range(1, 4)] == [False, False, False]
    assert run.failing_since == 1.0
    assert run.to_dict(2.0) == {"total": 4, "outages": 1, "failing_for_s": 1.0}
    assert run.succeeded(3.5) == (4, 2.5)
    assert run.succeeded(3.6) is None
    assert run.failed(5.0) is True  # a new outage is logged again
    assert run.succeeded(5.25) == (1, 0.25)
    assert run.to_dict(6.0) == {"total": 5, "outages": 2, "failing_for_s": None}


def test_failure_run_reads_an_ongoing_outage_without_ending_it() -> None:
    run = FailureRun()
    assert run.ongoing(0.5) is None
    run.failed(1.0)
    run.failed(1.5)
    assert run.ongoing(3.0) == (2, 2.0)
    assert run.ongoing(4.0) == (2, 3.0)  # still the same outage
    assert run.to_dict(4.0) == {"total": 2, "outages": 1, "failing_for_s": 3.0}
    assert run.succeeded(5.0) == (2, 4.0)


def test_an_outage_left_open_at_stop_ends_with_the_first_receive_after_a_restart(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO)
    bus = ReceiveFailingBus(channel=f"restart-{uuid.uuid4().hex}", receive_own_messages=False)
    scheduler = Scheduler(bus, specs(1), FAST, name="bus0")
    try:
        with scheduler:
            assert wait_until(lambda: bus.refused_receives >= 3)
        assert scheduler.metrics()["receive_failures"]["failing_for_s"] > 0  # open after stop
        bus.receives_fail = False
        with scheduler:
            assert wait_until(
                lambda: scheduler.metrics()["receive_failures"]["failing_for_s"] is None
            )
    finally:
        bus.shutdown()
    assert len(records(caplog, logging.INFO, "receives work again")) == 1
    assert scheduler.metrics()["receive_failures"]["outages"] == 1


class TxRecorder(SchedulerObserver):
    """Non-blocking observer: every frame that went out, as (servo, kind, seq)."""

    def __init__(self) -> None:
        self.tx: list[tuple[str, str, int | None]] = []

    def on_tx(self, bus, msg, t, kind, servo, seq) -> None:
        self.tx.append((servo, kind, seq))


def test_an_unplugged_adapter_takes_servos_offline_and_drops_setpoints_meant_for_the_outage(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """The trial: with the adapter unplugged the servos read online with 15 s old data, and a
    DO_SET_SERVO accepted during the outage moved the payload servo 12 s later, on replug."""
    caplog.set_level(logging.INFO)
    channel = f"outage-offline-{uuid.uuid4().hex}"
    adapter = Adapter(channel)
    sims = [SimServo("rmd-x", i) for i in (1, 2)]
    recorder = TxRecorder()
    told: list[tuple[str, ServoState]] = []
    with VirtualServoBus(sims, channel=channel):
        bus = ResilientBus(adapter.open, name="bus0", initial_backoff_s=0.01, max_backoff_s=0.05)
        scheduler = Scheduler(bus, specs(), FAST, name="bus0", observer=recorder)
        scheduler.subscribe(lambda servo, state: told.append((servo, state)))
        names = [spec.name for spec in specs()]
        try:
            with scheduler:
                for name in names:
                    assert scheduler.set_setpoint(name, 10.0, "test").accepted
                assert wait_until(
                    lambda: all(
                        scheduler.state(n) is not None and (n, "command", 1) in recorder.tx
                        for n in names
                    )
                )
                assert all(scheduler.is_online(n) for n in names)

                adapter.unplug()
                assert wait_until(lambda: not any(scheduler.is_online(n) for n in names))
                for name in names:  # the existing offline path: NO_REPLY, subscribers told
                    assert Fault.NO_REPLY in scheduler.state(name).faults
                    assert any(s == name and Fault.NO_REPLY in st.faults for s, st in told)
                late = scheduler.set_setpoint("s1", 77.0, "do_set_servo")
                assert late.accepted  # the scheduler takes it; its send fails and drops it
                assert wait_until(
                    lambda: scheduler.metrics()["servos"]["s1"]["setpoints"]["dropped"]
                )

                adapter.plugged = True
                assert wait_until(lambda: all(scheduler.is_online(n) for n in names))
                replies_after = sims[0].replies
                assert wait_until(lambda: sims[0].replies > replies_after + 5)
            metrics = scheduler.metrics()
        finally:
            bus.shutdown()
            adapter.close_all()

    assert ("s1", "command", late.seq) not in recorder.tx
    assert ("s1", "refresh", late.seq) not in recorder.tx
    assert sims[0].target_deg == pytest.approx(10.0)  # still where it was before the outage
    assert metrics["servos"]["s1"]["setpoints"]["dropped"] == 1
    offline = records(caplog, logging.WARNING, "offline (sends failing)")
    assert sorted(line.split()[3] for line in offline) == names  # once per servo
    assert len(records(caplog, logging.INFO, "back online")) == len(names)
    dropped = records(caplog, logging.WARNING, "dropped unsent")
    assert len(dropped) == 1 and f"#{late.seq}" in dropped[0]
