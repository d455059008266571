"""A simulated CAN bus: one frame at a time, each taking its real time at the bitrate.

The host side (adapter emulator, virtual-bus bridge) submits frames with the time they became
ready; simulated servos answer frames addressed to them and push status when due. The bus
serialises everything: a frame starts when the bus is free, the lowest identifier wins
arbitration among frames that are waiting, and it completes ``busload.frame_time`` later
(worst-case bit stuffing). So a busy bus delays frames and the measured load means something.

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

from ..busload import frame_time
from .servo import SimServo

HOST = None
"""Source marker for frames submitted by the host side."""


@dataclass(order=True)
class _Pending:
    ready: float
    seq: int
    msg: can.Message
    source: SimServo | None


def arbitration_key(msg: can.Message) -> tuple[int, int, int]:
    """Order in which frames win arbitration: base ID first, then standard before extended."""
    if msg.is_extended_id:
        return (msg.arbitration_id >> 18, 1, msg.arbitration_id & 0x3FFFF)
    return (msg.arbitration_id, 0, 0)


class SimCanBus:
    """Frames between the host and a set of :class:`SimServo`, at a given bitrate."""

    def __init__(self, servos: Iterable[SimServo] = (), bitrate: int = 1_000_000,
                 load_history: int = 4096) -> None:
        self.servos = list(servos)
        self.bitrate = bitrate
        self._pending: list[_Pending] = []
        self._seq = itertools.count()
        self._in_flight: tuple[_Pending, float] | None = None
        self.bus_free_at = -math.inf
        self.frames = 0
        self.busy_s = 0.0
        self._busy: deque[tuple[float, float]] = deque(maxlen=load_history)

    def attach(self, servo: SimServo) -> None:
        self.servos.append(servo)

    def submit(self, msg: can.Message, ready: float, source: SimServo | None = HOST) -> None:
        """Queue ``msg`` for transmission; it may start no earlier than ``ready``."""
        self._pending.append(_Pending(ready, next(self._seq), msg, source))

    def next_event_time(self) -> float | None:
        """Earliest time something will happen on the bus (for a driver thread to sleep to)."""
        times = [s.next_push_time() for s in self.servos]
        candidates = [t for t in times if t is not None]
        if self._in_flight is not None:
            candidates.append(self._in_flight[1])
        elif self._pending:
            candidates.append(max(self.bus_free_at, min(p.ready for p in self._pending)))
        return min(candidates) if candidates else None

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
            if self._in_flight is None and self._pending:
                start = max(self.bus_free_at, min(p.ready for p in self._pending))
            else:
                start = math.inf
            done_at = self._in_flight[1] if self._in_flight else math.inf
            event = min(push_at, start, done_at)
            if event > now:
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
                self._start(start)
        return to_host

    def _start(self, start: float) -> None:
        waiting = [p for p in self._pending if p.ready <= start]
        winner = min(waiting, key=lambda p: (arbitration_key(p.msg), p.seq))
        self._pending.remove(winner)
        msg = winner.msg
        duration = frame_time(msg.is_extended_id, msg.dlc, self.bitrate, msg.is_remote_frame)
        self._in_flight = (winner, start + duration)
        self._busy.append((start, start + duration))
        self.busy_s += duration

    def _complete(self, to_host: list[tuple[float, can.Message]]) -> None:
        assert self._in_flight is not None
        frame, end = self._in_flight
        self._in_flight = None
        self.bus_free_at = end
        self.frames += 1
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
