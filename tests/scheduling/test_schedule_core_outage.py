"""The policy core when the bus refuses frames (adapter unplugged) and when replies come late.

Fake clock, no threads: each step's frames are either 'sent' or refused (``send_failed``), the
way the runner reports what ``bus.send`` did.
"""

from __future__ import annotations

import pytest

from mavservo.scheduling.schedule_core import Decision, ScheduleCore, ServoSpec, TimingConfig
from tests.support.servos import RmdXWithoutStartUp

T_C = 0.05
START = 100.0


def core_with(*specs: ServoSpec, **timing) -> ScheduleCore:
    return ScheduleCore(list(specs), TimingConfig(**timing), start=START)


def quiet(name: str = "s1", can_id: int = 1) -> ServoSpec:
    """A servo that is never polled: only commands and refreshes go to it."""
    return ServoSpec(name, RmdXWithoutStartUp(can_id), telemetry_hz=0)


def step(core: ScheduleCore, now: float, *, bus_up: bool) -> tuple[Decision, list]:
    """One step; every frame is sent (and answered at once) or refused, as the bus is."""
    decision = core.step(now)
    failures = []
    for out in decision.frames:
        if bus_up:
            core.sent(out, now)
            for _ in out.expectations:
                core.on_reply(out.servo, now + 0.001, out.expectations[0].key)
        else:
            failures.append(core.send_failed(out))
    return decision, failures


def test_refused_sends_take_a_servo_offline_within_offline_after_missed_slots() -> None:
    core = core_with(quiet(), offline_after_missed=3)
    core.submit("s1", 10.0, "test", START - 0.01)
    step(core, START, bus_up=True)
    assert core.is_online("s1")
    went_offline = []
    for k in range(1, 4):
        assert core.is_online("s1")  # a refused frame or two is retried, not fatal
        _, failures = step(core, START + k * T_C, bus_up=False)
        went_offline += [f.went_offline for f in failures]
    assert went_offline == [False, False, True]
    assert not core.is_online("s1")


def test_a_setpoint_that_never_went_out_is_dropped_and_the_last_sent_one_refreshes_after() -> None:
    core = core_with(quiet(), offline_after_missed=2)
    core.submit("s1", 10.0, "test", START - 0.01)
    step(core, START, bus_up=True)
    # accepted just before the outage, never sent: it must not go out when the bus is back
    late = core.submit("s1", 77.0, "do_set_servo", START + 0.01)
    dropped = []
    for k in range(1, 5):
        _, failures = step(core, START + k * T_C, bus_up=False)
        dropped += [f.dropped.seq for f in failures if f.dropped is not None]
    assert dropped == [late.seq]
    # submitted while offline (the backend refuses those, but a failsafe goes straight in)
    during = core.submit("s1", 55.0, "failsafe", START + 0.3)
    decision, failures = step(core, START + 6 * T_C, bus_up=False)
    assert [f.dropped.seq for f in failures if f.dropped] == [during.seq]
    after = [step(core, START + k * T_C, bus_up=True)[0] for k in range(7, 10)]
    sent = [(out.kind, out.seq) for d in after for out in d.frames]
    assert sent and all(seq == 1 for _, seq in sent), sent  # only the one that went out
    assert core.is_online("s1")
    fresh = core.submit("s1", 20.0, "do_set_servo", START + 0.6)
    assert fresh.seq == during.seq + 1  # numbers are never reused
    decision, _ = step(core, START + 13 * T_C, bus_up=True)
    assert [(o.kind, o.seq) for o in decision.frames] == [("command", fresh.seq)]


def test_a_refused_refresh_of_a_setpoint_that_went_out_drops_nothing() -> None:
    core = core_with(quiet(), offline_after_missed=1)
    core.submit("s1", 10.0, "test", START - 0.01)
    step(core, START, bus_up=True)
    _, failures = step(core, START + T_C, bus_up=False)
    assert [(f.went_offline, f.dropped) for f in failures] == [(True, None)]
    decision, _ = step(core, START + 2 * T_C, bus_up=True)
    assert [o.seq for o in decision.frames] == [1]


def test_a_servo_with_nothing_to_probe_with_comes_back_when_a_send_works() -> None:
    core = core_with(quiet("s1", 1), quiet("s2", 2), offline_after_missed=1)
    core.submit("s2", 10.0, "test", START - 0.01)
    step(core, START, bus_up=True)
    # s1's first setpoint meets the outage: dropped, and s1 has no poll and no last setpoint
    core.submit("s1", 30.0, "test", START + 0.01)
    _, failures = step(core, START + T_C, bus_up=False)
    assert [f.dropped.seq for f in failures if f.dropped] == [1]
    assert not core.is_online("s1") and not core.is_online("s2")
    decision = core.step(START + 2 * T_C)
    assert [o.servo for o in decision.frames] == ["s2"]  # nothing left to send to s1
    back = core.sent(decision.frames[0], START + 2 * T_C)
    assert back == ["s1"] and core.is_online("s1")
    assert not core.is_online("s2")  # s2 has its refresh: its reply says when it is back


def test_a_late_reply_says_how_long_after_its_request_it_came() -> None:
    core = core_with(quiet(), reply_timeout_s=0.02, refresh_interval_s=1.0, offline_after_missed=10)
    core.submit("s1", 10.0, "test", START - 0.01)
    decision = core.step(START)
    (out,) = decision.frames
    core.sent(out, START)
    assert core.step(START + T_C).lost == ["s1"]  # timed out at START + 0.02
    match = core.on_reply("s1", START + 0.08, out.expectations[0].key)
    assert match.kind == "late"
    assert match.late_latency_s == pytest.approx(0.08)
    again = core.on_reply("s1", START + 0.081, out.expectations[0].key)
    assert again.kind == "late" and again.late_latency_s is None  # each timeout answers once
