"""The STATUSTEXT queue: safety texts first, never dropped to make room for chatter.

Why: refused sets each queued a STATUSTEXT into a 32-entry queue that dropped the oldest; under a
50/s flood of NaN sets "autopilot lost, servos in failsafe" reached the ground station 0 of 2
times (606 texts dropped; issue 32, finding 4). Here a text is *essential* when its severity is
CRITICAL or worse (EMERGENCY 0, ALERT 1, CRITICAL 2) or its author says so (the failsafe's
"autopilot back"): essential texts go out before the others and are never dropped while an
ordinary one can be; when the queue is full an ordinary text is dropped (the oldest ordinary
one), so chatter can fill only the ordinary part. Essential texts have their own, larger bound
(:data:`ESSENTIAL_LIMIT`, a bug's flood must not grow memory without end).
"""

from __future__ import annotations

from collections import deque

#: MAV_SEVERITY_CRITICAL: this severity and the graver ones are essential.
CRITICAL = 2
#: Essential texts held at most (far more than a real failure produces in a second).
ESSENTIAL_LIMIT = 256


class TextQueue:
    """``put`` texts, ``pop`` the next one to send: essential ones first, each kind FIFO."""

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self._essential: deque[tuple[int, str]] = deque()
        self._ordinary: deque[tuple[int, str]] = deque()
        self.dropped = 0
        self.essential_dropped = 0

    def __len__(self) -> int:
        return len(self._essential) + len(self._ordinary)

    def put(self, severity: int, text: str, essential: bool = False) -> None:
        if essential or severity <= CRITICAL:
            if len(self._essential) >= ESSENTIAL_LIMIT:
                self._essential.popleft()
                self.essential_dropped += 1
            self._essential.append((severity, text))
            if len(self) > self.limit and self._ordinary:
                self._ordinary.popleft()
                self.dropped += 1
            return
        if len(self) >= self.limit:
            if not self._ordinary:
                self.dropped += 1  # the queue holds only essential texts: this one yields
                return
            self._ordinary.popleft()
            self.dropped += 1
        self._ordinary.append((severity, text))

    def pop(self) -> tuple[int, str] | None:
        if self._essential:
            return self._essential.popleft()
        if self._ordinary:
            return self._ordinary.popleft()
        return None
