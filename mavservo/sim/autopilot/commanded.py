"""What the simulated autopilot asked for, and when: the record tests compute tracking from.

A part of its own because it is the autopilot's memory for the test thread, not part of the
MAVLink conversation: the stream thread records each change (a SERVO_OUTPUT_RAW value, a
command, a gimbal target), the test thread asks what was being commanded at a time, so it is
locked, bounded (``keep`` per key, dropped in halves: amortised O(1)) and answers lookups by
bisection.
"""

from __future__ import annotations

import threading
from bisect import bisect_right
from dataclasses import dataclass
from typing import Any

#: Records kept by default (``keep``): commanded values per channel for
#: :meth:`CommandedLog.at` lookups (about 17 minutes of changes at 20 Hz, 7 at 50 Hz), sent
#: messages, received messages, commands and ACKs. Older commanded values are dropped in
#: halves (amortised O(1)). A process that only streams (``python -m mavservo.sim.autopilot
#: stream``, the soak's autopilot) asks for far fewer, so its memory is flat within a minute.
COMMANDED_KEEP = 20_000


@dataclass(frozen=True, slots=True)
class Commanded:
    """One change of what the autopilot asked for: a SERVO_OUTPUT_RAW value or a command."""

    t: float  # time.monotonic() when it first went out
    key: int  # servo channel (1-based), actuator index (1-based), or 0 for the gimbal
    value: Any  # PWM us, normalized float, or (roll, pitch, yaw, flags)
    source: str  # "servo_output_raw", "do_set_servo", "do_repeat_servo", "do_set_actuator", ...


class CommandedLog:
    """Changes per (kind, key), kind "servo" (channels), "actuator" or "gimbal"; thread-safe."""

    def __init__(self, keep: int = COMMANDED_KEEP) -> None:
        if keep < 2:
            raise ValueError("keep must be >= 2")
        self.keep = keep
        self._lock = threading.Lock()
        self._log: dict[tuple[str, int], list[Commanded]] = {}
        self._times: dict[tuple[str, int], list[float]] = {}  # for bisect

    def record(self, kind: str, entry: Commanded) -> None:
        with self._lock:
            log = self._log.setdefault((kind, entry.key), [])
            times = self._times.setdefault((kind, entry.key), [])
            log.append(entry)
            times.append(entry.t)
            if len(log) > self.keep:  # long runs (soak, `url: sim`) stay bounded
                drop = len(log) - self.keep // 2
                del log[:drop], times[:drop]

    def at(self, kind: str, key: int, t: float) -> Commanded | None:
        """The change of ``kind``/``key`` in force at monotonic time ``t`` (None: none yet)."""
        with self._lock:
            log = self._log.get((kind, key), [])
            i = bisect_right(self._times.get((kind, key), []), t)
            return log[i - 1] if i else None

    def changes(self, kind: str) -> list[Commanded]:
        """Every kept change of ``kind``, in time order."""
        with self._lock:
            return sorted(
                (c for (k, _), log in self._log.items() if k == kind for c in log),
                key=lambda c: c.t,
            )
