"""How the command loop waits for its next deadline, and the real-time policy it runs under.

Its own part because it is the one piece of the scheduler that depends on the operating
system's scheduling rather than on servos or frames: sleep until ``spin_s`` before the deadline,
then spin (yielding the GIL on every turn so the receive thread is never starved). On a shared
non-real-time machine that is what keeps a 50 ms loop within a fraction of a millisecond when a
core is free; ``realtime=True`` asks for SCHED_FIFO, which is what holds under load, and reports
(never raises) when the OS refuses. A runner that finds itself under SCHED_FIFO or SCHED_RR
(asked for, or inherited from the process, as under the systemd unit in deploy/) spins
``fifo_spin_s`` instead (default 0): its plain timed wake-up is late by 0.1-0.25 ms at p99 even
with every core busy, a tenth of the command goal, while a spin at real-time priority is never
preempted and cost a third of the scheduler's CPU (docs/benchmarks.md, Scheduler).
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable

from .schedule_core import TimingConfig

log = logging.getLogger("mavservo.scheduling.runner")  # the scheduler's one logger


class RunnerPacing:
    """The runner thread's waits: until a deadline, or until woken (``wake``) or stopped.

    ``spin_s`` is the spin actually used (``fifo_spin_s`` once the runner runs real-time);
    ``realtime_status`` says what the OS granted, for the metrics and the console.
    """

    def __init__(
        self,
        name: str,
        timing: TimingConfig,
        clock: Callable[[], float],
        stop: threading.Event,
        wake: threading.Event,
    ) -> None:
        self._name = name
        self._timing = timing
        self._clock = clock
        self._stop = stop
        self._wake = wake
        self.spin_s = timing.spin_s
        self.realtime_status = "not requested"

    def apply_realtime(self, priority: int, role: str) -> None:
        """SCHED_FIFO for the calling thread, if asked; a refusal is reported, never raised.

        Both threads get it (the receive thread one step lower): a receive thread preempted by
        ordinary load while it holds the scheduler's lock would otherwise stall the command
        loop behind it (priority inversion).
        """
        if not self._timing.realtime:
            return
        try:
            # pid 0 is the calling thread on Linux
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
            if role == "runner":
                self.realtime_status = f"SCHED_FIFO priority {priority}"
        except (AttributeError, OSError) as exc:
            self.realtime_status = f"refused ({role}): {exc!r}"
            log.warning("scheduler %s: real-time priority refused: %r", self._name, exc)

    def choose_spin(self) -> None:
        """Pick the spin for the calling (runner) thread's actual scheduling policy."""
        try:
            policy = os.sched_getscheduler(0)
        except (AttributeError, OSError):
            return
        if policy in (getattr(os, "SCHED_FIFO", -1), getattr(os, "SCHED_RR", -1)):
            self.spin_s = self._timing.fifo_spin_s
            if self.realtime_status == "not requested":
                self.realtime_status = "inherited real-time policy"

    def wait_until(self, deadline: float) -> None:
        """Sleep to ``spin`` before ``deadline``, then spin; return early when woken."""
        spin = self.spin_s
        clock = self._clock
        wake = self._wake
        while not self._stop.is_set():
            remaining = deadline - clock()
            if remaining <= 0:
                return
            if remaining > spin:
                if wake.wait(remaining - spin):
                    wake.clear()
                    return
                continue
            while clock() < deadline:
                if wake.is_set():
                    wake.clear()
                    return
                time.sleep(0)  # yield the GIL so the receive thread keeps its timestamps true
            return
