"""The run log's bounded queue and its one writer thread: callers never wait on the disk.

Its own part because it is the run log's promise to the scheduler and the link ("a slow disk
costs log lines, never command slots"), and that promise is about the queue, not the files:
:meth:`EventPump.put` appends to a deque (atomic, wakes nobody) or, once ``queue_size`` events
wait, counts the event as dropped; the writer thread polls, hands each event to an
:class:`EventWriter` and flushes it once a second. Anything with ``write``/``flush``/``capped``
can sit behind it (:class:`~.run_files.RunFiles` in a run; a list in a test).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter, deque
from typing import Protocol

from mavservo.records.problems import RunLogProblems
from mavservo.records.run_events import CATEGORY, Event

POLL_S = 0.05  # the writer wakes on its own; callers never signal it
FLUSH_EVERY_S = 1.0
#: Events the writer handles between two hand-overs of the interpreter lock (~1.5 ms of
#: ASC + BLF work at ~24 us a frame).
YIELD_EVERY = 64

#: the run log's one logger, whichever of its parts speaks (users filter on its name)
log = logging.getLogger("mavservo.records.runlog")


class EventWriter(Protocol):
    """What the writer thread drives: one event at a time, a flush a second, a size cap."""

    @property
    def capped(self) -> bool:
        """True once nothing more may be written this run (the events are counted dropped)."""
        ...

    def write(self, item: Event) -> None:
        """Write one event; an ``OSError`` means a file failed (already reported)."""
        ...

    def flush(self) -> None:
        """Put what was written onto the disk."""
        ...


class EventPump:
    """A bounded queue of events drained into ``writer`` by one daemon thread.

    :attr:`written` and :attr:`dropped` count events per category (``dropped`` also per
    cause: ``cap``, ``write_failed``); an event that breaks the writer for another reason is
    counted in ``problems`` (:meth:`RunLogProblems.event_failed`) and the thread goes on.
    """

    def __init__(
        self,
        writer: EventWriter,
        problems: RunLogProblems,
        queue_size: int,
        *,
        name: str = "mavservo-runlog",
    ) -> None:
        self._writer = writer
        self._problems = problems
        self._name = name
        # A deque, not a queue.Queue: append is atomic and wakes nobody, so a caller never
        # waits on a lock or hands the GIL to the writer; the writer polls every POLL_S.
        self._queue: deque[Event] = deque()
        self.queue_size = int(queue_size)
        self._stopping = threading.Event()
        self._drop_lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self.dropped: Counter[str] = Counter()
        self.written: Counter[str] = Counter()

    def put(self, item: Event) -> None:
        """Queue ``item`` (any thread, never blocks); dropped and counted when full."""
        if len(self._queue) < self.queue_size:
            self._queue.append(item)
        else:
            with self._drop_lock:
                self.dropped[CATEGORY[item[0]]] += 1

    @property
    def started(self) -> bool:
        return self._thread is not None

    def start(self) -> None:
        """Start the writer thread (idempotent)."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name=self._name, daemon=True)
            self._thread.start()

    def stop(self, timeout: float) -> None:
        """Let the thread write what is queued, then end it (waits at most ``timeout``)."""
        self._stopping.set()
        if self._thread is not None:
            self._thread.join(timeout)

    def _run(self) -> None:
        last_flush = time.monotonic()
        while True:
            stopping = self._stopping.is_set()  # read before draining: nothing is left behind
            burst = 0
            while self._queue:
                burst += 1
                if burst % YIELD_EVERY == 0:
                    # hand the interpreter lock over: a drain of thousands of frames (every
                    # frame of a busy bus) would otherwise hold it a whole switch interval
                    # (5 ms) while the scheduler waits to write its command slot
                    time.sleep(0)
                item = self._queue.popleft()
                if self._writer.capped:
                    self.dropped["cap"] += 1
                    continue
                try:
                    self._writer.write(item)
                    self.written[CATEGORY[item[0]]] += 1
                except OSError:  # a full disk must not kill the bridge
                    self.dropped["write_failed"] += 1
                except Exception as exc:  # noqa: BLE001 - nor must one odd event
                    self._problems.event_failed(exc)
            if stopping:
                return
            self._stopping.wait(POLL_S)
            now = time.monotonic()
            if now - last_flush >= FLUSH_EVERY_S:
                last_flush = now
                try:
                    self._writer.flush()
                except Exception:  # noqa: BLE001 - the writer thread must outlive any file
                    log.exception("run log flush failed")
