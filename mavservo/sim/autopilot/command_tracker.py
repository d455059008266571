"""COMMAND_LONG delivery with ACK matching and MAVSDK-style retries, as a pure state machine.

Why a state machine: the retry policy (same content, 0.5 s apart, at most 4 sends) is what the
bridge's de-duplication is tested against, so it must be exact and testable without sockets.
The stream thread asks :meth:`CommandTracker.due` what to (re)send at ``now`` and feeds every
COMMAND_ACK it receives to :meth:`CommandTracker.on_ack`.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

MAV_RESULT_IN_PROGRESS = 5

#: Settled commands and ACKs kept for inspection: a long run (the soak's autopilot child, a
#: scripted stream left running) must not grow, and ``due`` walks the command list every loop.
RECORDS_KEEP = 20_000


@dataclass
class CommandRecord:
    """One logical command and its fate. ``sends`` holds the monotonic time of every send."""

    command: int
    params: tuple[float, ...]
    target_system: int
    target_component: int
    created: float
    sends: list[float] = field(default_factory=list)
    result: int | None = None
    acked_at: float | None = None
    ack_from: tuple[int, int] | None = None
    gave_up: bool = False
    in_progress: bool = False  # an IN_PROGRESS ACK came: wait for the final one, no more retries

    @property
    def attempts(self) -> int:
        return len(self.sends)

    @property
    def done(self) -> bool:
        return self.result is not None or self.gave_up


@dataclass(frozen=True)
class AckRecord:
    """Every COMMAND_ACK received, matched or not, for tests to inspect."""

    t: float
    command: int
    result: int
    source: tuple[int, int]
    target: tuple[int, int]


class CommandTracker:
    """Pending commands, their retries and the ACKs that settle them.

    Memory is bounded by ``keep``: the newest ``keep`` ACKs, and every pending command plus the
    newest settled ones up to ``keep`` records (a pending command is never forgotten: it is
    settled or given up on, never dropped unseen).
    """

    def __init__(
        self, retry_interval_s: float = 0.5, max_attempts: int = 4, keep: int = RECORDS_KEEP
    ) -> None:
        if max_attempts < 1:
            raise ValueError("max_attempts must be >= 1")
        if keep < 1:
            raise ValueError("keep must be >= 1")
        self.retry_interval_s = retry_interval_s
        self.max_attempts = max_attempts
        self.keep = keep
        self.commands: list[CommandRecord] = []
        self.acks: deque[AckRecord] = deque(maxlen=keep)

    def submit(
        self,
        command: int,
        params: tuple[float, ...],
        target_system: int,
        target_component: int,
        now: float,
    ) -> CommandRecord:
        """Queue a command; it is due for its first send at ``now``."""
        if len(params) != 7:
            raise ValueError("COMMAND_LONG has exactly 7 params")
        record = CommandRecord(command, tuple(params), target_system, target_component, now)
        self.commands.append(record)
        if len(self.commands) > self.keep:
            self._forget_settled()
        return record

    def _forget_settled(self) -> None:
        """Drop the oldest settled records beyond ``keep``, down to ``keep // 2`` settled ones
        (in halves, so the cost stays O(1) per submit on average). Pending ones all stay."""
        settled = sum(1 for record in self.commands if record.done)
        drop = settled - self.keep // 2 if len(self.commands) > self.keep else 0
        if drop <= 0:
            return
        kept: list[CommandRecord] = []
        for record in self.commands:
            if drop and record.done:
                drop -= 1
                continue
            kept.append(record)
        self.commands[:] = kept

    def due(self, now: float) -> list[CommandRecord]:
        """Commands to (re)send at ``now``; marks them sent. Gives up after ``max_attempts``."""
        out = []
        for record in self.commands:
            if record.done or record.in_progress:
                continue
            if record.sends and now - record.sends[-1] < self.retry_interval_s:
                continue
            if record.attempts >= self.max_attempts:
                record.gave_up = True
                continue
            record.sends.append(now)
            out.append(record)
        return out

    def on_ack(
        self,
        command: int,
        result: int,
        source: tuple[int, int],
        target: tuple[int, int],
        now: float,
    ) -> CommandRecord | None:
        """Record an ACK and settle the oldest matching pending command (None if none matched).

        A command addressed to component 0 (broadcast) is settled by an ACK from any component
        of the target system; IN_PROGRESS keeps it pending but stops the retries, as MAVSDK does.
        """
        self.acks.append(AckRecord(now, command, result, source, target))
        for record in self.commands:
            if record.done or record.command != command or not record.sends:
                continue
            if record.target_system not in (0, source[0]):
                continue
            if record.target_component not in (0, source[1]):
                continue
            if result == MAV_RESULT_IN_PROGRESS:
                record.in_progress = True
                return record
            record.result = result
            record.acked_at = now
            record.ack_from = source
            return record
        return None

    @property
    def idle(self) -> bool:
        return all(record.done for record in self.commands)
