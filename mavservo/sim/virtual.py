"""Simulated servos on a python-can ``virtual`` channel, for fast in-process tests.

Code under test opens ``can.Bus(interface="virtual", channel=<same name>)`` and talks to the
servos as if they were on a real bus; a background thread carries frames through
:class:`~mavservo.sim.canbus.SimCanBus`, so replies still take their real bus time.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable

import can

from mavservo.threads import BackgroundLoop

from .canbus import SimCanBus
from .servo import SimServo

_MAX_WAIT_S = 0.002


class VirtualServoBus:
    """Background bridge between a python-can virtual channel and simulated servos.

    Use as a context manager or call :meth:`start` / :meth:`stop`. ``clock`` is injectable so
    a test can share the time base of the code it drives.
    """

    def __init__(
        self,
        servos: Iterable[SimServo],
        channel: str | int = "mavservo-sim",
        bitrate: int = 1_000_000,
        clock: Callable[[], float] = time.monotonic,
        interface: str = "virtual",
    ) -> None:
        """``interface``: the python-can bus the servos sit on (``sitl-mcast``: ArduPilot
        SITL's CAN, channel 0 for CAN_P1)."""
        self.channel = channel
        self.interface = interface
        self.canbus = SimCanBus(servos, bitrate)
        self.clock = clock
        self._loop = BackgroundLoop(self._run, name="sim-virtual-bus")
        self._bus: can.BusABC | None = None
        self.error: BaseException | None = None
        self._lock = threading.Lock()

    @property
    def servos(self) -> list[SimServo]:
        return self.canbus.servos

    def start(self) -> VirtualServoBus:
        self._bus = can.Bus(
            interface=self.interface, channel=self.channel, receive_own_messages=False
        )
        self._loop.start()
        return self

    def stop(self, timeout: float = 2.0) -> None:
        self._loop.stop(timeout)
        if self._bus is not None:
            self._bus.shutdown()
            self._bus = None

    def __enter__(self) -> VirtualServoBus:
        # ``with X(...).start() as x`` is the usual spelling: a second start would run a second
        # loop on the same state
        return self if self._loop.started else self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def load(self, window: float = 1.0) -> float:
        with self._lock:
            return self.canbus.load(self.clock(), window)

    def _run(self) -> None:
        bus = self._bus
        assert bus is not None
        try:
            while not self._loop.stopping:
                now = self.clock()
                with self._lock:
                    next_event = self.canbus.next_event_time()
                wait = _MAX_WAIT_S if next_event is None else next_event - now
                msg = bus.recv(timeout=max(0.0, min(_MAX_WAIT_S, wait)))
                with self._lock:
                    if msg is not None:
                        self.canbus.submit(msg, self.clock())
                    out = self.canbus.run_until(self.clock())
                for _, reply in out:
                    bus.send(reply)
        except BaseException as error:  # surfaced to the test instead of dying silently
            self.error = error
