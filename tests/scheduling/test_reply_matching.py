"""Reply matching without sequence numbers: a lost reply is declared where it happened.

The scheduler core runs on a fake clock with a fake wire: every frame it sends gets a reply
after a latency, except the ones a test drops; replies are delivered in send order, as a CAN
node sends them.
"""

from __future__ import annotations

import heapq
import random
from collections.abc import Callable
from dataclasses import dataclass, field

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mavservo.scheduling.reply_matching import ReplyMatcher
from mavservo.scheduling.schedule_core import ScheduleCore, ServoSpec, TimingConfig, exchange_key
from mavservo.servos import CubeMarsAK, RmdX
from tests.support.servos import RmdXWithoutStartUp

T_C = 0.02
TIMEOUT = 0.05


@dataclass
class Sent:
    t_tx: float
    key: int | None = None


@dataclass
class Wire:
    """One servo's replies: latency per frame, dropped frames, first-in first-out delivery."""

    latency: Callable[[int], float]  # frame index -> seconds
    drop: set[int] = field(default_factory=set)
    pending: list[tuple[float, int, int | None]] = field(default_factory=list)
    sent: list[tuple[float, int | None]] = field(default_factory=list)
    last_reply: float = 0.0

    def send(self, t: float, key: int | None) -> None:
        index = len(self.sent)
        self.sent.append((t, key))
        if index in self.drop:
            return
        reply = max(t + self.latency(index), self.last_reply + 1e-5)
        self.last_reply = reply
        heapq.heappush(self.pending, (reply, index, key))


@dataclass
class Outcome:
    lost_at: list[float] = field(default_factory=list)
    steps: list[float] = field(default_factory=list)
    late: int = 0
    matched: int = 0

    def declared_by(self, t: float) -> int:
        return sum(lost_at <= t for lost_at in self.lost_at)


def drive(wire: Wire, seconds: float, telemetry_period_s: float = 10.0) -> Outcome:
    """Run one RMD-X servo with a new setpoint every slot; return what the core declared."""
    spec = ServoSpec("s1", RmdXWithoutStartUp(1))
    core = ScheduleCore(
        [spec],
        TimingConfig(
            command_period_s=T_C,
            telemetry_period_s=telemetry_period_s,
            reply_timeout_s=TIMEOUT,
            offline_after_missed=1000,
        ),
        start=100.0,
    )
    outcome = Outcome()
    now, angle = 100.0, 0.0
    for _ in range(10_000):  # bounded: ends by time well before this
        if now > 100.0 + seconds:
            break
        while wire.pending and wire.pending[0][0] <= now:
            t, _, key = heapq.heappop(wire.pending)
            match = core.on_reply("s1", t, key)
            outcome.late += match.kind == "late"
            outcome.matched += match.kind in ("command", "refresh", "request")
        angle += 0.1
        core.submit("s1", angle, "test", t=now)
        decision = core.step(now)
        outcome.steps.append(now)
        outcome.lost_at += [now] * len(decision.lost)
        for out in decision.frames:
            core.sent(out, now)
            wire.send(now, exchange_key(spec.profile, out.msg))
        now = decision.next_deadline
    return outcome


def test_one_lost_reply_is_declared_within_its_timeout_not_carried_along():
    wire = Wire(latency=lambda i: 0.0015, drop={10})
    outcome = drive(wire, seconds=2.0)
    (lost_at,) = outcome.lost_at  # exactly one loss ...
    t_drop = wire.sent[10][0]
    assert t_drop + TIMEOUT <= lost_at <= t_drop + TIMEOUT + T_C  # ... where it happened
    assert outcome.late == 0
    assert outcome.matched == len(wire.sent) - 1 - len(wire.pending)  # all others matched


def test_a_servo_slower_than_the_command_period_loses_nothing():
    wire = Wire(latency=lambda i: 0.03, drop=set())
    outcome = drive(wire, seconds=2.0)
    assert outcome.lost_at == [] and outcome.late == 0


def test_a_servo_that_suddenly_slows_down_keeps_its_replies_in_order():
    wire = Wire(latency=lambda i: 0.0015 if i < 40 else 0.035)
    outcome = drive(wire, seconds=3.0)
    assert outcome.lost_at == [] and outcome.late == 0


def test_a_reply_of_another_kind_does_not_take_a_lost_reply_s_place():
    # Telemetry polls (9C) interleave with position commands (A4); one poll reply is lost.
    # The run is deterministic, so a first run tells which frame is a poll.
    probe = Wire(latency=lambda i: 0.002)
    assert drive(probe, seconds=1.0, telemetry_period_s=0.1).lost_at == []
    poll = next(i for i, (_, key) in enumerate(probe.sent) if key == 0x9C and i > 5)
    wire = Wire(latency=lambda i: 0.002, drop={poll})
    outcome = drive(wire, seconds=1.0, telemetry_period_s=0.1)
    (lost_at,) = outcome.lost_at
    t_drop = wire.sent[poll][0]
    assert t_drop + TIMEOUT <= lost_at <= t_drop + TIMEOUT + T_C
    assert outcome.late == 0


@settings(max_examples=60, deadline=None)
@given(
    latency_ms=st.floats(0.3, 30.0),
    seed=st.integers(0, 2**32 - 1),
    drop_rate=st.sampled_from([0.01, 0.05, 0.2]),
)
def test_every_loss_is_declared_exactly_at_its_own_deadline(latency_ms, seed, drop_rate):
    """Any latency from 0.3 ms to beyond the command period, jitter under 1 ms, random losses
    of commands and polls once the servo has answered a few (its latency is learned): at
    every step the losses declared are exactly the dropped replies whose deadline has passed
    (none carried along, none invented), and no reply is counted late."""
    rng = random.Random(seed)
    jitter = [rng.uniform(0.0, 0.001) for _ in range(2_000)]
    drop = {i for i in range(10, 2_000) if rng.random() < drop_rate} | {rng.randrange(10, 60)}
    wire = Wire(latency=lambda i: latency_ms / 1000 + jitter[i % len(jitter)], drop=drop)
    outcome = drive(wire, seconds=1.5, telemetry_period_s=0.1)
    dropped = [wire.sent[i][0] for i in sorted(drop) if i < len(wire.sent)]
    assert dropped  # the draw lost something
    for now in outcome.steps:
        assert outcome.declared_by(now) == sum(t + TIMEOUT <= now for t in dropped), now
    assert outcome.late == 0


def test_matcher_takes_the_oldest_until_it_has_learned_a_latency():
    matcher = ReplyMatcher()
    expected = [Sent(0.000, 0xA4), Sent(0.020, 0xA4)]
    assert matcher.pick(expected, 0.0215, 0xA4) == 0
    assert matcher.typical_latency_s is None  # a pick among several teaches nothing
    assert matcher.pick([Sent(0.040, 0xA4)], 0.0415, 0xA4) == 0
    assert matcher.typical_latency_s == pytest.approx(0.0015)  # a certain one does


def test_matcher_prefers_the_candidate_of_typical_latency():
    matcher = ReplyMatcher(typical_latency_s=0.0015)
    expected = [Sent(0.000, 0xA4), Sent(0.010, 0x9C), Sent(0.020, 0xA4)]
    assert matcher.pick(expected, 0.0215, 0xA4) == 2  # the 21.5 ms old one was lost
    assert matcher.pick(expected, 0.0115, 0x9C) == 1  # kind first
    assert matcher.pick(expected, 0.0215, 0x92) is None  # nothing of its kind: late


def test_matcher_ignores_requests_sent_after_the_reply_arrived():
    matcher = ReplyMatcher(typical_latency_s=0.012)
    expected = [Sent(0.000, 0xA4), Sent(0.010, 0xA4)]  # immediate commands 10 ms apart
    assert matcher.pick(expected, 0.0035, 0xA4) == 0


def test_profiles_without_an_exchange_key_match_any_expectation():
    cubemars = CubeMarsAK(1)
    command = cubemars.position_command(10.0)
    assert exchange_key(cubemars, command) is None
    rmd = RmdX(1)
    assert exchange_key(rmd, rmd.position_command(10.0)) == 0xA4
    assert [exchange_key(rmd, m) for m in rmd.telemetry_requests()] == [0x9C]
