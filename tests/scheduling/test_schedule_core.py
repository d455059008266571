"""The scheduler's policy core under a fake clock: deterministic, no threads, no sleeping."""

from __future__ import annotations

import math

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mavservo.scheduling.busload import frame_time
from mavservo.scheduling.schedule_core import (
    Decision,
    ScheduleCore,
    ScheduleError,
    ServoSpec,
    TimingConfig,
)
from mavservo.servos import RmdX, ServoProfile
from tests.support.servos import RmdXWithoutStartUp

T_C = 0.05
T_T = 0.09


class PushServo(ServoProfile):
    """A tiny push-style profile: commands on 0x300+id, status pushed on 0x380+id, no requests."""

    replies_per_command = 0
    replies_per_request = 0

    def __init__(self, can_id: int) -> None:
        self.can_id = can_id

    def position_command(self, angle_deg: float, max_speed_dps: float | None = None):
        if abs(angle_deg) > 180:
            raise ValueError("angle outside +-180")
        raw = int(round(angle_deg * 100)).to_bytes(4, "little", signed=True)
        return can.Message(arbitration_id=0x300 + self.can_id, is_extended_id=False, data=raw)

    def telemetry_requests(self) -> list[can.Message]:
        return []

    def is_reply(self, msg: can.Message) -> bool:
        return msg.arbitration_id == 0x380 + self.can_id

    def decode(self, msg, timestamp):  # not used by the core
        return None

    def identifiers(self):  # not used by the core
        return ()

    @classmethod
    def sim_device(cls, motor, can_id, options):  # not used by the core
        raise NotImplementedError


def rmd(n: int, **kwargs) -> list[ServoSpec]:
    return [ServoSpec(f"s{i}", RmdXWithoutStartUp(i), **kwargs) for i in range(1, n + 1)]


def core_with(specs, start: float = 100.0, **timing) -> ScheduleCore:
    return ScheduleCore(specs, TimingConfig(**timing), start=start)


def run(core: ScheduleCore, now: float) -> Decision:
    """One step with every frame 'sent' at the decision time (the fake wire is instant)."""
    decision = core.step(now)
    for out in decision.frames:
        core.sent(out, now)
    return decision


def kinds(decision: Decision) -> list[tuple[str, str]]:
    return [(out.servo, out.kind) for out in decision.frames]


def test_periodic_setpoint_waits_for_the_next_slot_and_goes_before_requests():
    core = core_with(rmd(2), telemetry_phase_s=0.0)
    first = run(core, 100.0)  # slot 0 and telemetry tick 0: nothing to command yet
    assert kinds(first) == [("s1", "request"), ("s2", "request")]
    assert first.next_deadline == pytest.approx(100.0 + T_C)

    result = core.submit("s1", 10.0, "test", t=100.01)
    assert result.accepted and result.seq == 1
    assert run(core, 100.02).frames == []  # periodic: not before the slot

    slot = run(core, 100.0 + T_C)
    assert kinds(slot) == [("s1", "command")]
    assert slot.command_slot == pytest.approx(100.0 + T_C)
    assert slot.frames[0].msg.data == RmdX(1).position_command(10.0).data


def test_commands_come_first_when_slot_and_telemetry_tick_coincide():
    core = core_with(rmd(3), telemetry_phase_s=0.0)  # an explicit phase of 0: they coincide
    for name in ("s1", "s2", "s3"):
        core.submit(name, 1.0, "test", t=99.0)
    decision = run(core, 100.0)
    order = [out.kind for out in decision.frames]
    assert order == ["command"] * 3 + ["request"] * 3


def test_refresh_every_slot_by_default_with_the_same_sequence_number():
    core = core_with(rmd(1))
    core.submit("s1", 5.0, "test", t=99.0)
    sent = [run(core, 100.0 + k * T_C) for k in range(5)]
    commands = [out for d in sent for out in d.frames if out.kind != "request"]
    assert [out.kind for out in commands] == ["command"] + ["refresh"] * 4
    assert {out.seq for out in commands} == {1}


def test_refresh_interval_resends_only_after_silence_and_a_new_setpoint_restarts_it():
    core = core_with(rmd(1), refresh_interval_s=0.2, telemetry_period_s=10.0)
    core.submit("s1", 5.0, "test", t=99.0)
    slots = {}
    for k in range(12):
        now = 100.0 + k * T_C
        if k == 6:
            core.submit("s1", 7.0, "test", t=now - 0.001)
        slots[k] = [out.kind for out in run(core, now).frames if out.kind != "request"]
    assert slots[0] == ["command"]
    assert [k for k, v in slots.items() if v == ["refresh"]] == [4, 10]
    assert slots[6] == ["command"]


def test_stale_setpoint_is_rejected_and_newer_one_wins():
    core = core_with(rmd(1))
    assert core.submit("s1", 1.0, "mavlink", t=50.0).accepted
    stale = core.submit("s1", 2.0, "mavlink", t=49.0)
    assert not stale.accepted and "stale" in stale.reason
    assert core.latest("s1").angle_deg == 1.0
    newer = core.submit("s1", 3.0, "gimbal", t=50.0)
    assert newer.accepted and newer.seq == 2


@pytest.mark.parametrize("angle", [math.nan, math.inf])
def test_non_finite_and_unknown_setpoints_are_rejected(angle):
    core = core_with(rmd(1))
    assert not core.submit("s1", angle, "test", t=1.0).accepted
    assert not core.submit("nope", 1.0, "test", t=1.0).accepted


def test_profile_refusal_becomes_a_rejection_with_its_reason():
    core = core_with([ServoSpec("p", PushServo(1))])
    result = core.submit("p", 500.0, "test", t=1.0)
    assert not result.accepted and "180" in result.reason


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(st.floats(0.0, 0.2), st.booleans(), st.floats(-90, 90)),
        min_size=1,
        max_size=40,
    )
)
def test_frames_never_carry_an_older_setpoint_than_one_already_sent(events):
    specs = [ServoSpec("s1", RmdX(1), command_mode="immediate"), ServoSpec("s2", RmdX(2))]
    core = core_with(specs, immediate_min_spacing_s=0.02)
    now = 100.0
    highest_sent = {"s1": 0, "s2": 0}
    last_immediate_send = -math.inf
    for dt, submit_first, angle in events:
        now += dt
        if submit_first:
            core.submit("s1" if angle > 0 else "s2", angle, "test", t=now)
        for out in run(core, now).frames:
            if out.seq is not None:
                assert out.seq >= highest_sent[out.servo]
                assert out.seq == core.latest(out.servo).seq
                highest_sent[out.servo] = out.seq
            if out.servo == "s1" and out.kind in ("command", "refresh"):
                # the minimum spacing holds for every command to an immediate servo, slots too
                # (its start-up frame goes right before its first command)
                assert now - last_immediate_send >= 0.02 - 1e-9
                last_immediate_send = now


def test_immediate_mode_sends_at_once_but_respects_minimum_spacing():
    core = core_with(
        rmd(1, command_mode="immediate"), immediate_min_spacing_s=0.01, telemetry_phase_s=0.0
    )
    run(core, 100.0)
    core.submit("s1", 1.0, "test", t=100.003)
    assert core.wants_immediate_wake("s1")
    first = run(core, 100.003)
    assert kinds(first) == [("s1", "command")]

    core.submit("s1", 2.0, "test", t=100.005)
    held = run(core, 100.005)
    assert held.frames == []
    assert held.next_deadline == pytest.approx(100.013)
    released = run(core, 100.013)
    assert [(o.kind, o.seq) for o in released.frames] == [("command", 2)]


def test_telemetry_deferred_near_a_command_slot_goes_right_after_its_commands():
    # Tick at +90 ms is 10 ms before the slot at +100 ms; a 15 ms guard suspends polling.
    core = core_with(rmd(2), command_guard_s=0.015, telemetry_phase_s=0.0)
    for name in ("s1", "s2"):
        core.submit(name, 0.0, "test", t=99.0)
    run(core, 100.0)
    run(core, 100.05)
    tick = run(core, 100.09)
    assert tick.telemetry_tick == pytest.approx(100.09)
    assert tick.frames == [] and tick.deferred_polls == 2
    assert tick.next_deadline == pytest.approx(100.10)
    slot = run(core, 100.10)
    assert [o.kind for o in slot.frames] == ["refresh", "refresh", "request", "request"]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0.0005, 0.03), min_size=5, max_size=60), st.integers(1, 12))
def test_no_request_can_still_be_on_the_bus_when_the_next_slot_starts(gaps, n_servos):
    timing = {"bitrate": 250_000, "command_guard_s": 0.002, "max_load": 1.0}
    core = core_with(rmd(n_servos), **timing)
    for spec in rmd(n_servos):
        core.submit(spec.name, 0.0, "test", t=0.0)
    request_cost = frame_time(False, 8, 250_000) * 2
    command_cost = frame_time(False, 8, 250_000) * 2
    now = 100.0
    for gap in gaps:
        now += gap
        decision = run(core, now)
        commands = sum(1 for o in decision.frames if o.kind != "request")
        requests = sum(1 for o in decision.frames if o.kind == "request")
        if not requests:
            continue
        if decision.command_slot is not None:
            next_slot = decision.command_slot + T_C
        else:
            next_slot = 100.0 + math.ceil((now - 100.0) / T_C) * T_C
        finish = now + commands * command_cost + requests * request_cost
        assert finish <= next_slot - 0.002 + 1e-9


def test_round_robin_polls_all_32_servos_once_per_tick():
    core = core_with(rmd(32), max_load=0.9)
    assert core.warnings == []
    polls = {f"s{i}": 0 for i in range(1, 33)}
    now, ticks = 100.0, 0
    while now < 100.0 + 20 * T_T - 1e-9:
        decision = run(core, now)
        if decision.telemetry_tick is not None:
            ticks += 1
        for out in decision.frames:
            if out.kind == "request":
                polls[out.servo] += 1
                core.on_reply(out.servo, now + 0.001)
        now = decision.next_deadline
    assert set(polls.values()) == {ticks}


def test_polls_that_cannot_fit_degrade_fairly_and_say_so():
    # A 35 ms guard before every 50 ms slot leaves too little bus for 32 polls per 90 ms.
    core = core_with(rmd(32), max_load=0.9, bitrate=500_000, command_guard_s=0.035)
    assert any("cannot keep its rate" in w for w in core.warnings)
    polls = {f"s{i}": 0 for i in range(1, 33)}
    for name in polls:
        core.submit(name, 0.0, "test", t=99.0)  # every slot carries 32 commands
    now, ticks, late = 100.0, 0, 0
    while now < 100.0 + 30 * T_T:
        decision = run(core, now)
        ticks += decision.telemetry_tick is not None
        late += len(decision.late_polls)
        for out in decision.frames:
            if out.kind == "request":
                polls[out.servo] += 1
                core.on_reply(out.servo, now)
        now = decision.next_deadline
    assert max(polls.values()) < ticks  # the configured rate is not reached ...
    assert max(polls.values()) - min(polls.values()) <= 2  # ... but nobody starves
    assert late > 0  # ... and the late polls are reported


def test_late_wakeup_serves_the_latest_slot_and_counts_the_missed_ones():
    core = core_with(rmd(1), telemetry_period_s=10.0, telemetry_phase_s=0.0)
    core.submit("s1", 1.0, "test", t=99.0)
    run(core, 100.0)
    late = run(core, 100.0 + 3.2 * T_C)
    assert late.missed_slots == 2
    assert late.command_slot == pytest.approx(100.0 + 3 * T_C)
    assert [o.kind for o in late.frames] == ["refresh"]  # one frame, no burst of replays
    assert late.next_deadline == pytest.approx(100.0 + 4 * T_C)


def test_lost_replies_take_a_servo_offline_and_a_reply_brings_it_back():
    core = core_with(rmd(1), reply_timeout_s=0.02, offline_after_missed=3)
    core.submit("s1", 1.0, "test", t=99.0)
    went_offline, lost = [], 0
    for k in range(4):
        decision = run(core, 100.0 + k * T_C)
        lost += len(decision.lost)
        went_offline += decision.went_offline
    assert lost >= 3 and went_offline == ["s1"]
    assert not core.is_online("s1")
    match = core.on_reply("s1", 100.0 + 3 * T_C + 0.001)
    assert match.back_online and core.is_online("s1")


def test_reply_latency_is_measured_from_the_real_write_time():
    core = core_with(rmd(1), telemetry_period_s=10.0, telemetry_phase_s=0.0)
    run(core, 100.0)  # consume the first telemetry tick
    core.on_reply("s1", 100.0005)
    core.submit("s1", 1.0, "test", t=100.01)
    decision = core.step(100.05)
    (out,) = decision.frames
    core.sent(out, 100.0503)
    match = core.on_reply("s1", 100.0515)
    assert match.kind == "command"
    assert match.latency_s == pytest.approx(0.0012)


def test_push_servo_latency_is_first_status_after_the_command():
    core = core_with([ServoSpec("p", PushServo(1))])
    core.submit("p", 1.0, "test", t=99.0)
    (out,) = core.step(100.0).frames
    core.sent(out, 100.001)
    first = core.on_reply("p", 100.004)
    assert first.kind is None and first.latency_s == pytest.approx(0.003)
    assert core.on_reply("p", 100.006).latency_s is None


def test_release_stops_refresh_until_the_next_setpoint():
    core = core_with(rmd(1), telemetry_period_s=10.0, telemetry_phase_s=0.0)
    core.submit("s1", 1.0, "test", t=99.0)
    run(core, 100.0)
    core.release("s1")
    released = [o for k in range(1, 4) for o in run(core, 100.0 + k * T_C).frames]
    # the profile's release frame (RMD-X 0x80, motor off) once, then nothing
    assert [(o.kind, o.lifecycle, o.msg.data[0]) for o in released] == [
        ("lifecycle", "release", 0x80)
    ]
    core.submit("s1", 2.0, "test", t=100.2)
    assert [o.kind for o in run(core, 100.25).frames] == ["command"]


def test_over_budget_schedule_is_refused_with_its_load():
    # 16 RMD servos at 125 kbit/s: commands alone are 16 * 20 Hz * 270 bit = 69 % of the bus.
    with pytest.raises(ScheduleError) as refused:
        core_with(rmd(16), bitrate=125_000, max_load=0.5)
    message = str(refused.value)
    assert "R = " in message and "exceeds max_load 50.0%" in message
    expected = 16 * (20 * 270 + (1 / T_T) * 270) / 125_000
    assert f"{expected:.1%}" in message


def test_immediate_mode_counts_its_worst_case_in_the_budget():
    periodic = core_with(rmd(4), max_load=1.0).worst_case_load
    immediate = core_with(
        rmd(4, command_mode="immediate"), max_load=1.0, immediate_min_spacing_s=0.01
    ).worst_case_load
    # 100 commands/s at 10 ms spacing replace the 20/s of the slots (270 bits with the reply)
    assert immediate == pytest.approx(periodic + 4 * (100 - 20) * 270 / 1_000_000)


@pytest.mark.parametrize(
    "bad",
    [
        {"command_period_s": 0},
        {"max_load": -1},
        {"offline_after_missed": 0},
        {"refresh_interval_s": 0},
        {"bitrate": math.nan},
    ],
)
def test_bad_timing_is_refused(bad):
    with pytest.raises(ScheduleError):
        TimingConfig(**bad)


def test_duplicate_names_and_bad_modes_are_refused():
    with pytest.raises(ScheduleError):
        core_with([ServoSpec("a", RmdX(1)), ServoSpec("a", RmdX(2))])
    with pytest.raises(ScheduleError):
        ServoSpec("a", RmdX(1), command_mode="sometimes")


def drive(core: ScheduleCore, until: float, reply_after: float = 0.001) -> list[Decision]:
    """Step ``core`` from deadline to deadline until ``until``, answering every frame."""
    decisions = []
    now = core.start
    for _ in range(10_000):  # bounded: a few thousand deadlines at most
        if now >= until - 1e-9:
            break
        decision = run(core, now)
        decisions.append((now, decision))
        for out in decision.frames:
            for _ in out.expectations:
                core.on_reply(out.servo, now + reply_after)
        now = decision.next_deadline
    return decisions


def test_automatic_phase_keeps_every_poll_round_clear_of_the_command_bursts():
    # T_c 50 ms, T_t 90 ms: with ticks anchored on a slot, every 5th tick fell on one and its
    # polls queued behind 8 commands. Phased, no tick shares a step with a slot, every poll
    # round starts after the slot's command burst and ends before the next slot's guard.
    servos = rmd(8)
    core = core_with(servos, start=100.0)
    timing = core.timing
    command_burst = 8 * 2 * frame_time(False, 8, timing.bitrate)
    poll_burst = command_burst  # one 8-byte request and one 8-byte reply per servo
    for name in core.servo_names:
        core.submit(name, 0.0, "test", t=99.0)
    decisions = drive(core, until=100.0 + 45 * T_T)
    ticks = [(now, d) for now, d in decisions if d.telemetry_tick is not None]
    assert len(ticks) >= 44
    for now, decision in ticks:
        assert decision.command_slot is None
        assert [o.kind for o in decision.frames] == ["request"] * 8
        since_slot = (now - 100.0) % T_C
        assert since_slot >= command_burst - 1e-9
        assert since_slot + poll_burst <= T_C - timing.command_guard_s + 1e-9
    # the phase does not disturb the tick period: still exactly T_t apart
    times = [d.telemetry_tick for _, d in ticks]
    assert all(b - a == pytest.approx(T_T) for a, b in zip(times, times[1:], strict=False))
    # the phase is the middle of the free gap: ticks land 4.5 ms + k * 10 ms after a slot
    gap = 0.010 - timing.command_guard_s - poll_burst - command_burst
    assert core.telemetry_phase_s == pytest.approx(command_burst + gap / 2)


def test_each_servo_keeps_its_place_in_the_poll_round():
    # A fixed order keeps every reply at the same offset after its tick; the old rotating
    # order moved each servo by one place per tick (up to 7 polls of reply jitter).
    core = core_with(rmd(8))
    places: dict[str, set[int]] = {name: set() for name in core.servo_names}
    for _, decision in drive(core, until=100.0 + 20 * T_T):
        requests = [o.servo for o in decision.frames if o.kind == "request"]
        for place, name in enumerate(requests):
            places[name].add(place)
    assert places == {f"s{i}": {i - 1} for i in range(1, 9)}


def test_every_servo_is_polled_at_its_own_rate_with_the_phase():
    # the phase moves the first tick, not the rates: a 5 Hz servo beside 1/T_t ones
    specs = [ServoSpec("fast", RmdX(1)), ServoSpec("slow", RmdX(2), telemetry_hz=5.0)]
    core = core_with(specs)
    polls: dict[str, list[float]] = {"fast": [], "slow": []}
    for now, decision in drive(core, until=100.0 + 2.0):
        for out in decision.frames:
            if out.kind == "request":
                polls[out.servo].append(now)
    assert polls["fast"][0] == pytest.approx(100.0 + core.telemetry_phase_s)
    assert len(polls["fast"]) == pytest.approx(2.0 / T_T, abs=1)
    slow = polls["slow"]
    # 5 Hz on a 90 ms tick: polled on the tick nearest each 200 ms due time (2 or 3 ticks
    # apart), 200 ms on average
    gaps = [b - a for a, b in zip(slow, slow[1:], strict=False)]
    assert {round(g / T_T) for g in gaps} == {2, 3}
    assert all(g == pytest.approx(round(g / T_T) * T_T) for g in gaps)
    assert (slow[-1] - slow[0]) / len(gaps) == pytest.approx(0.2, abs=0.02)


def test_bursts_too_long_for_the_gap_start_polls_right_after_the_commands():
    # 32 servos at 1 Mbit/s: 8.6 ms of commands leave no clear phase in a 10 ms gap
    core = core_with(rmd(32), max_load=0.9)
    assert core.telemetry_phase_s == pytest.approx(32 * 2 * frame_time(False, 8, 1_000_000))


@pytest.mark.parametrize("phase", [-0.001, T_T, math.nan])
def test_a_phase_outside_the_telemetry_period_is_refused(phase):
    with pytest.raises(ScheduleError, match="telemetry_phase_s"):
        TimingConfig(telemetry_phase_s=phase)


def test_mark_failsafe_relabels_the_setpoint_in_force_without_a_new_command():
    core = core_with(rmd(1), telemetry_phase_s=0.0)
    assert core.submit("s1", 10.0, "servo_output_raw", t=100.0).seq == 1
    core.mark_failsafe("s1")
    latest = core._slots["s1"].latest
    assert latest is not None
    assert (latest.seq, latest.angle_deg, latest.source) == (1, 10.0, "failsafe")
    core.mark_failsafe("nobody")  # an unknown servo: nothing to mark, no error
