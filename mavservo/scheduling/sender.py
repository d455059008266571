"""The write side of the scheduler: what the command loop does with a step of the policy core.

Its own part because it is the only code that calls ``bus.send`` (the runner thread, and the
stopping thread once the runner is gone), and it keeps the write side's own state: whether
sends are failing. It books what a step decided (missed slots, lost replies, servos gone
offline and their dropped setpoints) and what the bus did with each frame (written, refused),
under the scheduler's lock, and tells the observers after the lock is released, so a slow
observer never holds up the receive thread.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import can

from mavservo.servos import Fault, ServoState

from .advice import ServoAdvice
from .bus_book import BusBook
from .busload import message_bits
from .failure_run import FailureRun
from .observers import ObserverFanout
from .outage_log import Line
from .schedule_core import Decision, Outgoing, Setpoint

log = logging.getLogger("mavservo.scheduling.runner")  # the scheduler's one logger


class FrameWriter:
    """Steps the policy core and writes its frames to ``bus`` (see the module docstring).

    ``book`` is what it shares with the receive thread, under the book's lock.
    """

    def __init__(
        self,
        name: str,
        bus: can.BusABC,
        *,
        clock: Callable[[], float],
        book: BusBook,
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
        self._advice = advice
        self._fanout = fanout
        self.failures = FailureRun()
        """Failed sends (read and changed under ``lock``)."""

    def step(self) -> Decision:
        """One step of the policy core at the current time, booked (frames not yet sent)."""
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
                # (a slot with frames is timed at its first write, in send_all)
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
                    hint = self._advice.silence_hint(servo)
                    if hint is not None:
                        advice.append((servo, hint))
                more, state = self._go_offline(servo, "no reply", dropped.get(servo), now)
                lines += more
                if state is not None:
                    offline_states.append((servo, state))
            lines += self._online_log.flush(now)
        for servo in decision.lost:
            self._fanout.lost(self._name, servo, now)
        self._log(lines)
        for servo, text in advice:
            self._advice.advise(servo, text)
        for servo, state in offline_states:
            self._fanout.state(servo, state)
        return decision

    def send_all(self, decision: Decision) -> None:
        """Write a step's frames in order, each bus node's packed transfer as one batch."""
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
                ended = self.failures.succeeded(t)
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
                log.info(
                    "scheduler %s: sends work again: %d failed over %.1f s", self._name, *ended
                )
            self._log(lines)
            # every frame once in the CAN log, each tied to one servo it carries a command to
            # (new setpoints first); a packed transfer has fewer frames than commands, so every
            # command it carries is then reported written, at its last frame's write
            paired = sorted(outs, key=lambda out: out.kind != "command")
            for index, msg in enumerate(msgs):
                out = paired[min(index, len(paired) - 1)]
                self._fanout.tx(self._name, msg, t, out.kind, out.servo, out.seq)
            if self._fanout.writes:
                for out in outs:
                    self._fanout.written(self._name, t, out.kind, out.servo, out.seq)

    def _refused(self, out: Outgoing, exc: Exception, now: float) -> None:
        """The bus refused ``out`` (or a frame of the transfer carrying it)."""
        lines: list[Line] = []
        state: ServoState | None = None
        with self._lock:
            failure = self._core.send_failed(out)
            self._metrics.servos[out.servo].send_failed += 1
            first = self.failures.failed(now)
            if failure.went_offline:
                lines, state = self._go_offline(out.servo, "sends failing", failure.dropped, now)
            elif failure.dropped is not None:
                lines = self._dropped(out.servo, failure.dropped, now)
        if first:
            log.warning(
                "scheduler %s: send to %s failed: %s (further failed sends are "
                "counted, not logged, until one works again)",
                self._name,
                out.servo,
                exc,
            )
        self._log(lines)
        if state is not None:
            self._fanout.state(out.servo, state)

    def send_node_frames(self) -> None:
        """The bus nodes' own frames (heartbeat, answers), after the step's frames."""
        now = self._clock()
        with self._lock:
            frames = self._nodes.due(now, self._core.is_online)
        for msg in frames:
            try:
                self._bus.send(msg)
            except can.CanError as exc:
                with self._lock:
                    first = self.failures.failed(self._clock())
                if first:
                    log.warning("scheduler %s: node frame refused: %s", self._name, exc)
                continue
            t = self._clock()
            with self._lock:
                self._metrics.frames_written += 1
                self._metrics.load.add(t, message_bits(msg))
            self._fanout.tx(self._name, msg, t, "lifecycle", "", None)

    def send_final_frames(self) -> None:
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
                    self._name,
                    out.lifecycle,
                    out.servo,
                    exc,
                )
                continue
            t = self._clock()
            with self._lock:
                self._metrics.frames_written += 1
                self._account_tx(out, t)
            self._fanout.tx(self._name, out.msg, t, out.kind, out.servo, out.seq)
            self._fanout.written(self._name, t, out.kind, out.servo, out.seq)

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

    def _go_offline(
        self, servo: str, reason: str, dropped: Setpoint | None, now: float
    ) -> tuple[list[Line], ServoState | None]:
        """Book a servo going offline (caller holds the lock): its state carries NO_REPLY, as
        for a silent servo; returns the lines to log and the state to tell subscribers."""
        self._metrics.servos[servo].went_offline += 1
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

    def _log(self, lines: list[Line]) -> None:
        for level, text in lines:
            log.log(level, "scheduler %s: %s", self._name, text)
