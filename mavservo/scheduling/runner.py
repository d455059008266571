"""The dual-loop priority scheduler: the only writer to one CAN bus.

:class:`Scheduler` runs the pure policy of :mod:`mavservo.scheduling.schedule_core` on absolute
monotonic deadlines in one thread (the only caller of ``bus.send``, so command-over-telemetry
priority is structural), and decodes replies in a second thread (``bus.recv``) through the servo
profiles. Upper layers talk to it through a small thread-safe API: ``set_setpoint``, ``state``,
``is_online``, ``subscribe``, ``release``, ``metrics``.

Waiting: sleep until ``spin_s`` before the deadline, then spin (yielding the GIL on every turn
so the receive thread is never starved). On a shared non-real-time machine that is what keeps a
50 ms loop within a fraction of a millisecond when a core is free; ``realtime=True`` asks for
SCHED_FIFO, which is what holds under load, and reports (never raises) when the OS refuses.
A runner that finds itself under SCHED_FIFO or SCHED_RR (asked for, or inherited from the
process, as under the systemd unit in deploy/) spins ``fifo_spin_s`` instead (default 0): its
plain timed wake-up is late by 0.1-0.25 ms at p99 even with every core busy, a tenth of the
command goal, while a spin at real-time priority is never preempted and cost a third of the
scheduler's CPU (docs/benchmarks.md, Scheduler).
"""

from __future__ import annotations

import enum
import itertools
import logging
import math
import os
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, ParamSpec, Protocol, runtime_checkable

import can

from mavservo.records import SchedulerMetrics, write_json
from mavservo.scheduling.outage_log import LateReplies, Line, OnlineLog
from mavservo.scheduling.schedule_core import (
    Decision,
    FrameKind,
    Outgoing,
    ScheduleCore,
    ScheduleError,
    ServoSpec,
    Setpoint,
    SetpointResult,
    TimingConfig,
    exchange_key,
)
from mavservo.servos import Advising, BusNode, Fault, ProfileOptions, ServoState, node_reports_of

from .bus_nodes import BusNodes
from .busload import message_bits
from .load_watch import LoadWatch

__all__ = [
    "ScheduleError",
    "Scheduler",
    "SchedulerObserver",
    "ServoSpec",
    "SetpointResult",
    "StateCallback",
    "TimingConfig",
    "WriteObserver",
]

log = logging.getLogger(__name__)
_P = ParamSpec("_P")

StateCallback = Callable[[str, ServoState], None]
_RECV_TIMEOUT_S = 0.05


class SchedulerObserver(Protocol):
    """Hooks called from the scheduler's threads (the scheduler's observer boundary).

    A Protocol: the run log implements it structurally; a class that subclasses it explicitly
    inherits a no-op for every hook it does not override. Implementations MUST be non-blocking
    (append to a queue, bump a counter): they run inside the command loop and the receive loop,
    so a slow observer would delay commands. Exceptions are logged and swallowed; they never
    stop the loop. ``bus`` is the scheduler's name.
    """

    def on_setpoint(self, servo: str, seq: int, angle_deg: float, source: str, t: float) -> None:
        """A setpoint was accepted into the scheduler."""
        return None

    def on_tx(
        self,
        bus: str,
        msg: can.Message,
        t: float,
        kind: FrameKind,
        servo: str,
        seq: int | None,
    ) -> None:
        """``bus.send`` returned for ``msg``; ``t`` is the monotonic time just after the write."""
        return None

    def on_rx(
        self, bus: str, msg: can.Message, t: float, servo: str, state: ServoState | None
    ) -> None:
        """A reply from ``servo`` was decoded into ``state``; None for a frame that starts or
        continues a multi-frame report (a DroneCAN Status), which is whole at its last frame."""
        return None

    def on_lost(self, bus: str, servo: str, t: float) -> None:
        """A reply ``servo`` owed us did not arrive within ``reply_timeout_s``."""
        return None

    def on_reject(self, bus: str, reason: str, raw_bytes: bytes, t: float) -> None:
        """The bus's frame decoder rejected bytes (forwarded through ``report_reject``)."""
        return None


@runtime_checkable
class WriteObserver(Protocol):
    """An observer that also wants to know when a servo's frames are all on the wire: a
    capability of a :class:`SchedulerObserver`, checked with isinstance once, when the
    scheduler is built (an observer without it is not called)."""

    def on_written(self, bus: str, t: float, kind: FrameKind, servo: str, seq: int | None) -> None:
        """Every frame carrying ``servo``'s ``kind`` frame (its ``seq``) is on the wire, the last
        of them written at ``t``: called once per servo per write, after the frames' ``on_tx``.
        A packed transfer (DroneCAN's ArrayCommand: 8 servos' commands in 5 frames) has fewer
        frames than commands, so ``on_tx`` cannot say which commands it wrote; this does, for
        every family alike."""
        ...


@runtime_checkable
class RejectReporting(Protocol):
    """A bus that reports the bytes its frame decoder rejected (the aa55 bus): ``on_reject``
    is called with ``(reason, raw_bytes)``; None until someone listens."""

    on_reject: Callable[[Any, bytes], None] | None


class _NoObserver(SchedulerObserver):
    """The observer of a scheduler nobody observes: every hook a no-op."""


class FailureRun:
    """Counts every failure of one repeating operation and says what to log, once per outage.

    Why: when the adapter is unplugged every send fails, 20-80 times a second for as long as
    it is away. One warning per failure buried the log (``--quiet`` does not hide warnings)
    and said nothing the first one had not. So an outage is logged when it starts (the
    caller logs ``failed`` returning True, with the reason) and when the operation works
    again (``succeeded`` returns how many failed and for how long); in between failures are
    only counted. ``total`` and ``outages`` count every failure and every outage. Not
    thread-safe: the caller serialises (the scheduler calls it under its lock).
    """

    def __init__(self) -> None:
        self.total = 0
        self.outages = 0
        self.failing_since: float | None = None
        """When the current outage began (None while the operation works)."""
        self._in_outage = 0

    def failed(self, t: float) -> bool:
        """Count a failure at ``t``; True if it starts an outage (the one to log)."""
        self.total += 1
        self._in_outage += 1
        if self.failing_since is not None:
            return False
        self.failing_since = t
        self.outages += 1
        return True

    def succeeded(self, t: float) -> tuple[int, float] | None:
        """The operation worked at ``t``: ``(failures, seconds)`` of the outage it ends, if any."""
        ended = self.ongoing(t)
        self.failing_since = None
        self._in_outage = 0
        return ended

    def ongoing(self, now: float) -> tuple[int, float] | None:
        """``(failures, seconds)`` of the outage still going on at ``now``, if any.

        Reads without ending it: at ``stop()`` an outage that lasted to the end is logged, but
        it did not end in a success, so metrics written afterwards still show it failing.
        """
        if self.failing_since is None:
            return None
        return (self._in_outage, now - self.failing_since)

    def to_dict(self, now: float) -> dict[str, Any]:
        return {
            "total": self.total,
            "outages": self.outages,
            "failing_for_s": None if self.failing_since is None else now - self.failing_since,
        }


class Scheduler:
    """One bus, its servos and the two loops. Refuses an over-budget schedule at construction.

    ``servos``: :class:`ServoSpec` per servo (name, profile, command mode, telemetry rate).
    ``clock``: a monotonic clock in seconds (injectable). ``observer``: see
    :class:`SchedulerObserver`. Construction raises :class:`ScheduleError` (a ``ValueError``)
    with the computed worst-case R when the schedule cannot fit ``timing.max_load``.
    """

    def __init__(
        self,
        bus: can.BusABC,
        servos: Sequence[ServoSpec],
        timing: TimingConfig | None = None,
        *,
        clock: Callable[[], float] = time.monotonic,
        observer: SchedulerObserver | None = None,
        name: str | None = None,
        node_options: Mapping[str, ProfileOptions] | None = None,
    ) -> None:
        self.timing = timing or TimingConfig()
        self.name = name or str(bus.channel_info)
        self._bus = bus
        self._clock = clock
        self._observer: SchedulerObserver = observer or _NoObserver()
        self._write_observer = observer if isinstance(observer, WriteObserver) else None
        self._nodes = BusNodes(self.name, servos, self.timing, node_options or {}, clock())
        self._core = ScheduleCore(
            servos,
            self.timing,
            start=clock(),
            packed=frozenset(self._nodes.node_of),
            extra_flows=self._nodes.flows,
        )
        self._specs = {spec.name: spec for spec in servos}
        self._metrics = SchedulerMetrics(
            self._specs,
            self.timing.command_period_s,
            self.timing.telemetry_period_s,
            self.timing.bitrate,
            self.timing.load_window_s,
        )
        for spec in servos:  # a servo polled at its own rate is judged against that rate
            if spec.telemetry_hz:
                self._metrics.servos[spec.name].telemetry_intervals.nominal_s = max(
                    1 / spec.telemetry_hz, self.timing.telemetry_period_s
                )
        self._states: dict[str, ServoState] = {}
        self._subscribers: list[StateCallback] = []
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._started_at: float | None = None
        self._cpu = {"runner_s": 0.0, "receiver_s": 0.0}
        self._send_failures = FailureRun()
        self._receive_failures = FailureRun()
        self._online_log = OnlineLog()
        self._late_replies = LateReplies(self.timing.reply_timeout_s)
        self._load_watch = LoadWatch(
            self.name, self.timing.bitrate, self.timing.load_window_s, self.timing.max_load
        )
        self.realtime_status = "not requested"
        self.on_event: Callable[[str], None] | None = None
        """Where advice about a servo goes besides the log (the bridge: console, event list
        and STATUSTEXT); called from the scheduler's threads, must not block."""
        self._advised: set[str] = set()
        """Servos whose :meth:`_advise` line went out (once per servo and run)."""
        self._node_reports = {
            spec.name: reports
            for spec in servos
            if (reports := node_reports_of(spec.profile)) is not None
        }
        """The servos whose reports come from a node (resolved once, asked for every frame)."""
        self._diagnosing = [
            (spec.name, spec.profile) for spec in servos if isinstance(spec.profile, Advising)
        ]
        """Servos whose profile can say whose an unclaimed frame is (a foreign node's flood
        costs nothing for the others)."""
        self.spin_s = self.timing.spin_s
        """The spin the runner actually uses (``fifo_spin_s`` once it runs real-time)."""
        for warning in self._core.warnings:
            log.warning("scheduler %s: %s", self.name, warning)
        if isinstance(bus, RejectReporting) and bus.on_reject is None:
            # an aa55 bus with no rejection callback yet: count its decoder rejections here
            bus.on_reject = self.report_reject

    def take_notices(self) -> list[str]:
        """Notices of the bus nodes since the last call (another master on a DroneCAN bus, a
        safety state no ArduPilot node will move with), logged once (those of received frames
        as they came, the others here); the bridge sends them as STATUSTEXT."""
        with self._lock:
            fresh = self._nodes.collect()
            notices = self._nodes.take_notices()
        for notice in fresh:
            log.warning("scheduler %s: %s", self.name, notice)
        return notices

    def node_states(self) -> list[tuple[str, tuple[int, dict[str, Any]]]]:
        """``(profile name, (version, state))`` of every bus node with something to keep across
        restarts (the DroneCAN allocation table), read under the lock: the receive thread
        changes it."""
        with self._lock:
            return self._nodes.states()

    @property
    def nodes(self) -> list[BusNode]:
        """The bus nodes this scheduler owns (tests, diagnostics)."""
        return [node for _, node, _ in self._nodes.nodes]

    # --------------------------------------------------------------------------- lifecycle
    def start(self) -> None:
        """Anchor the schedule at the current time and start the two threads."""
        if self._threads:
            raise RuntimeError("scheduler already started")
        self._stop.clear()
        with self._lock:
            self._started_at = self._clock()
            self._core.anchor(self._started_at)
        self._threads = [
            threading.Thread(target=self._run, name=f"mavservo-sched-{self.name}", daemon=True),
            threading.Thread(target=self._receive, name=f"mavservo-rx-{self.name}", daemon=True),
        ]
        for thread in self._threads:
            thread.start()

    def stop(self, timeout: float = 2.0) -> None:
        """Stop both threads (the bus stays open: it belongs to the caller).

        A thread still blocked in ``bus.send``/``bus.recv`` after ``timeout`` is left to finish
        on its own (it is a daemon): every access to the failure runs is under the lock, so
        its last counts stay consistent with what is read here.
        """
        self._stop.set()
        self._wake.set()
        was_running = bool(self._threads)
        for thread in self._threads:
            thread.join(timeout)
            if thread.is_alive():
                log.warning(
                    "scheduler %s: thread %s did not stop within %.1f s",
                    self.name,
                    thread.name,
                    timeout,
                )
        stopped = not any(thread.is_alive() for thread in self._threads)
        self._threads = []
        if was_running and stopped:  # a runner still in bus.send would be a second writer
            self._send_final_frames()
        now = self._clock()
        with self._lock:
            runs = [("sends", self._send_failures), ("receives", self._receive_failures)]
            unfinished = [(what, run.ongoing(now)) for what, run in runs]
        for what, ended in unfinished:
            if ended is not None:  # an outage that lasted to the end still gets its count
                log.info(
                    "scheduler %s: stopped while %s were failing: %d failed over %.1f s",
                    self.name,
                    what,
                    *ended,
                )

    def _send_final_frames(self) -> None:
        """Pending release frames and the shutdown frames, sent by the stopping thread once the
        runner is gone (still one writer); a refused one is counted and the rest still go."""
        with self._lock:
            frames = self._core.final_frames(self._clock())
        for out in frames:
            try:
                self._bus.send(out.msg)
            except can.CanError as exc:
                with self._lock:
                    self._metrics.servos[out.servo].send_failed += 1
                log.warning(
                    "scheduler %s: %s frame to %s refused: %s",
                    self.name,
                    out.lifecycle,
                    out.servo,
                    exc,
                )
                continue
            t = self._clock()
            with self._lock:
                self._metrics.frames_written += 1
                self._account_tx(out, t)
            self._notify_observer(
                self._observer.on_tx, self.name, out.msg, t, out.kind, out.servo, out.seq
            )
            if self._write_observer is not None:
                self._notify_observer(
                    self._write_observer.on_written, self.name, t, out.kind, out.servo, out.seq
                )

    def __enter__(self) -> Scheduler:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ------------------------------------------------------------------------ upper layers
    @property
    def warnings(self) -> list[str]:
        """Start-up findings (e.g. telemetry rates that cannot be kept), already logged."""
        return list(self._core.warnings)

    @property
    def worst_case_load(self) -> float:
        return self._core.worst_case_load

    @property
    def servo_names(self) -> list[str]:
        return self._core.servo_names

    def set_setpoint(
        self, servo: str, angle_deg: float, source: str, t: float | None = None
    ) -> SetpointResult:
        """Queue a new setpoint; rejected if unknown, invalid, or older (``t``) than the last."""
        when = self._clock() if t is None else t
        with self._lock:
            result = self._core.submit(servo, angle_deg, source, when)
            servo_metrics = self._metrics.servos.get(servo)
            if servo_metrics is not None:
                if result.accepted:
                    servo_metrics.setpoints_accepted += 1
                else:
                    servo_metrics.setpoints_rejected += 1
            wake = result.accepted and self._core.wants_immediate_wake(servo)
        if result.accepted:
            assert result.seq is not None
            self._notify_observer(
                self._observer.on_setpoint, servo, result.seq, angle_deg, source, when
            )
        if wake:
            self._wake.set()
        return result

    def mark_failsafe(self, servo: str) -> None:
        """The setpoint in force is held by a failsafe (``hold``): no new command goes out."""
        with self._lock:
            self._core.mark_failsafe(servo)

    def release(self, servo: str) -> None:
        """Stop sending and refreshing ``servo`` until its next setpoint (failsafe release)."""
        with self._lock:
            self._core.release(servo)
            wake = self._core.wants_lifecycle_wake()
        if wake:
            self._wake.set()  # the release frames (motor off) go out now, not at the next slot

    def state(self, servo: str) -> ServoState | None:
        with self._lock:
            return self._states.get(servo)

    def is_online(self, servo: str) -> bool:
        """False after ``offline_after_missed`` replies in a row did not arrive, or frames to
        it in a row were refused by the bus (adapter unplugged), until its next reply."""
        with self._lock:
            return self._core.is_online(servo)

    def subscribe(self, callback: StateCallback) -> Callable[[], None]:
        """Call ``callback(servo, state)`` on every decoded reply and when a servo goes offline.

        Runs in the receive (or command) thread: keep it short. Returns an unsubscribe function.
        """
        with self._lock:
            self._subscribers.append(callback)

        def unsubscribe() -> None:
            with self._lock:
                if callback in self._subscribers:
                    self._subscribers.remove(callback)

        return unsubscribe

    def report_reject(self, reason: object, raw_bytes: bytes, t: float | None = None) -> None:
        """Count a frame the bus's decoder rejected.

        Matches the aa55 bus's ``on_reject(reason, raw_bytes)`` callback, which the constructor
        installs when the bus has that attribute unset. ``reason`` may be an enum (its value is
        reported) or a string.
        """
        when = self._clock() if t is None else t
        text = str(reason.value if isinstance(reason, enum.Enum) else reason)
        with self._lock:
            self._metrics.bus_rejected += 1
        self._notify_observer(self._observer.on_reject, self.name, text, bytes(raw_bytes), when)

    def round_trip_samples(self, per_servo: int = 256) -> list[float]:
        """The latest wire round trips L of every servo (seconds, frame written -> its reply
        decoded: the summary's L), at most ``per_servo`` each, for live percentiles.

        A bounded tail rather than the whole 4096-sample windows, so a caller that publishes a
        few times a second sorts a few hundred values, not tens of thousands.
        """
        with self._lock:
            return [
                value
                for servo in self._metrics.servos.values()
                for value in itertools.islice(reversed(servo.latency.recent), per_servo)
            ]

    def load_ratio(self) -> float:
        """Measured bus load R over the last window (cheap: for live telemetry)."""
        now = self._clock()
        with self._lock:
            return self._metrics.load.ratio(now)

    @property
    def metrics_store(self) -> SchedulerMetrics:
        """The live accumulators (for benches and reports after ``stop()``; while running,
        prefer the ``metrics()`` snapshot, which is taken under the scheduler's lock)."""
        return self._metrics

    def metrics(self) -> dict[str, Any]:
        """JSON-serialisable snapshot: per servo L, sigma_L, intervals, frame counts; bus R."""
        now = self._clock()
        with self._lock:
            snapshot = self._metrics.to_dict(now)
            for name in self._specs:
                snapshot["servos"][name]["online"] = self._core.is_online(name)
            snapshot["send_failures"] = self._send_failures.to_dict(now)
            snapshot["receive_failures"] = self._receive_failures.to_dict(now)
        # next to the measured loads, under one name everywhere (summary, metrics.json, report)
        snapshot["load"]["planned"] = self.worst_case_load
        snapshot["info"].update(
            bus=self.name,
            max_load=self.timing.max_load,
            bitrate=self.timing.bitrate,
            command_period_s=self.timing.command_period_s,
            telemetry_period_s=self.timing.telemetry_period_s,
            warnings=self.warnings,
            realtime=self.realtime_status,
            spin_s=self.spin_s,
            uptime_s=None if self._started_at is None else now - self._started_at,
            cpu=dict(self._cpu),
        )
        return snapshot

    def write_metrics(self, path: str | Path) -> Path:
        """Write ``metrics()`` as JSON (the run log calls this at the end of a run)."""
        return write_json(path, self.metrics())

    # ------------------------------------------------------------------------ the threads
    @staticmethod
    def _notify_observer(hook: Callable[_P, None], *args: _P.args, **kwargs: _P.kwargs) -> None:
        """Call one observer hook; an observer's failure is logged, never raised."""
        try:
            hook(*args, **kwargs)
        except Exception:  # an observer must never stop the loop
            log.exception("scheduler observer %s failed", getattr(hook, "__name__", hook))

    def _notify_subscribers(self, servo: str, state: ServoState) -> None:
        with self._lock:
            subscribers = list(self._subscribers)
        for callback in subscribers:
            try:
                callback(servo, state)
            except Exception:
                log.exception("scheduler subscriber failed for %s", servo)

    def _apply_realtime(self, priority: int, role: str) -> None:
        """SCHED_FIFO for the calling thread, if asked; a refusal is reported, never raised.

        Both threads get it (the receive thread one step lower): a receive thread preempted by
        ordinary load while it holds the scheduler's lock would otherwise stall the command
        loop behind it (priority inversion).
        """
        if not self.timing.realtime:
            return
        try:
            # pid 0 is the calling thread on Linux
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
            if role == "runner":
                self.realtime_status = f"SCHED_FIFO priority {priority}"
        except (AttributeError, OSError) as exc:
            self.realtime_status = f"refused ({role}): {exc!r}"
            log.warning("scheduler %s: real-time priority refused: %r", self.name, exc)

    def _choose_spin(self) -> None:
        """Pick the spin for the calling (runner) thread's actual scheduling policy."""
        try:
            policy = os.sched_getscheduler(0)
        except (AttributeError, OSError):
            return
        if policy in (getattr(os, "SCHED_FIFO", -1), getattr(os, "SCHED_RR", -1)):
            self.spin_s = self.timing.fifo_spin_s
            if self.realtime_status == "not requested":
                self.realtime_status = "inherited real-time policy"

    def _wait_until(self, deadline: float) -> None:
        """Sleep to ``spin`` before ``deadline``, then spin; return early when woken."""
        spin = self.spin_s
        while not self._stop.is_set():
            remaining = deadline - self._clock()
            if remaining <= 0:
                return
            if remaining > spin:
                if self._wake.wait(remaining - spin):
                    self._wake.clear()
                    return
                continue
            while self._clock() < deadline:
                if self._wake.is_set():
                    self._wake.clear()
                    return
                time.sleep(0)  # yield the GIL so the receive thread keeps its timestamps true
            return

    def _run(self) -> None:
        self._apply_realtime(self.timing.realtime_priority, "runner")
        self._choose_spin()
        while not self._stop.is_set():
            decision = self._step()
            self._send_all(decision)
            if self._nodes:
                self._send_node_frames()
            with self._lock:
                deadline = min(self._core.next_deadline(self._clock()), self._nodes.next_due())
            self._cpu["runner_s"] = time.thread_time()
            self._wait_until(deadline)

    def _log(self, lines: list[Line]) -> None:
        for level, text in lines:
            log.log(level, "scheduler %s: %s", self.name, text)

    def _go_offline(
        self, servo: str, reason: str, dropped: Setpoint | None, now: float
    ) -> tuple[list[Line], ServoState | None]:
        """Book a servo going offline (caller holds the lock): its state carries NO_REPLY, as
        for a silent servo; returns the lines to log and the state to tell subscribers."""
        lines = self._online_log.offline(servo, reason, now)
        if dropped is not None:
            lines += self._dropped(servo, dropped, now)
        state = self._states.get(servo)
        if state is not None:
            state = state.with_faults(state.faults | Fault.NO_REPLY)
            self._states[servo] = state
        return lines, state

    def _dropped(self, servo: str, dropped: Setpoint, now: float) -> list[Line]:
        """Count a setpoint dropped unsent (caller holds the lock) and say so."""
        self._metrics.servos[servo].setpoints_dropped += 1
        return [
            (
                logging.WARNING,
                f"servo {servo} is offline: setpoint #{dropped.seq} ({dropped.angle_deg:g} deg "
                f"from {dropped.source}, {now - dropped.t:.2f} s old) dropped unsent; the "
                "servo moves again on a fresh setpoint once it is back",
            )
        ]

    def _step(self) -> Decision:
        now = self._clock()
        offline_states: list[tuple[str, ServoState]] = []
        lines: list[Line] = []
        advice: list[tuple[str, str]] = []
        with self._lock:
            decision = self._core.step(now)
            metrics = self._metrics
            metrics.missed_command_slots += decision.missed_slots
            if decision.command_slot is not None and not any(
                out.kind in ("command", "refresh") for out in decision.frames
            ):
                # nothing to write in this slot: it is on time when the loop got round to it
                # (a slot with frames is timed at its first write, in _send_all)
                metrics.command_slot_served(decision.command_slot, now)
            if decision.telemetry_tick is not None:
                metrics.telemetry_ticks.mark(now)
            for servo in decision.lost:
                metrics.servos[servo].timed_out += 1
            dropped = dict(decision.dropped)
            for servo in decision.went_offline:
                sent = self._metrics.servos[servo].lifecycle_sent
                sent += self._metrics.servos[servo].commands_sent
                if sent and servo not in self._states:  # spoken to, never heard: what to check
                    profile = self._specs[servo].profile
                    hint = profile.silence_hint() if isinstance(profile, Advising) else None
                    if hint is not None:
                        advice.append((servo, hint))
                more, state = self._go_offline(servo, "no reply", dropped.get(servo), now)
                lines += more
                if state is not None:
                    offline_states.append((servo, state))
            lines += self._online_log.flush(now)
        for servo in decision.lost:
            self._notify_observer(self._observer.on_lost, self.name, servo, now)
        self._log(lines)
        for servo, text in advice:
            self._advise(servo, text)
        for servo, state in offline_states:
            self._notify_subscribers(servo, state)
        return decision

    def _announce(self, text: str) -> None:
        """A WARNING and ``on_event`` (STATUSTEXT through the bridge): advice about a servo,
        the measured load over ``max_load`` (:mod:`.load_watch`, rate-limited there)."""
        log.warning("scheduler %s: %s", self.name, text)
        on_event = self.on_event
        if on_event is not None:
            try:
                on_event(text)
            except Exception:  # noqa: BLE001 - an observer must not stop the loop
                log.exception("scheduler %s: on_event failed", self.name)

    def _advise(self, servo: str, text: str) -> None:
        """Say once per servo why it is not heard (a wrong protocol, host id, id...): a WARNING
        and ``on_event`` (STATUSTEXT through the bridge). Users of other tools lose hours to a
        motor that answers in a protocol the host does not speak."""
        with self._lock:
            if servo in self._advised:
                return
            self._advised.add(servo)
        self._announce(f"servo {servo}: {text}")

    def _diagnose(self, msg: can.Message) -> None:
        """A frame no servo claims: ask each servo not yet advised whether it is its own in
        another form (:class:`~mavservo.servos.base.Advising`)."""
        for name, profile in self._diagnosing:
            if name in self._advised:
                continue
            text = profile.diagnose(msg)
            if text is not None:
                self._advise(name, text)

    def _send_all(self, decision: Decision) -> None:
        slot_marked = decision.command_slot is None
        with self._lock:  # a node packs commands: it shares state with the receive thread
            batches = self._nodes.batches(decision.frames)
        for outs, msgs in batches:
            try:
                for msg in msgs:
                    self._bus.send(msg)
            except can.CanError as exc:
                now = self._clock()
                for out in outs:
                    self._refused(out, exc, now)
                continue
            t = self._clock()
            with self._lock:
                ended = self._send_failures.succeeded(t)
                back = [servo for out in outs for servo in self._core.sent(out, t)]
                lines = [line for servo in back for line in self._online_log.online(servo, t)]
                for out in outs:
                    self._account_tx(out, t, load=len(msgs) == 1 and len(outs) == 1)
                self._metrics.frames_written += len(msgs)
                if len(outs) != 1 or len(msgs) != 1:
                    for msg in msgs:
                        self._metrics.load.add(t, message_bits(msg))
                if not slot_marked and any(out.kind in ("command", "refresh") for out in outs):
                    assert decision.command_slot is not None
                    self._metrics.command_slot_served(decision.command_slot, t)
                    slot_marked = True
            if ended is not None:
                log.info("scheduler %s: sends work again: %d failed over %.1f s", self.name, *ended)
            self._log(lines)
            # every frame once in the CAN log, each tied to one servo it carries a command to
            # (new setpoints first); a packed transfer has fewer frames than commands, so every
            # command it carries is then reported written, at its last frame's write
            paired = sorted(outs, key=lambda out: out.kind != "command")
            for index, msg in enumerate(msgs):
                out = paired[min(index, len(paired) - 1)]
                self._notify_observer(
                    self._observer.on_tx, self.name, msg, t, out.kind, out.servo, out.seq
                )
            if self._write_observer is not None:
                written = self._write_observer.on_written
                for out in outs:
                    self._notify_observer(written, self.name, t, out.kind, out.servo, out.seq)

    def _refused(self, out: Outgoing, exc: Exception, now: float) -> None:
        """The bus refused ``out`` (or a frame of the transfer carrying it)."""
        lines: list[Line] = []
        state: ServoState | None = None
        with self._lock:
            failure = self._core.send_failed(out)
            self._metrics.servos[out.servo].send_failed += 1
            first = self._send_failures.failed(now)
            if failure.went_offline:
                lines, state = self._go_offline(out.servo, "sends failing", failure.dropped, now)
            elif failure.dropped is not None:
                lines = self._dropped(out.servo, failure.dropped, now)
        if first:
            log.warning(
                "scheduler %s: send to %s failed: %s (further failed sends are "
                "counted, not logged, until one works again)",
                self.name,
                out.servo,
                exc,
            )
        self._log(lines)
        if state is not None:
            self._notify_subscribers(out.servo, state)

    def _send_node_frames(self) -> None:
        """The bus nodes' own frames (heartbeat, answers), after the step's frames."""
        now = self._clock()
        with self._lock:
            frames = self._nodes.due(now, self._core.is_online)
        for msg in frames:
            try:
                self._bus.send(msg)
            except can.CanError as exc:
                with self._lock:
                    first = self._send_failures.failed(self._clock())
                if first:
                    log.warning("scheduler %s: node frame refused: %s", self.name, exc)
                continue
            t = self._clock()
            with self._lock:
                self._metrics.frames_written += 1
                self._metrics.load.add(t, message_bits(msg))
            self._notify_observer(self._observer.on_tx, self.name, msg, t, "lifecycle", "", None)

    def _account_tx(self, out: Outgoing, t: float, load: bool = True) -> None:
        servo = self._metrics.servos[out.servo]
        if out.kind == "request":
            servo.requests_sent += 1
        elif out.kind == "lifecycle":
            servo.lifecycle_sent += 1
        else:
            if out.kind == "command":
                servo.commands_sent += 1
            else:
                servo.refreshes_sent += 1
            servo.command_intervals.mark(t)
        if load:
            self._metrics.load.add(t, message_bits(out.msg))

    def _receive(self) -> None:
        self._apply_realtime(max(1, self.timing.realtime_priority - 1), "receiver")
        # This thread's own view of whether receives are failing: the loop checks it on every
        # message, so it is a local (no lock, no attribute lookup) and the shared FailureRun
        # is only touched, under the lock, when a receive fails or works again. It starts from
        # the run's state: stop() leaves an outage that lasted to the end open, and after a
        # restart the first receive that works ends it.
        with self._lock:
            failing = self._receive_failures.failing_since is not None
        while not self._stop.is_set():
            try:
                msg = self._bus.recv(timeout=_RECV_TIMEOUT_S)
            except can.CanError as exc:
                failing = True
                with self._lock:
                    first = self._receive_failures.failed(self._clock())
                if first:
                    log.warning(
                        "scheduler %s: receive failed: %s (further failures are counted, "
                        "not logged, until a receive works again)",
                        self.name,
                        exc,
                    )
                self._stop.wait(_RECV_TIMEOUT_S)
                continue
            if failing:
                failing = False
                now = self._clock()
                with self._lock:
                    ended = self._receive_failures.succeeded(now)
                if ended is not None:
                    log.info(
                        "scheduler %s: receives work again: %d failed over %.1f s",
                        self.name,
                        *ended,
                    )
            if msg is not None:
                self.handle_frame(msg, self._clock())
                if self._nodes:
                    # A DroneCAN transfer is decoded in pure Python (the dronecan package):
                    # hand the interpreter lock over after each frame, so the runner, back
                    # from a write, never waits a whole switch interval (5 ms) for it.
                    time.sleep(0)
            self._cpu["receiver_s"] = time.thread_time()

    def _node_receive(self, msg: can.Message, t: float) -> None:
        """Give a received frame to the bus nodes (caller holds the lock): answers wake the
        runner, notices are logged here and kept for the bridge."""
        wake, notices = self._nodes.receive(msg, t)
        if wake:
            self._wake.set()
        for notice in notices:
            log.warning("scheduler %s: %s", self.name, notice)

    def handle_frame(self, msg: can.Message, t: float) -> ServoState | None:
        """Decode one received frame (called by the receive thread; public for tests and for
        buses that deliver frames through a Notifier instead)."""
        claimants = [name for name, spec in self._specs.items() if spec.profile.is_reply(msg)]
        warning = None
        with self._lock:
            if not msg.is_error_frame and not msg.is_fd:
                bits = message_bits(msg)
                self._metrics.load.add(t, bits)
                self._load_watch.received(t, bits, bool(claimants))
                warning = self._load_watch.check(t, self._metrics.load.ratio(t))
            if self._nodes:
                self._node_receive(msg, t)
        if warning is not None:
            self._announce(warning)
        if not claimants:
            if not msg.is_error_frame:
                self._diagnose(msg)
            return None
        if len(claimants) == 1:
            servo = claimants[0]
            return self._accept(servo, msg, t, self._specs[servo].profile.decode(msg, t))
        # several servos share the sender (a DroneCAN node with several actuators): each
        # decodes the frame; one actuator's Status is that servo's state and none of the
        # others' business, the node's NodeStatus everyone's. A frame none of them takes is
        # rejected once, on the first of them.
        decoded = [(name, self._specs[name].profile.decode(msg, t)) for name in claimants]
        taken = any(state is not None for _, state in decoded)
        first: ServoState | None = None
        for index, (name, state) in enumerate(decoded):
            if state is None and (taken or index):
                continue
            result = self._accept(name, msg, t, state)
            first = first if first is not None else result
        return first

    def _accept(
        self, servo: str, msg: can.Message, t: float, state: ServoState | None
    ) -> ServoState | None:
        """One servo's decoded report of ``msg`` (None: rejected): the scheduler's reply,
        metrics, observers and subscribers."""
        profile = self._specs[servo].profile
        reports = self._node_reports.get(servo)
        lines: list[Line] = []
        if state is not None and reports is not None and not reports.completes_report(msg):
            # the start of a multi-frame report: logged, but neither a reply nor a new state
            # (state None for the observer: the run log's trace and the latency's round trip
            # take the report at its last frame, as the metrics do)
            self._notify_observer(self._observer.on_rx, self.name, msg, t, servo, None)
            return state
        answer = state is not None and not (reports is not None and reports.is_liveness_only(msg))
        with self._lock:
            servo_metrics = self._metrics.servos[servo]
            if state is None:
                servo_metrics.rejected += 1
                return None
            match = self._core.on_reply(servo, t, exchange_key(profile, msg), answer=answer)
            servo_metrics.received += 1
            if match.back_online:
                lines += self._online_log.online(servo, t)
            if match.kind == "late":
                servo_metrics.late_replies += 1
                lines += self._late_replies.late(servo, match.late_latency_s)
            if match.latency_s is not None and math.isfinite(match.latency_s):
                servo_metrics.latency.add(match.latency_s)
            if match.kind in ("request", None):
                servo_metrics.telemetry_intervals.mark(t)
            if match.kind is None:
                servo_metrics.pushed += 1
            servo_metrics.state_intervals.mark(t)
            self._states[servo] = state
        self._log(lines)
        # a sign of life only (NodeStatus) is no answer: the latency's round trip waits for
        # the servo's own report
        self._notify_observer(
            self._observer.on_rx, self.name, msg, t, servo, state if answer else None
        )
        self._notify_subscribers(servo, state)
        return state
