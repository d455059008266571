"""What every simulated USB-serial CAN adapter shares: a pty published under a stable path,
hot-plug, line corruption, and a thread carrying frames over a simulated bus.

:class:`PtyAdapter` is the device side of a serial CAN adapter whose wire format a subclass
speaks (:class:`~mavservo.sim.adapter.AdapterEmulator`: AA-55; :class:`~mavservo.sim.slcan.
SlcanEmulator`: LAWICEL ASCII). The port is a stable symlink (``<dir>/ttyUSBsim0`` ->
``/dev/pts/N``) so that "pulling the USB cable" (:meth:`PtyAdapter.unplug`) and "plugging it
back" (:meth:`PtyAdapter.replug`) look to the host the way a real hot-plug does. Line
corruption (bit flips, dropped bytes, garbage bursts) is injected on the serial side, seeded.

``nodes_bitrate`` injects a wrong-bitrate mistake: the servos' controllers run at that rate
whatever the host sets the adapter to, so a host at another rate hears nothing of them and
they hear nothing of it (:attr:`SimCanBus.nodes_bitrate`).
"""

from __future__ import annotations

import contextlib
import errno
import os
import random
import select
import tempfile
import threading
import time
import tty
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, fields
from typing import Any

import can

from mavservo.threads import BackgroundLoop

from .canbus import SimCanBus
from .servo import SimServo

_MAX_WAIT_S = 0.002

DIRECTIONS = ("to_host", "to_adapter", "both")


@dataclass
class LineFaults:
    """Corruption of the serial line between host and adapter (seeded, per direction)."""

    flip_prob: float = 0.0
    """Per byte: probability one random bit is flipped."""
    drop_byte_prob: float = 0.0
    """Per byte: probability the byte is lost."""
    burst_prob: float = 0.0
    """Per write: probability a burst of random garbage is inserted at a random place."""
    burst_len: int = 8
    direction: str = "to_host"
    """Which way the corruption applies: ``to_host``, ``to_adapter`` or ``both``."""

    def __post_init__(self) -> None:
        if self.direction not in DIRECTIONS:
            raise ValueError(f"line fault direction must be one of {DIRECTIONS}")

    @classmethod
    def from_dict(cls, values: Mapping[str, Any] | None) -> LineFaults:
        values = dict(values or {})
        unknown = sorted(set(values) - {f.name for f in fields(cls)})
        if unknown:
            raise ValueError(f"unknown line fault option(s) {unknown}")
        return cls(**values)

    @property
    def active(self) -> bool:
        return bool(self.flip_prob or self.drop_byte_prob or self.burst_prob)


class LineCorrupter:
    """Applies :class:`LineFaults` to byte chunks, reproducibly for a given seed."""

    def __init__(self, faults: LineFaults, seed: int = 0) -> None:
        self.faults = faults
        self._rng = random.Random(seed)
        self.flipped = 0
        self.dropped = 0
        self.bursts = 0

    def applies_to(self, direction: str) -> bool:
        return self.faults.active and self.faults.direction in (direction, "both")

    def corrupt(self, data: bytes) -> bytes:
        f, rng = self.faults, self._rng
        out = bytearray()
        for byte in data:
            if f.drop_byte_prob and rng.random() < f.drop_byte_prob:
                self.dropped += 1
                continue
            if f.flip_prob and rng.random() < f.flip_prob:
                byte ^= 1 << rng.randrange(8)
                self.flipped += 1
            out.append(byte)
        if f.burst_prob and rng.random() < f.burst_prob:
            at = rng.randrange(len(out) + 1)
            out[at:at] = bytes(rng.randrange(256) for _ in range(f.burst_len))
            self.bursts += 1
        return bytes(out)


class LagMeter:
    """How late the adapter thread handles bus events (a lagging simulator, not the host).

    A servo reply is due on the wire at a known time; if the thread gets there ``lag`` seconds
    later, the host sees the reply that much later. Spikes above ``spike_s`` are kept (bounded)
    with their monotonic time so a bench can line them up with the host's lost replies.
    """

    def __init__(self, spike_s: float = 0.005, keep: int = 1000) -> None:
        self.spike_s = spike_s
        self.max_s = 0.0
        self.samples = 0
        self.spikes: deque[tuple[float, float]] = deque(maxlen=keep)
        self.spike_count = 0

    def add(self, now: float, lag: float) -> None:
        self.samples += 1
        self.max_s = max(self.max_s, lag)
        if lag > self.spike_s:
            self.spike_count += 1
            self.spikes.append((now, lag))

    def take(self) -> dict[str, Any]:
        """The figures since the last call, then start again."""
        out = {
            "max_s": self.max_s,
            "samples": self.samples,
            "spikes": self.spike_count,
            "spike_times": list(self.spikes),
        }
        self.max_s, self.samples, self.spike_count = 0.0, 0, 0
        self.spikes.clear()
        return out


class PtyAdapter:
    """A serial CAN adapter on a pty in front of :class:`SimCanBus`; subclasses speak its
    wire format (:meth:`_from_host`, :meth:`_to_host`, and optionally :meth:`_on_idle` and
    :meth:`_on_plug`)."""

    thread_name = "sim-serial-adapter"

    def __init__(
        self,
        servos: Iterable[SimServo],
        *,
        bitrate: int = 1_000_000,
        line_faults: LineFaults | None = None,
        link_path: str | None = None,
        seed: int = 0,
        clock: Callable[[], float] = time.monotonic,
        nodes_bitrate: int | None = None,
    ) -> None:
        self.canbus = SimCanBus(servos, bitrate)
        self.canbus.nodes_bitrate = nodes_bitrate
        self.clock = clock
        self.line = LineCorrupter(line_faults or LineFaults(), seed)
        self._own_dir = None if link_path else tempfile.mkdtemp(prefix="mavservo-sim-")
        self.path = link_path or os.path.join(self._own_dir or "", "ttyUSBsim0")
        self._master: int | None = None
        self._slave: int | None = None
        self.device: str | None = None
        """The /dev/pts/N the link points to now (None while unplugged)."""
        self._lock = threading.RLock()
        self._loop = BackgroundLoop(self._run, name=self.thread_name)
        self.error: BaseException | None = None

        self.frames_from_host = 0
        self.frames_to_host = 0
        self.bytes_overflowed = 0
        self.plug_count = 0
        self.lag = LagMeter()

    # -- lifecycle ---------------------------------------------------------------------------

    @property
    def servos(self) -> list[SimServo]:
        return self.canbus.servos

    @property
    def bitrate(self) -> int:
        return self.canbus.bitrate

    @property
    def plugged(self) -> bool:
        return self._master is not None

    def start(self) -> Any:
        """Create the port and run the adapter in a background thread (returns ``self``)."""
        self.replug()
        self._loop.start()
        return self

    def stop(self, timeout: float = 2.0) -> None:
        self._loop.stop(timeout)
        self.unplug()
        if self._own_dir is not None:
            with contextlib.suppress(OSError):
                os.rmdir(self._own_dir)

    def __enter__(self) -> Any:
        # ``with X(...).start() as x`` is the usual spelling: a second start would run a second
        # loop on the same state
        return self if self._loop.started else self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def unplug(self) -> None:
        """Pull the USB cable: the pty goes away and the link disappears."""
        with self._lock:
            for fd in (self._master, self._slave):
                if fd is not None:
                    with contextlib.suppress(OSError):
                        os.close(fd)
            self._master = self._slave = None
            self.device = None
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.path)

    def replug(self) -> None:
        """Plug the cable (back) in: a fresh pty, the link re-pointed at it, settings kept."""
        with self._lock:
            if self._master is not None:
                self.unplug()
            master, slave = os.openpty()
            tty.setraw(slave)
            os.set_blocking(master, False)
            self._master, self._slave = master, slave
            self.device = os.ttyname(slave)
            temporary = f"{self.path}.{os.getpid()}.tmp"
            with contextlib.suppress(FileNotFoundError):
                os.unlink(temporary)
            os.symlink(self.device, temporary)
            os.replace(temporary, self.path)
            self._on_plug()
            self.plug_count += 1

    def inject(self, frames: Iterable[can.Message]) -> None:
        """Frames from a foreign node on the bus (an attacker, a second master), queued now:
        the bus carries them like any node's and the host receives them."""
        with self._lock:
            now = self.clock()
            for msg in frames:
                self.canbus.inject(msg, now)

    def load(self, window: float = 1.0) -> float:
        with self._lock:
            return self.canbus.load(self.clock(), window)

    # -- the wire format (subclasses) ----------------------------------------------------------

    def _from_host(self, data: bytes, now: float) -> None:
        """Bytes the host wrote, as it wrote them: the subclass passes them through
        :meth:`_line_to_adapter` (a wrapper may read the clean bytes, see sim/child.py)."""
        raise NotImplementedError

    def _line_to_adapter(self, data: bytes) -> bytes:
        """``data`` after the injected line faults of the host-to-adapter direction."""
        return self.line.corrupt(data) if self.line.applies_to("to_adapter") else data

    def _to_host(self, frames: list[tuple[float, can.Message]]) -> None:
        """Frames that finished on the bus, to be written to the host."""
        raise NotImplementedError

    def _on_idle(self, now: float, idle_s: float) -> None:
        """Nothing came from the host for ``idle_s`` (a parser may flush a partial line)."""
        return None

    def _on_plug(self) -> None:
        """A fresh port: a parser starts over."""
        return None

    # -- the adapter thread --------------------------------------------------------------------

    def _run(self) -> None:
        last_rx = self.clock()
        try:
            while not self._loop.stopping:
                with self._lock:
                    master = self._master
                    next_event = self.canbus.next_event_time()
                now = self.clock()
                wait = _MAX_WAIT_S if next_event is None else next_event - now
                wait = max(0.0, min(_MAX_WAIT_S, wait))
                if master is None:
                    self._loop.wait(wait)
                    data = b""
                else:
                    data = self._read(master, wait)
                with self._lock:
                    now = self.clock()
                    if data:
                        last_rx = now
                        self._from_host(data, now)
                    else:
                        self._on_idle(now, now - last_rx)
                    due = self.canbus.next_event_time()
                    if due is not None and due <= now:
                        self.lag.add(now, now - due)
                    self._to_host(self.canbus.run_until(now))
        except BaseException as error:  # kept for tests and the CLI to report
            self.error = error

    def _read(self, master: int, wait: float) -> bytes:
        try:
            ready, _, _ = select.select([master], [], [], wait)
            if ready:
                return os.read(master, 4096)
        except (OSError, ValueError) as error:
            # EIO: no process holds the slave open; EBADF: unplugged under us.
            if isinstance(error, OSError) and error.errno not in (errno.EIO, errno.EBADF):
                raise
            self._loop.wait(wait)
        return b""

    def _write(self, data: bytes, frames: int) -> None:
        if self._master is None:
            return
        if self.line.applies_to("to_host"):
            data = self.line.corrupt(data)
        self.frames_to_host += frames
        try:
            written = os.write(self._master, data)
        except BlockingIOError:
            written = 0
        except OSError:
            return
        self.bytes_overflowed += len(data) - written
