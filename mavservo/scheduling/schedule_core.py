"""The scheduler's policy core: what goes on the bus when, as a pure state machine.

No threads, no I/O, no clock: ``step(now)`` is given the time and returns the frames to send
now, in order, and when to call it again; ``submit`` accepts setpoints; ``on_reply`` and
``sent``/``send_failed`` feed back what happened on the wire. That is what the fake-clock tests
drive, and what :mod:`mavservo.scheduling.runner` runs on absolute monotonic deadlines.

Rules (paper section 3.3):

* Command slots every ``command_period_s`` on absolute deadlines ``start + k * T_c``. A late
  wake-up serves the most recent slot and counts the skipped ones as missed; it never replays
  them (replaying would send bursts of stale commands).
* Within a step, command frames always come before telemetry requests.
* Telemetry is suspended around command slots: a request is sent only if it, and the replies
  it provokes, fit on the bus before ``next command slot - command_guard_s``. Requests that do
  not fit wait until the commands of that slot have gone out (the paper's "resume once the
  command interval is satisfied"), so no request ever delays a command past its slot.
* ``periodic`` servos: a new setpoint goes out on the next command slot (latency 0..T_c, mean
  T_c/2 plus the loop's wake-up error). ``immediate`` servos: a new setpoint goes out at once
  (the runner is woken), but never sooner than ``immediate_min_spacing_s`` after the previous
  command to that servo, slots included (latency ~ wake-up error, at most the spacing); slots
  still refresh. Worst-case rate: max(1 / T_c, 1 / spacing).
* Keep-alive: a servo with a setpoint and no newer one for ``refresh_interval_s`` gets its
  last setpoint re-sent on a slot. Frames only ever carry the newest accepted setpoint, and
  setpoints carry per-servo sequence numbers, so a stale setpoint can never follow a newer one.
* Telemetry: every servo has its own poll deadline at its own rate (``telemetry_hz``, default
  ``1 / telemetry_period_s``) checked on telemetry ticks every ``telemetry_period_s``; due
  servos are served oldest-due first, equally due ones in configuration order. The order is
  fixed on purpose: a servo keeps its place in the round, so its reply comes back at the same
  offset after every tick and its reception intervals stay on the period (a rotating order
  moved each reply by up to ``n - 1`` polls from tick to tick). Fairness when polls do not fit
  comes from the oldest-due rule and the deferred polls keeping the front of the next round.
  A servo with a request still unanswered is not polled again until the reply or its timeout.
* Telemetry ticks are phased away from command slots (``telemetry_phase_s``, default
  automatic): ticks fall at ``start + phase + k * T_t``, i.e. at ``phase mod g`` plus
  multiples of ``g = gcd(T_c, T_t)`` after a slot, and the automatic phase puts them in the
  middle of the bus time left between a slot's command burst (commands and their replies) and
  the guard plus the poll burst before the next slot. Without it, every ``T_c / g``-th tick
  landed on a slot and its polls queued behind the slot's commands: their replies came
  ~1.6 ms late and two reception intervals in every ``T_c / g`` were off by that much.
* A reply expected but not received within ``reply_timeout_s`` is lost; after
  ``offline_after_missed`` losses in a row a servo is offline until its next reply. A frame
  the bus refused (``send_failed``: adapter unplugged, bus down) counts as a miss too: while
  the bus is away no request goes out, so no reply is ever owed and none could be declared
  lost, and the servo would read online, with frozen data, for the whole outage.
* A servo going offline drops its setpoint that never went out (``Decision.dropped``), and
  while it is offline every setpoint whose send the bus refuses is dropped too
  (``SendFailure.dropped``): the bus is gone or the servo is not answering, and applying it
  whenever the bus or the servo is back, seconds later, would be a late command (the trial's
  payload servo moved 12 s after its ACK). The servo keeps being refreshed with its last
  setpoint that did go out (a position it already had, and the probe that tells when it is
  back) and moves again on a fresh setpoint. A servo with nothing to probe with (no polls,
  no pushes, no setpoint that went out) that went offline on refused sends comes back when a
  send on the bus works again (``sent`` returns it): nothing else could ever bring it back. A reply
  is matched to an expectation of its own kind and plausible latency
  (:mod:`mavservo.scheduling.reply_matching`), so one lost reply is declared lost where it happened
  and
  not carried along by the replies after it.
* Liveness follows from the profile's telemetry shape, one rule per shape: a *polled* servo
  (its profile has telemetry requests) is alive while it answers them (the misses above); a
  *pushing* servo (no requests; it reports on its own at ``telemetry_hz``) is alive while its
  pushes keep coming: silent for more than ``offline_after_missed`` push periods (plus one
  ``reply_timeout_s`` of slack), counted from its last report or from the start, it goes
  offline, commanded or not, exactly as a polled servo does (``Decision.went_offline``, its
  unsent setpoint dropped). Before, only the replies its commands were owed could take a
  pushing servo offline: an uncommanded one, or one whose sends the adapter still took, read
  online with a frozen state for a whole outage (the trial: ``age 21655 ms``, ``online``). It
  comes back with its next push, not with a working send.
* Lifecycle frames come from the profile and go out through this core like every frame (the
  runner stays the only writer): a servo's start-up frames (enable, mode, its own
  communication-loss timeout) right before its first command, again before the next command
  after it was offline (it may have been power-cycled) or after a release, and again when the
  profile's ``needs_startup()`` says so, never twice within ``STARTUP_RETRY_S``; a ``release``
  sends the profile's release frames (motor off) at the next step (again at the next command
  slot if the bus refused them); :meth:`ScheduleCore.
  final_frames` gives what is still pending plus every servo's shutdown frames when the
  scheduler stops. Their replies (``replies_per_lifecycle``) are expected like any other, and
  the bus-load budget counts the start-up frames at ``1 / STARTUP_RETRY_S``.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Sequence
from dataclasses import dataclass, field, replace
from typing import Literal

import can

from mavservo.errors import MavservoError
from mavservo.servos import ServoProfile

from .bus_plan import REPLY_DLC, plan_bus
from .busload import (
    FrameFlow,
    frame_time,
    message_bits,
)
from .lifecycle import STARTUP_RETRY_S, Lifecycles, ServoLifecycle
from .liveness import Liveness
from .owed_replies import Expectation, OwedReplies, ReplyMatch
from .poll_round import PollRound

CommandMode = Literal["periodic", "immediate"]
FrameKind = Literal["command", "refresh", "request", "lifecycle"]
LifecyclePurpose = Literal["startup", "release", "shutdown"]


class ScheduleError(MavservoError, ValueError):
    """A configuration the scheduler refuses to run (e.g. worst-case bus load over the limit)."""


@dataclass(frozen=True)
class TimingConfig:
    """Timing and budget of one bus. Defaults follow the paper (T_c = 50 ms, T_t = 90 ms)."""

    command_period_s: float = 0.05
    telemetry_period_s: float = 0.09
    refresh_interval_s: float | None = None
    """Re-send the last setpoint after this long without a new one; None: every command slot
    (the paper's fixed-rate command stream)."""
    immediate_min_spacing_s: float = 0.01
    reply_timeout_s: float = 0.05
    offline_after_missed: int = 3
    command_guard_s: float = 0.001
    """No telemetry request may still be on the bus this close before a command slot."""
    max_load: float = 0.5
    bitrate: int = 1_000_000
    spin_s: float = 0.001
    """The runner sleeps until this long before a deadline, then spins (see scheduler)."""
    fifo_spin_s: float = 0.0
    """The spin used instead of ``spin_s`` when the runner thread runs under SCHED_FIFO
    (``realtime=True``, or inherited, e.g. systemd's ``CPUSchedulingPolicy=fifo``): a FIFO
    thread's plain timed wake-up is already within ~0.25 ms at p99, and a spin it runs is never
    preempted, so it buys little and costs CPU (see docs/benchmarks.md, Scheduler)."""
    telemetry_phase_s: float | None = None
    """Offset of the first telemetry tick after the first command slot, in
    ``[0, telemetry_period_s)``; None: automatic, clear of command bursts (module docstring)."""
    realtime: bool = False
    realtime_priority: int = 50
    load_window_s: float = 1.0

    def __post_init__(self) -> None:
        positive = {
            "command_period_s": self.command_period_s,
            "telemetry_period_s": self.telemetry_period_s,
            "immediate_min_spacing_s": self.immediate_min_spacing_s,
            "reply_timeout_s": self.reply_timeout_s,
            "max_load": self.max_load,
            "bitrate": self.bitrate,
            "load_window_s": self.load_window_s,
        }
        for name, value in positive.items():
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ScheduleError(f"timing: {name} must be a positive number, got {value!r}")
        if self.refresh_interval_s is not None and not self.refresh_interval_s > 0:
            raise ScheduleError("timing: refresh_interval_s must be positive or None")
        if self.command_guard_s < 0 or self.spin_s < 0 or self.fifo_spin_s < 0:
            raise ScheduleError("timing: command_guard_s, spin_s and fifo_spin_s must be >= 0")
        if self.telemetry_phase_s is not None and not (
            math.isfinite(self.telemetry_phase_s)
            and 0 <= self.telemetry_phase_s < self.telemetry_period_s
        ):
            raise ScheduleError(
                "timing: telemetry_phase_s must be None or in [0, telemetry_period_s), "
                f"got {self.telemetry_phase_s!r}"
            )
        if self.offline_after_missed < 1:
            raise ScheduleError("timing: offline_after_missed must be >= 1")

    @property
    def refresh_s(self) -> float:
        return self.command_period_s if self.refresh_interval_s is None else self.refresh_interval_s


@dataclass(frozen=True)
class ServoSpec:
    """One servo on this bus: its name (as the mapping layer knows it), profile and policy."""

    name: str
    profile: ServoProfile
    """The contract the scheduler reads: frames, replies per frame, exchange keys, polls."""
    command_mode: CommandMode = "periodic"
    telemetry_hz: float | None = None
    """Polls per second; None: ``1 / telemetry_period_s``; 0: never poll."""
    max_speed_dps: float | None = None

    def __post_init__(self) -> None:
        if self.command_mode not in ("periodic", "immediate"):
            raise ScheduleError(
                f"servo {self.name!r}: command_mode must be 'periodic' or 'immediate', "
                f"got {self.command_mode!r}"
            )
        if self.telemetry_hz is not None and not (
            math.isfinite(self.telemetry_hz) and self.telemetry_hz >= 0
        ):
            raise ScheduleError(f"servo {self.name!r}: telemetry_hz must be >= 0")


@dataclass(frozen=True)
class Setpoint:
    seq: int
    angle_deg: float
    source: str
    t: float
    msg: can.Message


@dataclass(frozen=True)
class SetpointResult:
    """Outcome of ``submit``: accepted with its sequence number, or rejected with a reason."""

    accepted: bool
    seq: int | None
    reason: str = ""


@dataclass(frozen=True)
class Outgoing:
    """One frame to send, in order. ``seq`` is the setpoint's sequence number (None: request)."""

    servo: str
    kind: FrameKind
    msg: can.Message
    seq: int | None
    expectations: tuple[Expectation, ...] = ()
    setpoint: Setpoint | None = None
    lifecycle: LifecyclePurpose | None = None
    """For ``kind == "lifecycle"``: which of the profile's lifecycle lists the frame is from."""


@dataclass(frozen=True)
class SendFailure:
    """What a refused frame did: whether its servo went offline with it, and the unsent
    setpoint dropped because the servo is offline (None: none)."""

    went_offline: bool
    dropped: Setpoint | None


@dataclass
class Decision:
    """The result of one ``step``: frames in send order and the bookkeeping around them."""

    frames: list[Outgoing]
    next_deadline: float
    command_slot: float | None = None
    telemetry_tick: float | None = None
    missed_slots: int = 0
    lost: list[str] = field(default_factory=list)
    went_offline: list[str] = field(default_factory=list)
    dropped: list[tuple[str, Setpoint]] = field(default_factory=list)
    """Setpoints dropped unsent because their servo went offline (module docstring)."""
    late_polls: list[str] = field(default_factory=list)
    deferred_polls: int = 0


@dataclass
class _ServoSlot:
    spec: ServoSpec
    life: ServoLifecycle
    owed: OwedReplies
    poll_period: float | None
    command_cost_s: float
    latest: Setpoint | None = None
    last_sent: Setpoint | None = None
    """The newest setpoint the bus took: what an offline servo is refreshed with."""
    seq: int = 0
    """Last sequence number given out (never reused, even when a setpoint is dropped)."""
    sent_seq: int = 0
    last_command_time: float | None = None
    released: bool = False

    @property
    def has_unsent_setpoint(self) -> bool:
        return not self.released and self.latest is not None and self.latest.seq > self.sent_seq


def exchange_key(profile: ServoProfile, msg: can.Message) -> Hashable | None:
    """The profile's ``exchange_key`` of ``msg``; None for profiles whose replies do not say
    what they answer (they then match any outstanding expectation, oldest plausible first)."""
    return profile.exchange_key(msg)


class ScheduleCore:
    """The dual-loop policy as a state machine driven by ``now`` (see module docstring)."""

    def __init__(
        self,
        servos: Sequence[ServoSpec],
        timing: TimingConfig,
        start: float,
        *,
        packed: frozenset[str] = frozenset(),
        extra_flows: Sequence[FrameFlow] = (),
    ) -> None:
        """``packed``: servos whose commands a bus node packs together (DroneCAN), counted by
        the node's ``extra_flows`` (its commands and heartbeat) instead of one frame each."""
        names = [s.name for s in servos]
        if len(set(names)) != len(names):
            raise ScheduleError(f"duplicate servo names on one bus: {names}")
        if not servos:
            raise ScheduleError("a scheduler needs at least one servo")
        self.timing = timing
        self.start = start
        self.warnings: list[str] = []
        self._slots: dict[str, _ServoSlot] = {}
        self._order = names
        self._next_command_slot = start
        self._lifecycles = Lifecycles([(spec.name, spec.profile) for spec in servos])
        plan = plan_bus(
            servos, timing, startup_retry_s=STARTUP_RETRY_S, packed=packed, extra_flows=extra_flows
        )
        refusal = plan.over_budget(timing)
        if refusal is not None:
            raise ScheduleError(refusal)
        self.worst_case_load = plan.worst_case_load
        self.warnings.extend(plan.warnings)
        for spec in servos:
            costs = plan.servos[spec.name]
            # No staggering: servos sharing the tick rate are polled in the same round, one
            # after another, so each sees exactly one request per T_t.
            self._slots[spec.name] = _ServoSlot(
                spec=spec,
                life=self._lifecycles.servos[spec.name],
                poll_period=costs.poll_period,
                command_cost_s=costs.command_cost_s,
                owed=OwedReplies(
                    only_when_asked=costs.poll_period is not None
                    or bool(spec.profile.replies_per_request),
                    keyed_pushes=spec.profile.telemetry == "pushed",
                ),
            )
        polled = [
            (name, period, plan.servos[name].poll_cost_s)
            for name in names
            if (period := plan.servos[name].poll_period)
        ]
        self._liveness = Liveness(
            [(name, plan.servos[name].push_period) for name in names],
            timing.offline_after_missed,
            timing.reply_timeout_s,
        )
        self.telemetry_phase_s = plan.telemetry_phase_s
        self._polls = PollRound(polled, timing.telemetry_period_s, plan.telemetry_phase_s)
        self._request_outstanding = lambda name: self._slots[name].owed.request_outstanding
        self.anchor(start)

    def anchor(self, start: float) -> None:
        """Move the time origin (the runner anchors the schedule when it actually starts)."""
        self.start = start
        self._next_command_slot = start
        self._polls.anchor(start)
        self._liveness.anchor(start)

    def push_silence_limit_s(self, name: str) -> float | None:
        """How long a pushing servo may stay silent before it is offline (None: not pushing)."""
        return self._liveness.silence_limit_s(name)

    # ----------------------------------------------------------------------- upper layers
    @property
    def servo_names(self) -> list[str]:
        return list(self._order)

    def latest(self, name: str) -> Setpoint | None:
        return self._slots[name].latest

    def is_online(self, name: str) -> bool:
        return self._liveness.is_online(name)

    def submit(self, name: str, angle_deg: float, source: str, t: float) -> SetpointResult:
        """Accept a setpoint unless it is unknown, invalid or older than the accepted one."""
        slot = self._slots.get(name)
        if slot is None:
            return SetpointResult(False, None, f"unknown servo {name!r}")
        if not math.isfinite(angle_deg):
            return SetpointResult(False, None, f"angle must be finite, got {angle_deg!r}")
        latest = slot.latest
        if latest is not None and t < latest.t:
            return SetpointResult(
                False,
                None,
                f"stale: t={t:.6f} is older than accepted setpoint #{latest.seq} "
                f"(t={latest.t:.6f})",
            )
        try:
            msg = slot.spec.profile.position_command(angle_deg, slot.spec.max_speed_dps)
        except ValueError as exc:
            return SetpointResult(False, None, str(exc))
        slot.seq += 1
        seq = slot.seq
        slot.latest = Setpoint(seq, angle_deg, source, t, msg)
        slot.released = False
        self._lifecycles.cancel_release(name)
        return SetpointResult(True, seq)

    def mark_failsafe(self, name: str) -> None:
        """The setpoint in force is held by a failsafe from now on: the same command, no new
        one (its refreshes go on as before), only its source says failsafe, which is what a bus
        node's failsafe plan reads (a DroneCAN SafetyState turned on at failsafe)."""
        slot = self._slots.get(name)
        if slot is not None and slot.latest is not None and slot.latest.source != "failsafe":
            slot.latest = replace(slot.latest, source="failsafe")

    def release(self, name: str) -> None:
        """Stop commanding and refreshing a servo until its next setpoint (failsafe release),
        and send its profile's release frames (motor off) at the next step; the next command
        is preceded by the start-up frames again."""
        self._slots[name].released = True
        self._lifecycles.release(name)

    def wants_lifecycle_wake(self) -> bool:
        """True when release frames wait to go at once (the runner is woken for them)."""
        return self._lifecycles.wants_wake()

    def final_frames(self, now: float) -> list[Outgoing]:
        """What goes out when the scheduler stops: pending release frames, then every servo's
        shutdown frames, in configuration order."""
        out: list[Outgoing] = []
        for name in self._order:
            slot = self._slots[name]
            release, shutdown = self._lifecycles.final_frames(name)
            out += self._lifecycle(slot, release, "release", now)
            out += self._lifecycle(slot, shutdown, "shutdown", now)
        return out

    def wants_immediate_wake(self, name: str) -> bool:
        slot = self._slots.get(name)
        return bool(slot and slot.spec.command_mode == "immediate" and slot.has_unsent_setpoint)

    # ------------------------------------------------------------------------ the policy
    def _lifecycle(
        self, slot: _ServoSlot, frames: list[can.Message], purpose: LifecyclePurpose, now: float
    ) -> list[Outgoing]:
        """Outgoing lifecycle frames, each expecting the profile's ``replies_per_lifecycle``."""
        out = []
        profile = slot.spec.profile
        timeout = self.timing.reply_timeout_s
        for msg in frames:
            key = exchange_key(profile, msg)
            expectations = slot.owed.expect(
                "lifecycle", now, timeout, key, profile.replies_per_lifecycle
            )
            out.append(
                Outgoing(slot.spec.name, "lifecycle", msg, None, expectations, None, purpose)
            )
        return out

    def _start_up_if_needed(self, slot: _ServoSlot, now: float, decision: Decision) -> None:
        """Put the servo's start-up frames before its command when they are due."""
        frames = slot.life.startup_frames(now)
        if frames is not None:
            decision.frames += self._lifecycle(slot, frames, "startup", now)

    def _serve_releases(self, now: float, decision: Decision) -> None:
        for name, frames in self._lifecycles.due_releases(now):
            decision.frames += self._lifecycle(self._slots[name], frames, "release", now)

    def _command_frame(self, slot: _ServoSlot, kind: FrameKind, now: float) -> Outgoing:
        assert slot.latest is not None
        replies = slot.spec.profile.replies_per_command
        key = exchange_key(slot.spec.profile, slot.latest.msg)
        expectations = slot.owed.expect("command", now, self.timing.reply_timeout_s, key, replies)
        slot.sent_seq = slot.latest.seq
        slot.last_command_time = now
        if not replies:
            slot.owed.awaiting_first_since = now
        return Outgoing(
            slot.spec.name, kind, slot.latest.msg, slot.latest.seq, expectations, slot.latest
        )

    def _expire(self, now: float, decision: Decision) -> None:
        for name, slot in self._slots.items():
            expected = slot.owed.expected
            if not expected or expected[0].deadline > now:
                continue  # nearly every servo at nearly every step: no call
            for _ in range(slot.owed.expire(now)):
                decision.lost.append(name)
                if self._liveness.missed(name, on_send=False):
                    decision.went_offline.append(name)
                    dropped = self._drop_unsent(slot)
                    if dropped is not None:
                        decision.dropped.append((name, dropped))

    def _expire_silent_pushers(self, now: float, decision: Decision) -> None:
        """Take pushing servos whose pushes stopped offline (module docstring, Liveness)."""
        for name in self._liveness.fell_silent(now):
            decision.went_offline.append(name)
            dropped = self._drop_unsent(self._slots[name])
            if dropped is not None:
                decision.dropped.append((name, dropped))

    @staticmethod
    def _drop_unsent(slot: _ServoSlot) -> Setpoint | None:
        """Drop the setpoint that has not gone out, back to the last one that did.

        A refused refresh (or re-send) of the last setpoint that went out drops nothing: it is
        marked sent again, so it goes on as the refresh.
        """
        if not slot.has_unsent_setpoint:
            return None
        assert slot.latest is not None
        last_sent = slot.last_sent
        dropped = (
            None if last_sent is not None and last_sent.seq >= slot.latest.seq else slot.latest
        )
        slot.latest = last_sent
        if last_sent is not None:
            slot.sent_seq = max(slot.sent_seq, last_sent.seq)
        return dropped

    def _serve_command_slot(self, now: float, decision: Decision) -> None:
        t = self.timing
        if now < self._next_command_slot:
            return
        skipped = math.floor((now - self._next_command_slot) / t.command_period_s + 1e-9)
        slot_time = self._next_command_slot + skipped * t.command_period_s
        decision.missed_slots = skipped
        decision.command_slot = slot_time
        self._next_command_slot = slot_time + t.command_period_s
        # less a rounding margin: slot times are sums of periods, and a refresh due exactly on a
        # slot (refresh_interval_s 0.5 s in 0.2 s slots) waited a whole slot more when the sum
        # came out a hair short (tests/app/test_check_keep_alive.py)
        refresh_due = t.refresh_s - t.command_period_s / 2 - 1e-9
        for name in self._order:
            slot = self._slots[name]
            if slot.released or slot.latest is None:
                continue
            if slot.has_unsent_setpoint:
                if slot.spec.command_mode == "immediate" and not self._spacing_elapsed(slot, now):
                    continue  # the immediate path sends it when the spacing ends
                self._start_up_if_needed(slot, now, decision)
                decision.frames.append(self._command_frame(slot, "command", now))
                if slot.spec.command_mode == "periodic":
                    slot.last_command_time = slot_time
            elif (
                slot.last_command_time is None or slot_time - slot.last_command_time >= refresh_due
            ) and (slot.spec.command_mode == "periodic" or self._spacing_elapsed(slot, now)):
                self._start_up_if_needed(slot, now, decision)
                decision.frames.append(self._command_frame(slot, "refresh", now))
                if slot.spec.command_mode == "periodic":
                    slot.last_command_time = slot_time

    def _spacing_elapsed(self, slot: _ServoSlot, now: float) -> bool:
        last = slot.last_command_time
        return last is None or now - last >= self.timing.immediate_min_spacing_s - 1e-9

    def _serve_immediate(self, now: float, decision: Decision) -> None:
        for name in self._order:
            slot = self._slots[name]
            if slot.spec.command_mode != "immediate" or not slot.has_unsent_setpoint:
                continue
            if self._spacing_elapsed(slot, now):
                self._start_up_if_needed(slot, now, decision)
                decision.frames.append(self._command_frame(slot, "command", now))

    def _serve_telemetry(self, now: float, decision: Decision) -> None:
        t = self.timing
        polls = self._polls
        decision.telemetry_tick = polls.tick(now)
        if not polls.round:
            return
        # suspension: nothing may still occupy the bus at the next command slot
        # (the command frames of this very step go first and take their own bus time)
        bus_free_until = self._next_command_slot - t.command_guard_s
        budget = bus_free_until - now - sum(self._frame_cost(out) for out in decision.frames)
        for name in polls.take(now, budget, self._request_outstanding, decision.late_polls):
            slot = self._slots[name]
            profile = slot.spec.profile
            replies = profile.replies_per_request
            for req in profile.telemetry_requests():
                key = exchange_key(profile, req)
                expectations = slot.owed.expect("request", now, t.reply_timeout_s, key, replies)
                decision.frames.append(Outgoing(name, "request", req, None, expectations))
            profile.poll_sent()  # the one place a poll goes out: count it here
        decision.deferred_polls = len(polls.round)

    def _frame_cost(self, out: Outgoing) -> float:
        """Bus time of a frame of this step and its replies (a command: its servo's cost)."""
        if out.kind != "lifecycle":
            return self._slots[out.servo].command_cost_s
        bitrate = self.timing.bitrate
        reply = frame_time(bool(out.msg.is_extended_id), REPLY_DLC, bitrate)
        return message_bits(out.msg) / bitrate + len(out.expectations) * reply

    def step(self, now: float) -> Decision:
        """Frames to send at ``now`` (commands first) and when to call ``step`` again."""
        decision = Decision(frames=[], next_deadline=math.inf)
        self._expire(now, decision)
        self._expire_silent_pushers(now, decision)
        self._serve_releases(now, decision)
        self._serve_command_slot(now, decision)
        self._serve_immediate(now, decision)
        self._serve_telemetry(now, decision)
        decision.next_deadline = self.next_deadline(now)
        return decision

    def next_deadline(self, now: float) -> float:
        """Earliest time a frame may have to go out: slot, telemetry tick, end of a spacing.

        Reply timeouts are deliberately not deadlines: they are checked on the next step (at
        most one command period later), which keeps the runner from waking, and spinning,
        once per outstanding reply.
        """
        t = self.timing
        candidates = [self._next_command_slot, self._polls.next_tick]
        release_due = self._lifecycles.next_release()
        if release_due < math.inf:
            candidates.append(max(now, release_due))
        for slot in self._slots.values():
            if slot.spec.command_mode == "immediate" and slot.has_unsent_setpoint:
                last = slot.last_command_time
                candidates.append(now if last is None else last + t.immediate_min_spacing_s)
        if self._polls.round and self._polls.waiting(self._request_outstanding):
            # deferred polls go right after the next command slot's frames
            candidates.append(self._next_command_slot)
        return min(candidates)

    # ------------------------------------------------------------------ wire feedback
    def sent(self, out: Outgoing, t: float) -> list[str]:
        """The runner wrote ``out`` at ``t``: time its replies from the real write time.

        Returns the servos back online because the bus works again: those that went offline
        on refused sends and have nothing to probe with (module docstring).
        """
        for expectation in out.expectations:
            expectation.t_tx = t
            expectation.deadline = t + self.timing.reply_timeout_s
        slot = self._slots[out.servo]
        if out.setpoint is not None and (
            slot.last_sent is None or out.setpoint.seq > slot.last_sent.seq
        ):
            slot.last_sent = out.setpoint
        if out.kind != "request" and slot.owed.awaiting_first_since is not None:
            slot.owed.awaiting_first_since = t
        if not self._liveness.offline_on_sends:
            return []  # the common case, on every frame: nothing to scan
        return self._liveness.back_on_send(self._nothing_to_probe)

    def _nothing_to_probe(self, name: str) -> bool:
        """No setpoint to refresh and no polls: only a working send can bring it back."""
        slot = self._slots[name]
        return slot.latest is None and slot.poll_period is None

    def send_failed(self, out: Outgoing) -> SendFailure:
        """The bus refused ``out``: forget its replies and let the next slot try again.

        The refusal counts as a miss, and an offline servo's unsent setpoint is dropped
        (module docstring); a single refused frame (a full transmit buffer) leaves an online
        servo's setpoint to be retried on the next slot.
        """
        slot = self._slots[out.servo]
        slot.owed.forget(out.expectations)
        if out.kind == "lifecycle":
            # not a miss: the command after it (or the next poll) tells whether the servo is
            # there, and a bus that is down would otherwise be counted twice per slot
            if out.lifecycle == "startup":
                slot.life.restart()  # they go again before the next command
            elif out.lifecycle == "release":  # again, not in a tight loop
                self._lifecycles.release_refused(out.servo, slot.released, self._next_command_slot)
            return SendFailure(False, None)
        if out.seq is not None and slot.sent_seq == out.seq:
            slot.sent_seq = out.seq - 1
        went_offline = self._liveness.missed(out.servo, on_send=True)
        dropped = None if self.is_online(out.servo) else self._drop_unsent(slot)
        return SendFailure(went_offline, dropped)

    def on_reply(
        self, name: str, t: float, key: Hashable | None = None, *, answer: bool = True
    ) -> ReplyMatch:
        """A reply from ``name`` with exchange key ``key`` was decoded at ``t``: match it to
        the expectation it answers (its kind, the oldest of plausible latency). ``answer``
        False: a sign of life only (a DroneCAN NodeStatus, which any node can send with the
        servo's id): the servo is alive, but nothing is answered and no latency measured."""
        slot = self._slots[name]
        back_online = self._liveness.heard(name, t)
        if back_online:
            slot.life.restart()  # it may have been power-cycled: start it up again
        if not answer:
            return ReplyMatch(None, None, None, back_online)
        return slot.owed.match(t, key, back_online)
