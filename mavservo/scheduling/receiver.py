"""The receive side of the scheduler: one thread reading the bus, decoding replies through the
servo profiles and booking them.

Its own part because it has its own job and its own state: which servos claim a frame (and
which of them report through a bus node), the measured load and its watch, how late replies
come, whether receives are failing. It shares with the command loop only what is booked under
the scheduler's lock (the policy core's reply matching, the metrics, the latest states, the
online log) and the bus nodes, and it never writes to the bus: the runner stays the only
writer, so command-over-telemetry priority stays structural.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Sequence

import can

from mavservo.servos import ServoState, node_reports_of

from .advice import ServoAdvice
from .bus_book import BusBook
from .busload import message_bits
from .failure_run import FailureRun
from .load_watch import LoadWatch
from .observers import ObserverFanout
from .outage_log import LateReplies, Line
from .schedule_core import ServoSpec, TimingConfig, exchange_key

log = logging.getLogger("mavservo.scheduling.runner")  # the scheduler's one logger

RECV_TIMEOUT_S = 0.05
#: At most this many frames booked at the stop (a busy bus never ends: :meth:`drain`).
DRAIN_LIMIT = 10_000


class FrameReceiver:
    """Reads ``bus`` until stopped and books every frame (see the module docstring).

    ``book`` is what it shares with the command loop, under the book's lock; ``wake`` wakes
    the command loop when a bus node has answers to send.
    """

    def __init__(
        self,
        name: str,
        bus: can.BusABC,
        servos: Sequence[ServoSpec],
        timing: TimingConfig,
        *,
        clock: Callable[[], float],
        book: BusBook,
        wake: threading.Event,
        advice: ServoAdvice,
        fanout: ObserverFanout,
    ) -> None:
        self._name = name
        self._bus = bus
        self._clock = clock
        self._online_log = book.online_log
        # bound once: the frame and step paths read them for every frame
        self._lock, self._core, self._metrics = book.lock, book.core, book.metrics
        self._states, self._nodes = book.states, book.nodes
        self._wake = wake
        self._advice = advice
        self._fanout = fanout
        self._specs = {spec.name: spec for spec in servos}
        self._node_reports = {
            spec.name: reports
            for spec in servos
            if (reports := node_reports_of(spec.profile)) is not None
        }
        """The servos whose reports come from a node (resolved once, asked for every frame)."""
        self._late_replies = LateReplies(timing.reply_timeout_s)
        self._load_watch = LoadWatch(name, timing.bitrate, timing.load_window_s, timing.max_load)
        self.failures = FailureRun()
        """Failed receives (read and changed under ``lock``)."""
        self.cpu_s = 0.0
        """The receive thread's CPU time so far."""

    def run(self, stop: threading.Event) -> None:
        """The receive thread's loop, until ``stop`` is set."""
        # This thread's own view of whether receives are failing: the loop checks it on every
        # message, so it is a local (no lock, no attribute lookup) and the shared FailureRun
        # is only touched, under the lock, when a receive fails or works again. It starts from
        # the run's state: stop() leaves an outage that lasted to the end open, and after a
        # restart the first receive that works ends it.
        with self._lock:
            failing = self.failures.failing_since is not None
        while not stop.is_set():
            try:
                msg = self._bus.recv(timeout=RECV_TIMEOUT_S)
            except can.CanError as exc:
                failing = True
                with self._lock:
                    first = self.failures.failed(self._clock())
                if first:
                    log.warning(
                        "scheduler %s: receive failed: %s (further failures are counted, "
                        "not logged, until a receive works again)",
                        self._name,
                        exc,
                    )
                stop.wait(RECV_TIMEOUT_S)
                continue
            if failing:
                failing = False
                now = self._clock()
                with self._lock:
                    ended = self.failures.succeeded(now)
                if ended is not None:
                    log.info(
                        "scheduler %s: receives work again: %d failed over %.1f s",
                        self._name,
                        *ended,
                    )
            if msg is not None:
                self.handle_frame(msg, self._clock())
                if self._nodes:
                    # A DroneCAN transfer is decoded in pure Python (the dronecan package):
                    # hand the interpreter lock over after each frame, so the runner, back
                    # from a write, never waits a whole switch interval (5 ms) for it.
                    time.sleep(0)
            self.cpu_s = time.thread_time()

    def drain(self, wait_s: float, limit: int = DRAIN_LIMIT) -> int:
        """At the stop, once the receive thread is gone: book the frames the bus already
        holds and those arriving within ``wait_s`` of real time (at most ``limit``), so a
        reply that came after its timeout is counted late, not lost. Without it, a reply the
        receive thread had not read yet stayed ``lost``: 4 of a 120 s run's 7,176 replies
        through the autopilot (the bus had all 7,176, 4 queued), the command loop having
        expired them before the stop. Returns the frames booked. Nothing is read from a bus
        whose receives are failing; a receive that fails here is counted as the thread's."""
        with self._lock:
            if self.failures.failing_since is not None:
                return 0
        deadline = time.monotonic() + wait_s
        booked = 0
        while booked < limit:
            left = deadline - time.monotonic()
            try:
                msg = self._bus.recv(timeout=max(0.0, left))
            except can.CanError:
                with self._lock:
                    self.failures.failed(self._clock())
                break
            if msg is None:
                break
            self.handle_frame(msg, self._clock())
            booked += 1
        return booked

    def _node_receive(self, msg: can.Message, t: float) -> None:
        """Give a received frame to the bus nodes (caller holds the lock): answers wake the
        runner, notices are logged here and kept for the bridge."""
        wake, notices = self._nodes.receive(msg, t)
        if wake:
            self._wake.set()
        for notice in notices:
            log.warning("scheduler %s: %s", self._name, notice)

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
            self._advice.announce(warning)
        if not claimants:
            if not msg.is_error_frame:
                self._advice.diagnose(msg)
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
            self._fanout.rx(self._name, msg, t, servo, None)
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
        for level, text in lines:
            log.log(level, "scheduler %s: %s", self._name, text)
        # a sign of life only (NodeStatus) is no answer: the latency's round trip waits for
        # the servo's own report
        self._fanout.rx(self._name, msg, t, servo, state if answer else None)
        self._fanout.state(servo, state)
        return state
