"""One background loop's lifecycle: a stop request, a named daemon thread, a bounded join.

The simulator, the adapter emulator, the simulated autopilot and the bridge's MAVLink side each
run one loop in a thread, and each wrote the same ten lines by hand (an Event, a Thread, clear,
start, set, join with a timeout, forget), with small differences nobody chose: one could not be
restarted, none said when a join timed out, a restart after such a timeout ran two loops. This
class is those lines once. It imports nothing of the project, so every layer may use it.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

log = logging.getLogger(__name__)

#: How long :meth:`BackgroundLoop.stop` waits for the loop to notice, unless told otherwise.
DEFAULT_JOIN_TIMEOUT_S = 2.0


class BackgroundLoop:
    """Runs ``target`` in a daemon thread called ``name`` until :meth:`stop`.

    ``target`` polls :attr:`stopping` or sleeps with :meth:`wait` (which returns early, True,
    once a stop was requested), so stopping never waits out a sleep.
    """

    def __init__(self, target: Callable[[], None], name: str) -> None:
        self._target = target
        self.name = name
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def stopping(self) -> bool:
        """True once a stop was requested (until the next :meth:`start`)."""
        return self._stop.is_set()

    @property
    def is_running(self) -> bool:
        """True while the thread is alive (also between a stop request and its end)."""
        return self._thread is not None and self._thread.is_alive()

    @property
    def started(self) -> bool:
        """True from :meth:`start` until a :meth:`stop` saw the thread end."""
        return self._thread is not None

    @property
    def stop_event(self) -> threading.Event:
        """The stop request as an Event, for functions that take one (``replay(stop=...)``)."""
        return self._stop

    def wait(self, seconds: float) -> bool:
        """Sleep up to ``seconds``; True at once when a stop is (or gets) requested."""
        return self._stop.wait(seconds)

    def start(self) -> None:
        """Start the thread; refused while the previous one still runs (two loops would share
        one state)."""
        if self.is_running:
            raise RuntimeError(f"{self.name}: already running")
        self._stop.clear()
        self._thread = threading.Thread(target=self._target, name=self.name, daemon=True)
        self._thread.start()

    def join(self, timeout: float) -> bool:
        """Wait at most ``timeout`` for the loop to end by itself (no stop request); True when
        it has ended, or never started."""
        thread = self._thread
        if thread is None or thread is threading.current_thread():
            return thread is None
        thread.join(timeout)
        return not thread.is_alive()

    def request_stop(self) -> None:
        """Ask the loop to end, without waiting for it."""
        self._stop.set()

    def stop(self, timeout: float = DEFAULT_JOIN_TIMEOUT_S) -> bool:
        """Ask the loop to end and wait at most ``timeout``; True when it has ended.

        Called from the loop itself (a loop stopping its owner) it only asks: a thread cannot
        join itself. A loop still running after ``timeout`` is logged and stays referenced, so
        :attr:`is_running` tells the truth and :meth:`start` refuses to run a second one.
        """
        self._stop.set()
        thread = self._thread
        if thread is None:
            return True
        if thread is threading.current_thread():
            return False
        thread.join(timeout)
        if thread.is_alive():
            log.warning("%s: still running %.1f s after the stop request", self.name, timeout)
            return False
        self._thread = None
        return True


def set_from_signal_handler(event: threading.Event) -> None:
    """Set ``event`` from a signal handler, without taking the event's lock in the handler.

    Why: a handler runs in the main thread between two bytecodes, possibly while the main
    thread itself is inside ``event.wait()`` holding the event's internal lock (a plain, not
    re-entrant, Lock); ``event.set()`` in the handler then waits for that lock for ever. A
    SIGTERM landing in that window hung ``mavservo sim`` (a test killed it after 20 s), and
    ``mavservo run`` waits on its stop event the same way: under systemd the bridge would have
    been SIGKILLed without telling its servos their stop action. A short-lived thread sets the
    event instead: it waits, if it must, until the main thread has left the lock.
    """
    threading.Thread(target=event.set, name="signal-stop", daemon=True).start()
