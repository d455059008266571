"""Saving the parameter overlay off the MAVLink path: coalesced, in its own thread.

Why: the overlay was written and fsynced twice per PARAM_SET while the MAVLink lock was held.
200 sets a second with a slow SD card (+20 ms per fsync) queued heartbeats behind the writes and
the bridge declared a healthy autopilot lost seven times (issue 32, finding 2). Here a set only
hands the latest values over (:meth:`OverlaySaver.submit`, no I/O); a thread writes them
(atomically, fsync included: :func:`mavservo.config.overlay.write_overlay`) at most once per
``interval_s``, so a flood of sets costs one write a second whatever its rate. A write that
fails is reported through ``on_failure`` (the bridge sends it as STATUSTEXT: the ground station
must know a value will not survive a restart), once per kind of failure until a write succeeds.
A failed write is tried again every ``interval_s`` (review3: the values of a write that failed
once, a state directory not yet mounted, a full disk, were never written again unless another
PARAM_SET came, so a space freed later still lost them at the next restart).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path

from mavservo.config import write_overlay
from mavservo.threads import BackgroundLoop

log = logging.getLogger(__name__)

#: Shortest time between two overlay writes.
SAVE_INTERVAL_S = 1.0


class OverlaySaver:
    """The overlay file's one writer: the latest submitted values, written by its own thread."""

    def __init__(
        self,
        path: Path,
        config_name: str,
        *,
        on_failure: Callable[[str], None] = lambda text: None,
        interval_s: float = SAVE_INTERVAL_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.path = path
        self._config_name = config_name
        self._on_failure = on_failure
        self.interval_s = interval_s
        self._clock = clock
        self._lock = threading.Lock()
        self._pending: dict[str, float] | None = None
        self._wake = threading.Event()
        self._loop = BackgroundLoop(self._run, name="overlay-saver")
        self._last_write = -float("inf")
        self._failing: str | None = None  # the failure reported last (None: writes succeed)
        self.writes = 0
        self.failures = 0

    def submit(self, values: Mapping[str, float]) -> None:
        """The overlay is now ``values``: written soon (never on the caller's thread)."""
        with self._lock:
            self._pending = dict(values)
        self._wake.set()

    def start(self) -> None:
        self._loop.start()

    def stop(self) -> None:
        """Stop the thread and write what is still pending (a clean stop loses no value)."""
        self._loop.request_stop()
        self._wake.set()
        self._loop.stop()
        self._write_pending()

    def _run(self) -> None:
        while not self._loop.stopping:
            self._wake.wait(1.0)
            if self._loop.stopping:
                return
            delay = self._last_write + self.interval_s - self._clock()
            if delay > 0 and self._loop.wait(delay):
                return
            self._wake.clear()
            self._write_pending()

    def _write_pending(self) -> None:
        with self._lock:
            values, self._pending = self._pending, None
        if values is None:
            return
        self._last_write = self._clock()
        try:
            if values or self.path.exists() or self.path.is_symlink():
                write_overlay(self.path, values, self._config_name)
        except OSError as exc:
            self.failures += 1
            with self._lock:  # tried again at the next interval unless newer values came
                if self._pending is None:
                    self._pending = values
            reason = exc.strerror or type(exc).__name__
            if reason != self._failing:
                self._failing = reason
                log.error(
                    "parameters: cannot write %s (%s); the values are in force but will not "
                    "survive a restart (set StateDirectory= or make the directory writable)",
                    self.path,
                    exc,
                )
                self._on_failure(f"servo bridge: parameters not saved: {reason}")
            return
        self.writes += 1
        if self._failing is not None:
            self._failing = None
            log.info("parameters: %s written again", self.path)

    def stats(self) -> dict[str, int]:
        return {"overlay_writes": self.writes, "overlay_write_failures": self.failures}
