"""The threaded scheduler end to end on python-can's ``virtual`` bus with simulated servos."""

from __future__ import annotations

import json
import os
import threading
import time
import uuid
from collections import defaultdict

import can
import pytest

from mavservo.scheduling.runner import (
    ScheduleError,
    Scheduler,
    SchedulerObserver,
    ServoSpec,
    TimingConfig,
)
from mavservo.servos import Fault, RmdX
from mavservo.sim.servo import SimServo
from mavservo.sim.virtual import VirtualServoBus
from tests.support.waiting import wait_until

FAST = TimingConfig(command_period_s=0.02, telemetry_period_s=0.03, reply_timeout_s=0.05)
WAIT_LIMIT_S = 5.0


class Recorder(SchedulerObserver):
    """Non-blocking observer: appends to lists (list.append is atomic under the GIL)."""

    def __init__(self) -> None:
        self.tx: list[tuple[str, str, int | None, float]] = []
        self.rx: list[str] = []
        self.lost: list[str] = []
        self.setpoints: list[tuple[str, int, str]] = []
        self.rejects: list[str] = []

    def on_setpoint(self, servo, seq, angle_deg, source, t):
        self.setpoints.append((servo, seq, source))

    def on_tx(self, bus, msg, t, kind, servo, seq):
        self.tx.append((servo, kind, seq, t))

    def on_rx(self, bus, msg, t, servo, state):
        self.rx.append(servo)

    def on_lost(self, bus, servo, t):
        self.lost.append(servo)

    def on_reject(self, bus, reason, raw_bytes, t):
        self.rejects.append(reason)


@pytest.fixture
def sim_bus():
    """Four simulated RMD-X servos and a host-side virtual bus on a private channel."""
    channel = f"sched-{uuid.uuid4().hex}"
    sims = [SimServo("rmd-x", i) for i in range(1, 5)]
    with VirtualServoBus(sims, channel=channel) as servos:
        bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        try:
            yield bus, servos
        finally:
            bus.shutdown()


def specs(n: int = 4) -> list[ServoSpec]:
    return [ServoSpec(f"s{i}", RmdX(i)) for i in range(1, n + 1)]


def test_commands_reach_the_servos_and_telemetry_comes_back(sim_bus):
    bus, servos = sim_bus
    recorder = Recorder()
    updates: dict[str, int] = defaultdict(int)
    scheduler = Scheduler(bus, specs(), FAST, observer=recorder, name="test")
    scheduler.subscribe(lambda name, state: updates.__setitem__(name, updates[name] + 1))
    targets = {"s1": 10.0, "s2": -20.0, "s3": 30.0, "s4": 5.0}
    with scheduler:
        for name, angle in targets.items():
            assert scheduler.set_setpoint(name, angle, "test").accepted

        def settled() -> bool:
            states = {name: scheduler.state(name) for name in targets}
            return all(
                s is not None and abs(s.position_deg - targets[n]) <= 1.0 for n, s in states.items()
            )

        assert wait_until(settled), {n: scheduler.state(n) for n in targets}

        def polled_enough() -> bool:
            servos_now = scheduler.metrics()["servos"]
            return all(servos_now[n]["telemetry_interval_s"]["interval"]["n"] >= 3 for n in targets)

        assert wait_until(polled_enough)
    for sim in servos.servos:
        assert sim.target_deg == pytest.approx(targets[f"s{sim.can_id}"], abs=0.01)
    snapshot = json.loads(json.dumps(scheduler.metrics()))
    for name in targets:
        servo = snapshot["servos"][name]
        assert servo["online"]
        assert servo["latency_s"]["n"] > 0 and servo["latency_s"]["mean"] > 0
        assert servo["frames"]["commands"] == 1  # one new setpoint, the rest are refreshes
        assert servo["frames"]["refreshes"] > 0 and servo["frames"]["requests"] > 0
        assert updates[name] == servo["frames"]["received"]
    assert snapshot["load"]["total_bits"] > 0
    assert snapshot["command_tick"]["interval"]["n"] > 0
    assert [s for s, _, _ in recorder.setpoints] == list(targets)
    assert set(recorder.rx) == set(targets)


def test_sequence_numbers_on_the_wire_never_go_backwards(sim_bus):
    bus, _ = sim_bus
    recorder = Recorder()
    scheduler = Scheduler(
        bus,
        [ServoSpec("s1", RmdX(1), command_mode="immediate"), *specs(4)[1:]],
        FAST,
        observer=recorder,
    )
    with scheduler:
        for k in range(40):
            scheduler.set_setpoint("s1", float(k), "burst")
            scheduler.set_setpoint("s2", float(-k), "burst")
            time.sleep(0.002)
        assert wait_until(lambda: scheduler.metrics()["servos"]["s1"]["frames"]["refreshes"] > 2)
    for servo in ("s1", "s2"):
        seqs = [
            seq
            for name, kind, seq, _ in recorder.tx
            if name == servo and kind in ("command", "refresh")
        ]
        assert seqs == sorted(seqs) and seqs[-1] == 40
    immediate_sends = sum(1 for n, k, _, _ in recorder.tx if n == "s1" and k == "command")
    periodic_sends = sum(1 for n, k, _, _ in recorder.tx if n == "s2" and k == "command")
    assert immediate_sends > periodic_sends  # immediate does not wait for the 20 ms slot


def test_silent_servo_goes_offline_with_no_reply_fault_and_comes_back(sim_bus):
    bus, servos = sim_bus
    recorder = Recorder()
    seen_faults: list[Fault] = []
    scheduler = Scheduler(bus, specs(), FAST, observer=recorder)
    scheduler.subscribe(lambda name, state: name == "s3" and seen_faults.append(state.faults))
    with scheduler:
        scheduler.set_setpoint("s3", 1.0, "test")
        assert wait_until(lambda: scheduler.state("s3") is not None)
        servos.servos[2].faults.silent = True
        assert wait_until(lambda: not scheduler.is_online("s3"))
        assert Fault.NO_REPLY in scheduler.state("s3").faults
        assert scheduler.is_online("s1")
        servos.servos[2].faults.silent = False
        assert wait_until(lambda: scheduler.is_online("s3"))
        assert wait_until(lambda: Fault.NO_REPLY not in scheduler.state("s3").faults)
    assert "s3" in recorder.lost
    assert scheduler.metrics()["servos"]["s3"]["frames"]["lost"] >= FAST.offline_after_missed
    assert any(Fault.NO_REPLY in f for f in seen_faults)


def test_release_stops_the_keep_alive(sim_bus):
    """The threaded scheduler applies the core's release (which
    tests/scheduling/test_schedule_core.py proves under a fake clock). No fixed sleep: s2, set at
    the same time with the same refresh interval, keeps refreshing; while it refreshes three more
    times, a keep-alive of s1 would have gone out at least twice (one slot decided before the
    release may still go out)."""
    bus, _ = sim_bus
    scheduler = Scheduler(bus, specs(2), FAST)

    def refreshes(name: str) -> int:
        return scheduler.metrics()["servos"][name]["frames"]["refreshes"]

    with scheduler:
        scheduler.set_setpoint("s1", 3.0, "test")
        scheduler.set_setpoint("s2", -3.0, "test")
        assert wait_until(lambda: refreshes("s1") > 1 and refreshes("s2") > 1)
        scheduler.release("s1")
        released_at, other = refreshes("s1"), refreshes("s2")
        assert wait_until(lambda: refreshes("s2") >= other + 3)
        assert refreshes("s1") <= released_at + 1


def test_stale_setpoint_rejected_through_the_api(sim_bus):
    bus, _ = sim_bus
    recorder = Recorder()
    scheduler = Scheduler(bus, specs(1), FAST, observer=recorder)
    assert scheduler.set_setpoint("s1", 1.0, "a", t=10.0).accepted
    stale = scheduler.set_setpoint("s1", 2.0, "b", t=9.0)
    assert not stale.accepted
    assert scheduler.metrics()["servos"]["s1"]["setpoints"] == {
        "accepted": 1,
        "rejected": 1,
        "dropped": 0,
    }
    assert recorder.setpoints == [("s1", 1, "a")]


def test_over_budget_refused_at_construction(sim_bus):
    bus, _ = sim_bus
    with pytest.raises(ScheduleError, match="worst-case bus load R"):
        Scheduler(bus, specs(4), TimingConfig(bitrate=20_000, max_load=0.5))


def test_decoder_rejections_are_counted_and_observed(sim_bus, tmp_path):
    bus, _ = sim_bus
    recorder = Recorder()
    scheduler = Scheduler(bus, specs(1), FAST, observer=recorder)
    scheduler.report_reject("bad_end_marker", b"\xaa\xc8\x01", t=1.0)
    assert scheduler.metrics()["bus_rejected"] == 1 and recorder.rejects == ["bad_end_marker"]
    path = scheduler.write_metrics(tmp_path / "run" / "scheduler.json")
    assert json.loads(path.read_text())["bus_rejected"] == 1


def test_realtime_request_is_reported_not_raised(sim_bus):
    bus, _ = sim_bus
    scheduler = Scheduler(
        bus, specs(1), TimingConfig(command_period_s=0.02, telemetry_period_s=0.03, realtime=True)
    )
    with scheduler:
        assert wait_until(lambda: scheduler.realtime_status != "not requested")
    status = scheduler.metrics()["info"]["realtime"]
    assert status.startswith("SCHED_FIFO") or status.startswith("refused")


def test_failing_observer_and_subscriber_do_not_stop_the_loop(sim_bus):
    bus, _ = sim_bus

    class Broken(SchedulerObserver):
        def on_tx(self, *args):
            raise RuntimeError("observer bug")

    scheduler = Scheduler(bus, specs(1), FAST, observer=Broken())
    scheduler.subscribe(lambda name, state: 1 / 0)
    calls = threading.Event()
    scheduler.subscribe(lambda name, state: calls.set())
    with scheduler:
        scheduler.set_setpoint("s1", 1.0, "test")
        assert calls.wait(WAIT_LIMIT_S)
        assert wait_until(lambda: scheduler.metrics()["servos"]["s1"]["frames"]["received"] > 3)


def _start_under_fifo(scheduler: Scheduler) -> BaseException | None:
    """Start ``scheduler`` from a thread running SCHED_FIFO, as under systemd's
    ``CPUSchedulingPolicy=fifo``: the scheduler's threads inherit the policy. Returns the
    refusal when the OS does not grant it."""
    outcome: list[BaseException | None] = []

    def starter() -> None:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
        except (AttributeError, OSError) as exc:
            outcome.append(exc)
            return
        scheduler.start()
        outcome.append(None)

    thread = threading.Thread(target=starter)
    thread.start()
    thread.join(WAIT_LIMIT_S)
    return outcome[0] if outcome else RuntimeError("starter thread hung")


def test_a_runner_under_an_inherited_fifo_policy_uses_the_fifo_spin(sim_bus):
    bus, _ = sim_bus
    timing = TimingConfig(
        command_period_s=0.02, telemetry_period_s=0.03, spin_s=0.002, fifo_spin_s=0.0
    )
    scheduler = Scheduler(bus, specs(1), timing)
    refused = _start_under_fifo(scheduler)
    if refused is not None:
        pytest.skip(f"SCHED_FIFO not granted here: {refused!r}")
    try:
        assert wait_until(lambda: scheduler.realtime_status != "not requested")
        assert scheduler.realtime_status == "inherited real-time policy"
        assert scheduler.spin_s == 0.0
        assert scheduler.metrics()["info"]["spin_s"] == 0.0
        assert wait_until(lambda: scheduler.metrics()["command_tick"]["interval"]["n"] >= 5)
    finally:
        scheduler.stop()


def test_a_runner_at_normal_priority_keeps_the_configured_spin(sim_bus):
    bus, _ = sim_bus
    timing = TimingConfig(
        command_period_s=0.02, telemetry_period_s=0.03, spin_s=0.002, fifo_spin_s=0.0
    )
    with Scheduler(bus, specs(1), timing) as scheduler:
        assert wait_until(lambda: scheduler.metrics()["command_tick"]["interval"]["n"] >= 3)
        assert scheduler.spin_s == 0.002
        assert scheduler.realtime_status == "not requested"


def test_round_trip_samples_are_the_latest_wire_latencies_bounded_per_servo(sim_bus):
    bus, _ = sim_bus
    scheduler = Scheduler(bus, specs(2), FAST)
    assert scheduler.round_trip_samples() == []  # nothing measured yet
    with scheduler:
        scheduler.set_setpoint("s1", 4.0, "test")
        scheduler.set_setpoint("s2", -4.0, "test")
        assert wait_until(
            lambda: all(s["latency_s"]["n"] >= 6 for s in scheduler.metrics()["servos"].values())
        )
    store = scheduler.metrics_store.servos
    assert sorted(scheduler.round_trip_samples(per_servo=3)) == sorted(
        list(store["s1"].latency.recent)[-3:] + list(store["s2"].latency.recent)[-3:]
    )
    every = scheduler.round_trip_samples(per_servo=10_000)
    assert len(every) == store["s1"].latency.count + store["s2"].latency.count
    assert all(0 < value < FAST.reply_timeout_s for value in every)  # write -> reply, seconds


class LaggingReceiver(can.BusABC):
    """The host's virtual bus, whose frames the scheduler's receive thread never gets (a
    receive thread that lags on a loaded machine, or a tunnel whose replies come late): they
    wait in the bus, where any other thread reads them."""

    def __init__(self, inner: can.BusABC) -> None:
        self.inner = inner
        self.channel_info = "lagging"
        super().__init__(channel="lagging")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.inner.send(msg, timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if threading.current_thread().name.startswith("mavservo-rx-"):
            time.sleep(min(timeout or 0.0, 0.01))
            return None, False
        return self.inner.recv(timeout), False


def test_replies_waiting_in_the_bus_at_the_stop_are_late_not_lost(sim_bus):
    """The servo answered every frame, but its replies were still in the bus when the
    scheduler stopped (after their timeout): they are booked at the stop, late, not lost.
    Before, they stayed lost (a 120 s run through ArduPlane SITL: 4 lost, 4 queued)."""
    bus, servos = sim_bus
    scheduler = Scheduler(LaggingReceiver(bus), specs(1), FAST)

    def frames() -> dict[str, int]:
        return scheduler.metrics()["servos"]["s1"]["frames"]

    with scheduler:
        scheduler.set_setpoint("s1", 1.0, "test")
        assert wait_until(lambda: frames()["timed_out"] >= 2)
        sent = frames()["sent"]
        assert wait_until(lambda: servos.servos[0].replies >= sent)  # all in the bus now
    counted = frames()
    assert counted["timed_out"] >= 2 and counted["late"] >= counted["timed_out"]
    assert counted["lost"] == 0, counted
