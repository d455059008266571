"""The adapter emulator and its servos in a child process, driven over a pipe.

Why a child: real servos and a real USB-CAN adapter do not share the host's CPU, let alone its
interpreter lock. In one process the simulator's threads compete with the bridge for the GIL,
so a timing figure (a missed command slot, a late reply) measures both. :class:`SimulatorProcess`
starts ``python -m mavservo.sim.child`` (optionally at SCHED_FIFO, as hardware runs beside the
host rather than on it), reads the device path from its first output line, and then speaks
one JSON object per line: a request on the child's stdin, one reply on its stdout.

Requests (``op`` and its arguments):

* ``stats``: the adapter's counters, bus load, flood frames, host frames dropped by the full
  TX queue, and the adapter thread's lag since the last ``stats`` (:class:`LagMeter`);
* ``line``: replace the line corruption (:class:`LineFaults` fields; none: a clean line);
* ``unplug`` / ``replug``: the USB cable;
* ``servo_faults``: ``can_id`` and :class:`Faults` fields to set on that servo;
* ``flood``: ``arbitration_id`` (None stops it), ``dlc``: a foreign node at 100 % bus load;
* ``arrivals``: the frames from the host that reached the CAN bus since the last call, as
  ``"id:ext:rtr:datahex" -> count`` (to find frames the host never sent);
* ``wrong``: host frames that reached the bus so far, and how many of them the host never
  sent (judged against the host's bytes before the line corrupted them);
* ``trace``: ``t0``, ``t1``, ``ids``: frames with those IDs that reached the bus from the host
  or left the adapter for the host in that time (to follow a lost reply).

Time in replies is ``time.monotonic()``, the same clock as the parent's on Linux.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import threading
from collections import Counter, deque
from collections.abc import Sequence
from typing import Any

import can

from mavservo.transport import AA55Frame

from .adapter import AdapterEmulator, LineCorrupter, LineFaults, host_decoder
from .canbus import HOST, ForeignNode
from .servo import SimServo


def frame_key(msg: can.Message | AA55Frame) -> str:
    """A frame as text, identical for the same frame on both sides of the pipe."""
    return (
        f"{msg.arbitration_id:x}:{int(msg.is_extended_id)}:{int(msg.is_remote_frame)}:"
        f"{bytes(msg.data).hex()}"
    )


class RecentKeys:
    """The last ``window`` frame keys sent, as a multiset: "was this frame sent lately?"

    Why bounded: a frame reaches the adapter within milliseconds of being sent, and a soak must
    not measure the checker's own growth.
    """

    def __init__(self, window: int) -> None:
        self._window = window
        self._order: deque[str] = deque()
        self._counts: Counter[str] = Counter()

    def add(self, key: str) -> None:
        self._order.append(key)
        self._counts[key] += 1
        if len(self._order) > self._window:
            old = self._order.popleft()
            self._counts[old] -= 1
            if not self._counts[old]:
                del self._counts[old]

    def __contains__(self, key: object) -> bool:
        return key in self._counts


class SimulatorProcess:
    """A child process running :class:`AdapterEmulator`; ``path`` is the device to open.

    ``servos``: that many RMD-X servos with IDs 1..n, or ``config`` (a mavservo YAML file) and
    ``bus``: the same simulated servos the bridge would build for ``channel: sim``.
    ``realtime_priority``: run the child at SCHED_FIFO with that priority (None: normal).
    ``trace_keep`` / ``max_keys``: bound the trace and the arrival counts (:class:`_Arrivals`)
    lower than the defaults, so a long run's child is full (flat) sooner.
    """

    def __init__(
        self,
        servos: int | None = None,
        *,
        bitrate: int = 1_000_000,
        protocol: str = "variable",
        realtime_priority: int | None = None,
        config: str | None = None,
        bus: str = "bus0",
        start_timeout_s: float = 20.0,
        trace_keep: int | None = None,
        max_keys: int | None = None,
    ) -> None:
        command = [
            sys.executable,
            "-m",
            "mavservo.sim.child",
            "--bitrate",
            str(bitrate),
            "--protocol",
            protocol,
        ]
        if config is not None:
            command += ["--config", config, "--bus", bus]
        else:
            command += ["--servos", str(servos or 1)]
        if realtime_priority is not None:
            command += ["--realtime", str(realtime_priority)]
        if trace_keep is not None:  # the owner's bounds (None: the child's defaults)
            command += ["--trace-keep", str(trace_keep)]
        if max_keys is not None:
            command += ["--max-keys", str(max_keys)]
        self.process = subprocess.Popen(
            command,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            bufsize=1,
            env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
        )
        self._lock = threading.Lock()
        timer = threading.Timer(start_timeout_s, self.process.kill)
        timer.start()
        try:
            assert self.process.stdout is not None
            self.path = self.process.stdout.readline().strip()
        finally:
            timer.cancel()
        if not self.path:
            self.process.wait(5)
            raise RuntimeError(f"simulator child did not start (exit {self.process.returncode})")

    def request(self, op: str, **args: Any) -> dict[str, Any]:
        """Send one request, return the child's reply (raises if the child reports an error)."""
        assert self.process.stdin is not None and self.process.stdout is not None
        with self._lock:
            self.process.stdin.write(json.dumps({"op": op, **args}) + "\n")
            self.process.stdin.flush()
            line = self.process.stdout.readline()
        if not line:
            raise RuntimeError("simulator child is gone")
        reply = json.loads(line)
        if "error" in reply:
            raise RuntimeError(f"simulator child: {reply['error']}")
        return reply

    def stop(self) -> None:
        """Close the pipe (the child stops its adapter and exits); kill it if it hangs."""
        if self.process.poll() is None:
            try:
                assert self.process.stdin is not None
                self.process.stdin.close()
                self.process.wait(10)
            except (OSError, subprocess.TimeoutExpired):
                self.process.kill()
                self.process.wait(5)

    def __enter__(self) -> SimulatorProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class _Arrivals:
    """What the host's frames became on the way, all measured inside the child.

    * ``counts``: host frames as they reach the bus (wraps ``SimCanBus.submit``), by key;
      cleared when it holds ``max_keys`` distinct frames and nobody took it;
    * ``arrived`` / ``wrong``: every host frame that reached the bus, and those the host never
      sent. What was sent is read from the host's bytes *before* the line corrupts them (a
      second decoder on the clean stream), so the check costs the host nothing;
    * ``trace``: a bounded record of frames in both directions, so a lost reply can be
      followed to where it went missing: ``(t, "in", id, t)`` when a host frame reached the
      bus, ``(t, "out", id, end)`` when the adapter handed a servo's frame (finished on the
      wire at ``end``) to the host. Flood frames are not traced.
    """

    def __init__(
        self, emulator: AdapterEmulator, keep: int = 150_000, max_keys: int = 200_000
    ) -> None:
        self.counts: Counter[str] = Counter()
        self.max_keys = max_keys
        self.trace: deque[tuple[float, str, int, float]] = deque(maxlen=keep)
        self.arrived = 0
        self.wrong = 0
        self._sent = RecentKeys(60_000)
        self._emulator = emulator
        self._clean = host_decoder(emulator.protocol)
        self._clean_protocol = emulator.protocol
        canbus = emulator.canbus
        submit_original, run_original = canbus.submit, canbus.run_until
        from_host_original = emulator._from_host

        def from_host(data: bytes, now: float) -> None:
            self._remember_sent(data)
            from_host_original(data, now)

        def submit(
            msg: can.Message, ready: float, source: SimServo | ForeignNode | None = HOST
        ) -> None:
            if source is HOST:
                key = frame_key(msg)
                self.arrived += 1
                if key not in self._sent:
                    self.wrong += 1
                if len(self.counts) >= self.max_keys:
                    self.counts.clear()
                self.counts[key] += 1
                self.trace.append((ready, "in", msg.arbitration_id, ready))
            submit_original(msg, ready, source)

        def run_until(now: float) -> list[tuple[float, can.Message]]:
            out = run_original(now)
            flood = canbus.flood.msg if canbus.flood is not None else None
            for end, msg in out:
                if msg is not flood:
                    self.trace.append((now, "out", msg.arbitration_id, end))
            return out

        emulator._from_host = from_host  # type: ignore[method-assign]
        canbus.submit = submit  # type: ignore[method-assign]
        canbus.run_until = run_until  # type: ignore[method-assign]

    def _remember_sent(self, data: bytes) -> None:
        if self._clean_protocol != self._emulator.protocol:
            self.reset_clean()
        for item in self._clean.feed(data):
            if isinstance(item, AA55Frame):
                self._sent.add(frame_key(item))

    def reset_clean(self) -> None:
        """A new line (replug, protocol switch): the clean decoder starts afresh too."""
        self._clean = host_decoder(self._emulator.protocol)
        self._clean_protocol = self._emulator.protocol

    def take(self) -> dict[str, int]:
        out, self.counts = dict(self.counts), Counter()
        return out

    def between(self, t0: float, t1: float, ids: set[int]) -> list[tuple[float, str, int, float]]:
        return [e for e in self.trace if t0 <= e[0] <= t1 and e[2] in ids]


def _handle(
    emulator: AdapterEmulator, arrivals: _Arrivals, request: dict[str, Any]
) -> dict[str, Any]:
    op = request.pop("op")
    now = emulator.clock()
    with emulator._lock:  # the adapter thread reads all of this
        if op == "stats":
            bus = emulator.canbus
            flood = bus.flood
            return {
                "t": now,
                "frames_from_host": emulator.frames_from_host,
                "frames_to_host": emulator.frames_to_host,
                "frames_filtered": emulator.frames_filtered,
                "bytes_overflowed": emulator.bytes_overflowed,
                "rejected_from_host": sum(emulator.decoder.rejected.values()),
                "plug_count": emulator.plug_count,
                "bus_frames": bus.frames,
                "load_1s": bus.load(now),
                "flood_frames": flood.sent if flood else 0,
                "host_dropped": bus.host_dropped,
                "flipped": emulator.line.flipped,
                "lag": emulator.lag.take(),
                "adapter_error": repr(emulator.error) if emulator.error else None,
            }
        if op == "line":
            seed = int(request.pop("seed", 0))
            emulator.line = LineCorrupter(LineFaults.from_dict(request), seed)
        elif op == "unplug":
            emulator.unplug()
        elif op == "replug":
            emulator.replug()
            arrivals.reset_clean()
        elif op == "servo_faults":
            can_id = int(request.pop("can_id"))
            servo = next(s for s in emulator.servos if s.can_id == can_id)
            servo.faults = dataclasses.replace(servo.faults, **request)
        elif op == "flood":
            emulator.canbus.set_flood(
                request.get("arbitration_id"), now, int(request.get("dlc", 8))
            )
        elif op == "arrivals":
            return {"t": now, "arrivals": arrivals.take()}
        elif op == "wrong":
            return {"t": now, "arrived": arrivals.arrived, "wrong": arrivals.wrong}
        elif op == "trace":
            ids = {int(i) for i in request["ids"]}
            return {"t": now, "trace": arrivals.between(request["t0"], request["t1"], ids)}
        else:
            raise ValueError(f"unknown op {op!r}")
    return {"t": now}


def _servos(args: argparse.Namespace) -> list[SimServo]:
    if args.config:
        from mavservo.sim.servo import simulated_servos

        from ..config.loader import load_config

        return simulated_servos(load_config(args.config), args.bus)
    return [SimServo("rmd-x", i) for i in range(1, args.servos + 1)]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m mavservo.sim.child", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--servos", type=int, default=1)
    parser.add_argument("--config")
    parser.add_argument("--bus", default="bus0")
    parser.add_argument("--bitrate", type=int, default=1_000_000)
    parser.add_argument("--protocol", choices=("variable", "fixed"), default="variable")
    parser.add_argument("--realtime", type=int, default=None, metavar="PRIORITY")
    parser.add_argument("--trace-keep", type=int, default=150_000, help="frames traced")
    parser.add_argument("--max-keys", type=int, default=200_000, help="distinct arrivals kept")
    args = parser.parse_args(argv)
    if args.realtime is not None:  # before the adapter thread exists: it inherits the policy
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(args.realtime))
    emulator = AdapterEmulator(_servos(args), bitrate=args.bitrate, protocol=args.protocol)
    arrivals = _Arrivals(emulator, keep=args.trace_keep, max_keys=args.max_keys)
    emulator.start()
    try:
        print(emulator.path, flush=True)
        for line in sys.stdin:
            try:
                reply = _handle(emulator, arrivals, json.loads(line))
            except Exception as error:  # a bad request is answered, the adapter keeps going
                reply = {"error": repr(error)}
            print(json.dumps(reply), flush=True)
    finally:
        emulator.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
