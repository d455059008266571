"""The dual-loop priority scheduler: the only writer to one CAN bus.

:class:`Scheduler` runs the pure policy of :mod:`mavservo.scheduling.schedule_core` on absolute
monotonic deadlines in one thread (the only caller of ``bus.send``, so command-over-telemetry
priority is structural), and decodes replies in a second thread (``bus.recv``) through the servo
profiles. Upper layers talk to it through a small thread-safe API: ``set_setpoint``, ``state``,
``is_online``, ``subscribe``, ``release``, ``metrics``.

The scheduler owns its parts and the one lock they share, and delegates: the write side
(:mod:`.sender`: steps the core, writes its frames, books what the bus did), the receive side
(:mod:`.receiver`: reads, decodes and books replies), the runner's waits and real-time policy
(:mod:`.pacing`), the observers and subscribers (:mod:`.observers`), the advice to the user
(:mod:`.advice`) and the bus nodes (:mod:`.bus_nodes`). What is left here is what ties them
together: building them, starting and stopping the two threads, and the upper layers' API.
"""

from __future__ import annotations

import enum
import itertools
import logging
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import can

from mavservo.records import SchedulerMetrics, write_json
from mavservo.scheduling.outage_log import OnlineLog
from mavservo.scheduling.schedule_core import (
    ScheduleCore,
    ScheduleError,
    ServoSpec,
    SetpointResult,
    TimingConfig,
)
from mavservo.servos import BusNode, ProfileOptions, ServoState

from .advice import ServoAdvice
from .bus_book import BusBook
from .bus_nodes import BusNodes
from .failure_run import FailureRun
from .observers import (
    ObserverFanout,
    RejectReporting,
    SchedulerObserver,
    StateCallback,
    WriteObserver,
)
from .receiver import FrameReceiver
from .runner_pacing import RunnerPacing
from .sender import FrameWriter

__all__ = [
    "FailureRun",
    "RejectReporting",
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
        """The latest state of each servo heard (NO_REPLY added when it goes offline)."""
        self._lock = threading.Lock()
        """Guards the core, the metrics, the states, the online log and the bus nodes (the
        :class:`~.bus_book.BusBook`): the one lock both threads and the upper layers share."""
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._started_at: float | None = None
        self._runner_cpu_s = 0.0
        self._fanout = ObserverFanout(observer)
        self._advice = ServoAdvice(self.name, servos)
        self._pacing = RunnerPacing(self.name, self.timing, clock, self._stop, self._wake)
        book = BusBook(
            self._lock, self._core, self._metrics, self._states, OnlineLog(), self._nodes
        )
        self._writer = FrameWriter(
            self.name, bus, clock=clock, book=book, advice=self._advice, fanout=self._fanout
        )
        self._receiver = FrameReceiver(
            self.name,
            bus,
            servos,
            self.timing,
            clock=clock,
            book=book,
            wake=self._wake,
            advice=self._advice,
            fanout=self._fanout,
        )
        for warning in self._core.warnings:
            log.warning("scheduler %s: %s", self.name, warning)
        if isinstance(bus, RejectReporting) and bus.on_reject is None:
            # an aa55 bus with no rejection callback yet: count its decoder rejections here
            bus.on_reject = self.report_reject

    @property
    def on_event(self) -> Callable[[str], None] | None:
        """Where advice about a servo goes besides the log (the bridge: console, event list
        and STATUSTEXT); called from the scheduler's threads, must not block."""
        return self._advice.on_event

    @on_event.setter
    def on_event(self, callback: Callable[[str], None] | None) -> None:
        self._advice.on_event = callback

    @property
    def spin_s(self) -> float:
        """The spin the runner actually uses (``fifo_spin_s`` once it runs real-time)."""
        return self._pacing.spin_s

    @property
    def realtime_status(self) -> str:
        """What the OS granted the runner: not requested, SCHED_FIFO, inherited, refused."""
        return self._pacing.realtime_status

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
            self._writer.send_final_frames()
            # replies already received (or in flight) are booked, late ones as late, not lost
            self._receiver.drain(self.timing.reply_timeout_s)
        now = self._clock()
        with self._lock:
            runs = [("sends", self._writer.failures), ("receives", self._receiver.failures)]
            unfinished = [(what, run.ongoing(now)) for what, run in runs]
        for what, ended in unfinished:
            if ended is not None:  # an outage that lasted to the end still gets its count
                log.info(
                    "scheduler %s: stopped while %s were failing: %d failed over %.1f s",
                    self.name,
                    what,
                    *ended,
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
            self._fanout.setpoint(servo, result.seq, angle_deg, source, when)
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
        return self._fanout.subscribe(callback)

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
        self._fanout.reject(self.name, text, bytes(raw_bytes), when)

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
            snapshot["send_failures"] = self._writer.failures.to_dict(now)
            snapshot["receive_failures"] = self._receiver.failures.to_dict(now)
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
            cpu={"runner_s": self._runner_cpu_s, "receiver_s": self._receiver.cpu_s},
        )
        return snapshot

    def write_metrics(self, path: str | Path) -> Path:
        """Write ``metrics()`` as JSON (the run log calls this at the end of a run)."""
        return write_json(path, self.metrics())

    # ------------------------------------------------------------------------ the threads
    def handle_frame(self, msg: can.Message, t: float) -> ServoState | None:
        """Decode one received frame (called by the receive thread; public for tests and for
        buses that deliver frames through a Notifier instead)."""
        return self._receiver.handle_frame(msg, t)

    def _run(self) -> None:
        pacing = self._pacing
        writer = self._writer
        pacing.apply_realtime(self.timing.realtime_priority, "runner")
        pacing.choose_spin()
        while not self._stop.is_set():
            decision = writer.step()
            writer.send_all(decision)
            if self._nodes:
                writer.send_node_frames()
            with self._lock:
                deadline = min(self._core.next_deadline(self._clock()), self._nodes.next_due())
            self._runner_cpu_s = time.thread_time()
            pacing.wait_until(deadline)

    def _receive(self) -> None:
        self._pacing.apply_realtime(max(1, self.timing.realtime_priority - 1), "receiver")
        self._receiver.run(self._stop)
