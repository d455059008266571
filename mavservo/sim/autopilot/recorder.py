"""What the simulated autopilot heard back: counts, last message and arrival log per type.

Tests of the bridge read this instead of opening their own socket: the bridge's telemetry goes to
the autopilot link, which is the simulator. Thread-safe because the stream thread writes while
the test thread reads.
"""

from __future__ import annotations

import threading
from collections import Counter, deque
from typing import Any


class Received:
    """Counts per message type, last message per type, and a bounded arrival log."""

    def __init__(self, keep: int = 20_000) -> None:
        self._lock = threading.Lock()
        self._counts: Counter[str] = Counter()
        self._last: dict[str, Any] = {}
        self._log: deque[tuple[float, Any]] = deque(maxlen=keep)

    def add(self, t: float, msg: Any) -> None:
        name = msg.get_type()
        with self._lock:
            self._counts[name] += 1
            self._last[name] = msg
            self._log.append((t, msg))

    def count(self, msg_type: str) -> int:
        with self._lock:
            return self._counts[msg_type]

    def counts(self) -> dict[str, int]:
        with self._lock:
            return dict(self._counts)

    def last(self, msg_type: str) -> Any | None:
        with self._lock:
            return self._last.get(msg_type)

    def messages(self, msg_type: str | None = None) -> list[tuple[float, Any]]:
        """(t_monotonic, msg) in arrival order, optionally of one type."""
        with self._lock:
            return [(t, m) for t, m in self._log if msg_type is None or m.get_type() == msg_type]
