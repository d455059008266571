"""A simulated CAN bus: one frame at a time, each taking its real time at the bitrate.

The host side (adapter emulator, virtual-bus bridge) submits frames with the time they became
ready; simulated servos answer frames addressed to them and push status when due. The bus
serialises everything: a frame starts when the bus is free, the lowest identifier wins
arbitration among frames that are waiting, and it completes ``busload.frame_time`` later
(worst-case bit stuffing). So a busy bus delays frames and the measured load means something.

A foreign node that keeps the bus busy (:meth:`SimCanBus.set_flood`) is modelled as a frame that
is always waiting at its identifier: it takes part in every arbitration like any other frame,
but a run of consecutive flood frames is played as one segment (until a frame that beats it
becomes ready, a servo push, or ``now``), so a 100 % load costs no Python object per frame and
the simulation keeps real time. The host's transmit queue is bounded like an adapter's
(``host_queue``): a bus that never frees up drops the host's frames instead of growing a list.

Pure: time is passed in; ``run_until(now)`` plays the events up to ``now`` and returns the
frames the host should see, with the time each one finished on the wire.
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass

import can

from mavservo.scheduling import frame_time

from .servo import SimServo

HOST = None
"""Source marker for frames submitted by the host side."""


class ForeignNode:
    """Source marker of frames from a node that is neither the host nor a simulated servo (an
    autopilot's own traffic on a shared bus): they reach the host, no servo answers them."""


FOREIGN = ForeignNode()


@dataclass(order=True)
class _Pending:
    ready: float
    seq: int
    msg: can.Message
    source: SimServo | ForeignNode | None


@dataclass
class Flood:
    """A foreign node with one frame always queued: what it is and what it has sent so far."""

    msg: can.Message
    duration: float
    since: float
    sent: int = 0


@dataclass
class _FloodRun:
    """Consecutive flood frames on the wire from ``start``: ``count`` of them, ``delivered``
    already handed to the host."""

    flood: Flood
    start: float
    count: int
    delivered: int = 0

    def deliver(
        self, now: float, to_host: list[tuple[float, can.Message]], finished: bool = False
    ) -> None:
        """Hand over the frames that finished by ``now`` (one shared message object); all of
        them when the run is ``finished``.

        ``now - start`` is a difference of monotonic times: past 2**15 s of uptime its rounding
        error (~7e-12 s) exceeds 1e-9 of a frame, so the frame count is rounded with a
        tolerance of a thousandth of a frame, and a finished run never relies on it (it used
        to lose its last frame one run in two once the machine had been up 9 hours).
        """
        if finished:
            done = self.count
        else:
            elapsed = (now - self.start) / self.flood.duration
            done = min(self.count, int(elapsed + 1e-3))
        if done > self.delivered:
            end = self.start + done * self.flood.duration
            to_host.extend([(end, self.flood.msg)] * (done - self.delivered))
            self.flood.sent += done - self.delivered
            self.delivered = done


def arbitration_key(msg: can.Message) -> tuple[int, int, int]:
    """Order in which frames win arbitration: base ID first, then standard before extended."""
    if msg.is_extended_id:
        return (msg.arbitration_id >> 18, 1, msg.arbitration_id & 0x3FFFF)
    return (msg.arbitration_id, 0, 0)


class SimCanBus:
    """Frames between the host and a set of :class:`SimServo`, at a given bitrate."""

    def __init__(
        self,
        servos: Iterable[SimServo] = (),
        bitrate: int = 1_000_000,
        load_history: int = 4096,
        host_queue: int = 64,
    ) -> None:
        self.servos = list(servos)
        self.bitrate = bitrate
        self._pending: list[_Pending] = []
        self._seq = itertools.count()
        self._in_flight: tuple[_Pending | _FloodRun, float] | None = None
        self.bus_free_at = -math.inf
        self.flood: Flood | None = None
        self.host_queue = host_queue
        """Frames from the host waiting for the bus, at most (an adapter's TX buffer)."""
        self._host_waiting = 0
        self.host_dropped = 0
        """Frames from the host dropped because that queue was full (bus never free)."""
        self.nodes_bitrate: int | None = None
        """The rate the servos' controllers run at (None: whatever ``bitrate`` is). When the
        host's adapter is set to another rate, neither side decodes the other: the host's
        frames reach no servo and the servos' frames reach the host as nothing (an injected
        wrong-bitrate mistake; a real controller sees error frames, which AA-55 and LAWICEL
        adapters do not pass on)."""
        self.bitrate_mismatches = 0
        """Frames lost to that mismatch, either way."""
        self.frames = 0
        self.busy_s = 0.0
        self._busy: deque[tuple[float, float]] = deque(maxlen=load_history)

    def submit(
        self, msg: can.Message, ready: float, source: SimServo | ForeignNode | None = HOST
    ) -> None:
        """Queue ``msg`` for transmission; it may start no earlier than ``ready``."""
        if source is HOST:
            if self._host_waiting >= self.host_queue:
                self.host_dropped += 1
                return
            self._host_waiting += 1
        self._pending.append(_Pending(ready, next(self._seq), msg, source))

    def inject(self, msg: can.Message, ready: float) -> None:
        """Queue a frame of a node outside the simulation (:data:`FOREIGN`): it arbitrates
        like any frame and reaches the host; no simulated servo answers it."""
        self._pending.append(_Pending(ready, next(self._seq), msg, FOREIGN))

    def set_flood(
        self, arbitration_id: int | None, now: float, dlc: int = 8, extended: bool = False
    ) -> None:
        """Start (or with None stop) a foreign node transmitting ``dlc``-byte frames back to
        back at ``arbitration_id`` from ``now`` on."""
        if arbitration_id is None:
            self.flood = None
            return
        msg = can.Message(
            arbitration_id=arbitration_id, is_extended_id=extended, data=bytes(dlc), is_rx=True
        )
        self.flood = Flood(msg, frame_time(extended, dlc, self.bitrate, False), now)

    def next_event_time(self) -> float | None:
        """Earliest time something will happen on the bus (for a driver thread to sleep to)."""
        times = [s.next_push_time() for s in self.servos]
        candidates = [t for t in times if t is not None]
        if self._in_flight is not None:
            frame, end = self._in_flight
            if not isinstance(frame, _FloodRun) or self._beats_flood(frame.flood):
                # flood frames to the host may wait for the driver's next round (an adapter
                # batches them into USB packets anyway); a frame that wins against them may not
                candidates.append(end)
        else:
            candidates.append(self._next_start())
        candidates = [t for t in candidates if t != math.inf]
        return min(candidates) if candidates else None

    def _next_start(self) -> float:
        """When the idle bus starts its next frame (inf: nothing waits)."""
        start = math.inf
        if self._pending:
            start = max(self.bus_free_at, min(p.ready for p in self._pending))
        if self.flood is not None:
            start = min(start, max(self.bus_free_at, self.flood.since))
        return start

    def run_until(self, now: float) -> list[tuple[float, can.Message]]:
        """Play the bus up to ``now``; return servo frames that completed, in order."""
        to_host: list[tuple[float, can.Message]] = []
        for servo in self.servos:  # arm the push timer of servos that never ran yet
            if servo.next_push_time() is None:
                servo.poll(now)
        while True:
            push_at = min(
                (t for t in (s.next_push_time() for s in self.servos) if t is not None),
                default=math.inf,
            )
            start = self._next_start() if self._in_flight is None else math.inf
            done_at = self._in_flight[1] if self._in_flight else math.inf
            event = min(push_at, start, done_at)
            if event > now:
                if self._in_flight is not None and isinstance(self._in_flight[0], _FloodRun):
                    self._in_flight[0].deliver(now, to_host)
                break
            if event == done_at:
                self._complete(to_host)
            elif event == push_at:
                for servo in self.servos:
                    due_at = servo.next_push_time()
                    if due_at is not None and due_at <= push_at:
                        for due, reply in servo.poll(push_at):
                            self.submit(reply, due, servo)
            else:
                self._start(start, min(push_at, now))
        return to_host

    def _start(self, start: float, horizon: float) -> None:
        waiting = [p for p in self._pending if p.ready <= start]
        winner = min(waiting, key=lambda p: (arbitration_key(p.msg), p.seq)) if waiting else None
        flood = self.flood
        if flood is not None and (
            winner is None or arbitration_key(flood.msg) < arbitration_key(winner.msg)
        ):
            self._start_flood(flood, start, horizon)
            return
        assert winner is not None
        self._pending.remove(winner)
        if winner.source is HOST:
            self._host_waiting -= 1
        msg = winner.msg
        duration = frame_time(msg.is_extended_id, msg.dlc, self.bitrate, msg.is_remote_frame)
        self._in_flight = (winner, start + duration)
        self._busy.append((start, start + duration))
        self.busy_s += duration

    def _beats_flood(self, flood: Flood) -> bool:
        key = arbitration_key(flood.msg)
        return any(arbitration_key(p.msg) < key for p in self._pending)

    def _start_flood(self, flood: Flood, start: float, horizon: float) -> None:
        """The flood wins at ``start`` and keeps winning until a frame that beats it is ready
        or ``horizon`` (a servo push, or ``now``): one segment of back-to-back frames, the
        last one still on the wire at that moment (a frame is never pre-empted)."""
        key = arbitration_key(flood.msg)
        beaten_at = min(
            (p.ready for p in self._pending if p.ready > start and arbitration_key(p.msg) < key),
            default=math.inf,
        )
        until = min(beaten_at, horizon)
        count = max(1, math.ceil((until - start) / flood.duration - 1e-9))
        end = start + count * flood.duration
        self._in_flight = (_FloodRun(flood, start, count), end)
        if self._busy and self._busy[-1][1] == start:  # back to back: one busy interval
            start = self._busy.pop()[0]
        self._busy.append((start, end))
        self.busy_s += count * flood.duration

    def _complete(self, to_host: list[tuple[float, can.Message]]) -> None:
        assert self._in_flight is not None
        frame, end = self._in_flight
        self._in_flight = None
        self.bus_free_at = end
        if isinstance(frame, _FloodRun):
            self.frames += frame.count
            frame.deliver(end, to_host, finished=True)
            return
        self.frames += 1
        if self.nodes_bitrate is not None and self.nodes_bitrate != self.bitrate:
            self.bitrate_mismatches += 1
            return
        if frame.source is HOST:
            for servo in self.servos:
                for due, reply in servo.receive(frame.msg, end):
                    self.submit(reply, max(due, end), servo)
        else:
            frame.msg.timestamp = end
            to_host.append((end, frame.msg))

    def load(self, now: float, window: float = 1.0) -> float:
        """Fraction of ``[now - window, now]`` the bus spent carrying frames (0..1)."""
        since = now - window
        busy = sum(max(0.0, min(end, now) - max(start, since)) for start, end in self._busy)
        return busy / window
