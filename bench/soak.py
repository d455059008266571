"""Soak run: 16 servos, 50 Hz mirroring, 10 Hz telemetry, faults injected, memory watched.

The Bridge drives 16 RMD-X servos (``bench_faults.bridge_config``: SERVO_OUTPUT_RAW at 50 Hz,
each servo polled at 10 Hz, 20 ms command period). The run alternates windows of
``--window-s`` seconds: clean, line corruption (bit flips at 1e-3 per byte both ways), clean,
a USB unplug of 1 s, clean, one servo silent. Every window records the deltas of the counters
that matter; clean windows are where "no frame loss" and "no missed command slots" are judged.

Two set-ups:

* ``--setup deployed`` (default): the bridge as the production unit runs it
  (deploy/mavservo.service: the whole process SCHED_FIFO 50, ``scheduler.realtime: true``);
  the adapter emulator and its servos run in a child process
  (:class:`mavservo.sim.child.SimulatorProcess`) at SCHED_FIFO 40 and the simulated autopilot
  in another (``python -m mavservo.sim.autopilot stream``) at SCHED_FIFO 30, since real servos,
  adapter and
  autopilot do not share the bridge's CPU or interpreter lock.
* ``--setup in-process``: everything in this process at normal priority (the earlier runs).

Where each missed slot and lost reply comes from (``diagnosis`` in the output): a monitor
thread records when the process stalled (it woke late), ``gc.callbacks`` record collector
pauses, an observer records gaps between command slots and every lost reply, the adapter
records how late it handled bus events (the simulator lagging), and every window records the
run-queue wait of each thread (CPU taken by others) from ``/proc/<pid>/task/*/schedstat``.
Each event is then attributed to what overlapped it. ``start_up`` reports the first seconds
apart: slots missed while ``start()`` ran and in the warm-up before the first window, when the
first command went out (a slot missed before it had nothing to send), and the run-queue wait
of the bridge's threads and of each child over that time.

Resident memory (VmRSS) and the Python heap (tracemalloc, optional) are sampled at every
window boundary: "memory flat" means the last third does not grow beyond the first third.
At every boundary ``processes`` also records, for the bridge's process and each child
(simulator, autopilot), VmRSS, open file descriptors (``/proc/<pid>/fd``) and threads
(``/proc/<pid>/status`` Threads; for the bridge also ``threading.active_count()``), and
``flat_from_s`` says, per process, from when on its RSS (and the heap) never rose more than
1 % above its value then: the time to flat.

    flock /tmp/mavservo-bench.lock python bench/soak.py --minutes 30 > soak.json
"""

from __future__ import annotations

import argparse
import bisect
import gc
import json
import os
import platform
import signal
import sys
import threading
import time
import tracemalloc
from array import array
from collections import Counter
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_faults import DeployedRig, Recorder, bridge_config  # noqa: E402

from mavservo.app.bridge import Bridge  # noqa: E402
from mavservo.config.loader import load_config_text  # noqa: E402
from mavservo.scheduling.runner import SchedulerObserver  # noqa: E402
from mavservo.sim.adapter import LineCorrupter, LineFaults  # noqa: E402

PHASES = ("clean", "line_1e-3", "clean", "unplug", "clean", "servo_silent")
SILENT_ID = 2
COMMAND_PERIOD_S = 0.02
REPLY_TIMEOUT_S = 0.05
FOLLOWED_KEPT = 20
"""Clean-window losses kept in full (their trace excerpts, ~10 kB apiece); every verdict is
counted. Was 300: up to ~3 MB that filled loss by loss, i.e. slowly over a whole run."""
SENDS_KEPT = 3000
"""Sends and decodes kept per servo: 50 s at 60 frames/s, so a clean window's losses can be
followed up to two windows later."""


TRACE_FRAMES_PER_SERVO_S = 120
"""Frames the simulator traces per servo and second: ~60 from the host, ~60 replies."""
SIM_MAX_KEYS = 1000
"""Distinct host frames the simulator counts until it clears them: nobody reads them here
(its default, 200,000 keys, took minutes to fill)."""


def sim_trace_keep(servos: int, window_s: float) -> int:
    """The simulator's trace bound for this soak: a clean window's losses are followed at the
    next window's end, so the trace must reach back two windows (plus 10 s of margin); no
    further, so that the child's memory is full (flat) within about that time."""
    return int(TRACE_FRAMES_PER_SERVO_S * servos * (2 * window_s + 10))


def rss_kib(pid: int | str = "self") -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


def process_figures(pid: int | str = "self") -> dict[str, int]:
    """VmRSS (kB), open file descriptors and OS threads of ``pid``: what a leak shows up in."""
    figures = {"rss_kib": 0, "fds": 0, "threads": 0}
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                figures["rss_kib"] = int(line.split()[1])
            elif line.startswith("Threads:"):
                figures["threads"] = int(line.split()[1])
        figures["fds"] = len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:  # a child that has gone: zeros, the run goes on
        pass
    return figures


def flat_from(samples: list[tuple[float, int]], tolerance: float = 0.01) -> float | None:
    """The first time ``t`` of ``(t, value)`` samples after which the value never rose more
    than ``tolerance`` (a fraction) above its value at ``t``: when memory went flat."""
    highest_after = -1
    flat = None
    for t, value in reversed(samples):
        highest_after = max(highest_after, value)
        if highest_after <= value * (1 + tolerance):
            flat = t
    return flat


def run_queue_wait_s(pid: int | str = "self") -> dict[str, float]:
    """Seconds each thread of ``pid`` spent runnable but not running (CPU taken by others)."""
    names = {t.native_id: t.name for t in threading.enumerate()} if pid == "self" else {}
    out: dict[str, float] = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            waited = int((task / "schedstat").read_text().split()[1]) / 1e9
        except (OSError, IndexError, ValueError):
            continue
        name = names.get(int(task.name), (task / "comm").read_text().strip())
        out[name] = out.get(name, 0.0) + waited
    return out


class Ring:
    """The last ``maxlen`` records, oldest first, in columns allocated in full up front.

    The diagnosis records (every send and decode per servo, every lost reply) used to be deques
    of tuples of float objects: about 100 bytes a record, growing until full, which put the
    harness itself among the top heap growers of its own memory figure for minutes. Columns are
    ``array`` type codes (``"d"`` float, ``"b"``/``"i"`` int) or ``"s"`` for a string from a
    small set (kinds, servo names), stored as an index into a table. Iteration yields tuples,
    or the bare value for a one-column ring (reads like the deque it replaces).
    """

    def __init__(self, maxlen: int, columns: str) -> None:
        self.maxlen = maxlen
        self._columns = columns
        self._arrays = [
            array(
                "H" if code == "s" else code,
                bytes(array("H" if code == "s" else code).itemsize * maxlen),
            )
            for code in columns
        ]
        self._names: list[str] = []
        self._codes: dict[str, int] = {}
        self._next = 0
        self._size = 0

    def _encode(self, code: str, value: Any) -> Any:
        if code != "s":
            return value
        index = self._codes.get(value)
        if index is None:
            index = self._codes[value] = len(self._names)
            self._names.append(value)
        return index

    def append(self, record: Any) -> None:
        values = (record,) if len(self._columns) == 1 else record
        for column, code, value in zip(self._arrays, self._columns, values, strict=True):
            column[self._next] = self._encode(code, value)
        self._next = (self._next + 1) % self.maxlen
        self._size = min(self._size + 1, self.maxlen)

    def extend(self, records: Iterable[Any]) -> None:
        for record in records:
            self.append(record)

    def __len__(self) -> int:
        return self._size

    def __iter__(self) -> Iterator[Any]:
        start = (self._next - self._size) % self.maxlen
        for i in range(self._size):
            j = (start + i) % self.maxlen
            record = tuple(
                self._names[column[j]] if code == "s" else column[j]
                for column, code in zip(self._arrays, self._columns, strict=True)
            )
            yield record[0] if len(record) == 1 else record


class Diagnostics(SchedulerObserver):
    """Time-stamped evidence: process stalls, GC pauses, command-slot gaps, lost replies.

    Observer hooks only append to bounded rings allocated up front (they run inside the
    scheduler's loops, and the soak's memory figure must not measure its own records filling).
    """

    def __init__(self, stall_s: float = 0.005, keep: int = 20_000) -> None:
        self.stall_s = stall_s
        self.stalls = Ring(keep, "dd")  # (end, duration)
        self.gc_pauses = Ring(keep, "ddb")  # (end, s, generation)
        self.missed = Ring(keep, "di")  # (seen at, slots)
        self.lost = Ring(keep, "ds")  # (t, servo)
        self.sent: dict[str, Ring] = {}  # per servo: (t, kind)
        self.received: dict[str, Ring] = {}  # per servo: when its replies were decoded
        self.followed: list[dict[str, Any]] = []
        """The first ``FOLLOWED_KEPT`` clean-window losses followed through the trace (each
        holds the trace excerpt around it, kB apiece: a noisy run must not grow by them)."""
        self.verdicts: Counter[str] = Counter()
        """The verdict of every loss followed, kept or not."""
        self.sim_lag = Ring(keep, "dd")  # (t, lag)
        self.scheduler: Any = None
        """Set to the bridge's scheduler once it exists: its missed-slot count is watched."""
        self.first_command: float | None = None
        """When the first command frame went out: slots missed before it had nothing due."""
        self._gc_start = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="soak-monitor", daemon=True)

    def start(self) -> None:
        gc.callbacks.append(self._on_gc)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(2)
        gc.callbacks.remove(self._on_gc)

    def _on_gc(self, phase: str, info: dict[str, Any]) -> None:
        now = time.monotonic()
        if phase == "start":
            self._gc_start = now
        elif now - self._gc_start > 0.001:
            self.gc_pauses.append((now, now - self._gc_start, info["generation"]))

    def _watch(self) -> None:
        """Every 2 ms: did this thread wake late (the process stalled), did a slot go missed?"""
        period = 0.002
        expected = time.monotonic() + period
        missed = 0
        while not self._stop.wait(max(0.0, expected - time.monotonic())):
            now = time.monotonic()
            if now - expected > self.stall_s:
                self.stalls.append((now, now - expected))
            expected = now + period
            if self.scheduler is not None:
                count = self.scheduler.metrics_store.missed_command_slots
                if count > missed:
                    self.missed.append((now, count - missed))
                missed = count

    def on_tx(self, bus: str, msg: Any, t: float, kind: str, servo: str, seq: Any) -> None:
        # 50 s per servo: a window's losses are followed up to two windows later
        sent = self.sent.get(servo)
        if sent is None:
            sent = self.sent[servo] = Ring(SENDS_KEPT, "ds")
        sent.append((t, kind))
        if self.first_command is None and kind == "command":
            self.first_command = t

    def on_rx(self, bus: str, msg: Any, t: float, servo: str, state: Any) -> None:
        received = self.received.get(servo)
        if received is None:
            received = self.received[servo] = Ring(SENDS_KEPT, "d")  # 50 s, like sends
        received.append(t)

    def on_lost(self, bus: str, servo: str, t: float) -> None:
        self.lost.append((t, servo))

    def follow_losses(
        self, start: float, end: float, trace: Any, limit: int = 50
    ) -> list[dict[str, Any]]:
        """Follow each reply lost in ``[start, end)`` through the simulator's trace: did the
        frame reach the adapter, did the servo's reply leave it, when? ``trace(t0, t1, ids)``."""
        out = []
        for t_lost, servo in [e for e in self.lost if start <= e[0] < end][:limit]:
            can_id = int(servo.lstrip("s"))
            # the scheduler declares a loss at its first step after send + timeout
            sends = [
                (t, kind)
                for t, kind in self.sent.get(servo, ())
                if t_lost - 0.5 <= t <= t_lost - REPLY_TIMEOUT_S
            ][-3:]
            events = trace(t_lost - 0.15, t_lost + 0.3, [0x140 + can_id, 0x240 + can_id])
            t_send = sends[-1][0] if sends else None
            into = [e for e in events if e[1] == "in" and t_send is not None and e[0] >= t_send]
            outs = [e for e in events if e[1] == "out" and into and e[0] >= into[0][0]]
            if t_send is None:
                verdict = "no send found"
            elif not into or into[0][0] - t_send > REPLY_TIMEOUT_S:
                verdict = "frame did not reach the adapter in time"
            elif not outs:
                verdict = "servo sent no reply"
            elif outs[0][0] - t_send > REPLY_TIMEOUT_S:
                verdict = "simulator handed the reply over late"
            else:
                verdict = "reply left the adapter in time, the bridge missed its deadline"
            out.append(
                {
                    "t": round(t_lost, 3),
                    "servo": servo,
                    "sends": [(round(t - t_lost, 4), k) for t, k in sends],
                    # when the bridge decoded replies of this servo around the loss
                    "host_rx": [
                        round(t - t_lost, 4)
                        for t in self.received.get(servo, ())
                        if t_lost - 0.15 <= t <= t_lost + 0.1
                    ],
                    "sim": [(round(e[0] - t_lost, 4), e[1], hex(e[2])) for e in events],
                    "to_adapter_ms": None
                    if not into or t_send is None
                    else round((into[0][0] - t_send) * 1e3, 2),
                    "reply_out_ms": None
                    if not outs or t_send is None
                    else round((outs[0][0] - t_send) * 1e3, 2),
                    "verdict": verdict,
                }
            )
        return out

    def keep_followed(self, followed: list[dict[str, Any]]) -> None:
        """Count every verdict; keep the first ``FOLLOWED_KEPT`` losses in full."""
        self.verdicts.update(f["verdict"] for f in followed)
        self.followed += followed[: max(0, FOLLOWED_KEPT - len(self.followed))]

    def attribute(self, start: float, end: float, min_s: float = 0.005) -> str:
        """What else happened in ``[start, end]``: the first cause found, by weight."""

        def overlaps(events: Any, pad: float = 0.0) -> bool:
            return any(
                e_end - dur <= end and e_end + pad >= start and dur >= min_s
                for e_end, dur, *_ in events
            )

        if overlaps(self.gc_pauses):
            return "gc_pause"
        if overlaps(self.sim_lag):
            return "simulator_lag"
        if overlaps(self.stalls):
            return "process_stall"
        return "unexplained"

    def start_up(
        self, t_start: float, t_started: float, warm_up_end: float, missed_at_start: int
    ) -> dict[str, Any]:
        """The start-up figures, in seconds from the call of ``start()`` (``t_start``): how long
        it took, the slots missed meanwhile and in the warm-up after it, when the first command
        went out (slots missed before it had nothing to send), stalls and collector pauses."""

        def worst(events: Any) -> float:
            durations = [e[1] for e in events if t_start <= e[0] - e[1] and e[0] <= warm_up_end]
            return round(max(durations, default=0.0) * 1e3, 2)

        return {
            "start_call_s": round(t_started - t_start, 4),
            "missed_slots_during_start": missed_at_start,
            "missed_slots_warm_up": [
                (round(t - t_start, 4), n) for t, n in self.missed if t < warm_up_end
            ],
            "first_command_s": None
            if self.first_command is None
            else round(self.first_command - t_start, 4),
            "stall_max_ms": worst(self.stalls),
            "gc_pause_max_ms": worst(self.gc_pauses),
        }

    def report(self, windows: list[dict[str, Any]]) -> dict[str, Any]:
        """Every slot gap and lost reply with its cause and its window's phase."""
        starts = [w["t0"] for w in windows]

        def phase(t: float) -> str:
            i = window_at(starts, t)
            return windows[i]["phase"] if i >= 0 else "warm-up"

        def into(t: float) -> float:
            i = window_at(starts, t)
            return round(t - starts[i], 3) if i >= 0 else 0.0

        # a missed slot means the command thread woke at least one period late: look at the
        # (slots + 1) periods before the monitor saw it
        gaps = [
            {
                "t": round(t, 3),
                "slots": n,
                "phase": phase(t),
                "into_window_s": into(t),
                "cause": self.attribute(t - (n + 1) * COMMAND_PERIOD_S - 0.002, t),
            }
            for t, n in self.missed
        ]
        lost = [
            {
                "t": round(t, 3),
                "servo": s,
                "phase": phase(t),
                "into_window_s": into(t),
                "cause": self.attribute(t - REPLY_TIMEOUT_S, t),
            }
            for t, s in self.lost
        ]
        tally: dict[str, dict[str, int]] = {}
        for kind, events in (("missed_slots", gaps), ("lost", lost)):
            for e in events:
                bucket = tally.setdefault(f"{kind}_{e['phase']}", {})
                bucket[e["cause"]] = bucket.get(e["cause"], 0) + e.get("slots", 1)
        return {
            "causes": tally,
            "missed_slots": gaps[:300],
            "lost_clean": [e for e in lost if e["phase"] == "clean"][:300],
            "gc_pauses_over_5ms": sum(1 for _, d, _ in self.gc_pauses if d > 0.005),
            "gc_pause_max_ms": round(max((d for _, d, _ in self.gc_pauses), default=0) * 1e3, 2),
            "stalls_over_5ms": len(self.stalls),
            "stall_max_ms": round(max((d for _, d in self.stalls), default=0) * 1e3, 2),
            "sim_lag_spikes_over_5ms": len(self.sim_lag),
            "clean_losses_followed": self.followed,
            "clean_loss_verdicts": dict(self.verdicts),
        }


class InProcess:
    """The earlier set-up: the bridge builds the emulator and autopilot in this process."""

    name = "in-process"

    def __init__(self, servos: int, observer: SchedulerObserver, window_s: float) -> None:
        self.bridge = Bridge(
            load_config_text(bridge_config(servos, "variable")), log_dir=False, observers=[observer]
        )

    def start(self) -> None:
        self.bridge.start()
        self.emulator = self.bridge.emulators["bus0"]
        self.clean_line = self.emulator.line
        self.recorder = Recorder(self.bridge, self.emulator)

    def commands(self) -> tuple[int, int]:
        return self.recorder.arrived, self.recorder.wrong_count

    def set_phase(self, phase: str, seed: int) -> None:
        em = self.emulator
        with em._lock:
            if phase == "line_1e-3":
                em.line = LineCorrupter(LineFaults(flip_prob=1e-3, direction="both"), seed=seed)
            elif phase == "servo_silent":
                next(s for s in em.servos if s.can_id == SILENT_ID).faults.silent = True
        if phase == "unplug":
            em.unplug()
            time.sleep(1.0)
            em.replug()

    def clear_phase(self) -> None:
        with self.emulator._lock:
            self.emulator.line = self.clean_line
            next(s for s in self.emulator.servos if s.can_id == SILENT_ID).faults.silent = False

    def poll(self, diagnostics: Diagnostics, follow: tuple[float, float] | None) -> dict[str, Any]:
        with self.emulator._lock:
            lag = self.emulator.lag.take()
        diagnostics.sim_lag.extend(lag["spike_times"])
        return {"sim_lag_max_ms": round(lag["max_s"] * 1e3, 2)}

    def stop(self) -> dict[str, Any]:
        return self.bridge.stop()

    def child_pids(self) -> dict[str, int]:
        return {}


class Deployed:
    """The bridge as deployed (:class:`bench_faults.DeployedRig`) with the soak's faults."""

    name = "deployed"

    def __init__(self, servos: int, observer: SchedulerObserver, window_s: float) -> None:
        self.rig = DeployedRig(
            servos,
            observers=[observer],
            sim_trace_keep=sim_trace_keep(servos, window_s),
            sim_max_keys=SIM_MAX_KEYS,
        )
        self.sim = self.rig.sim
        self.bridge = self.rig.bridge

    def start(self) -> None:
        self.rig.start()
        # The bridge's threads keep SCHED_FIFO (inherited); this thread, the soak's own
        # bookkeeping at the window boundaries, goes back to normal priority so that it
        # cannot hold the CPU against them (the first 30-minute run lost slots to it).
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))

    def commands(self) -> tuple[int, int]:
        return self.rig.commands()

    def set_phase(self, phase: str, seed: int) -> None:
        if phase == "line_1e-3":
            self.sim.request("line", flip_prob=1e-3, direction="both", seed=seed)
        elif phase == "servo_silent":
            self.sim.request("servo_faults", can_id=SILENT_ID, silent=True)
        elif phase == "unplug":
            self.sim.request("unplug")
            time.sleep(1.0)
            self.sim.request("replug")

    def clear_phase(self) -> None:
        self.sim.request("line")
        self.sim.request("servo_faults", can_id=SILENT_ID, silent=False)

    def poll(self, diagnostics: Diagnostics, follow: tuple[float, float] | None) -> dict[str, Any]:
        if follow is not None:

            def trace(t0: float, t1: float, ids: list[int]) -> list[Any]:
                return self.sim.request("trace", t0=t0, t1=t1, ids=ids)["trace"]

            try:
                diagnostics.keep_followed(diagnostics.follow_losses(*follow, trace))
            except Exception as error:  # diagnosis must never end a 30-minute run
                diagnostics.keep_followed([{"verdict": f"follow failed: {error!r}"}])
        stats = self.sim.request("stats")
        diagnostics.sim_lag.extend(tuple(x) for x in stats["lag"]["spike_times"])
        keys = ("frames_to_host", "bytes_overflowed", "rejected_from_host", "host_dropped")
        last, self._last_stats = getattr(self, "_last_stats", {}), stats
        return {
            **{f"sim_{k}": stats[k] - last.get(k, 0) for k in keys},
            "sim_lag_max_ms": round(stats["lag"]["max_s"] * 1e3, 2),
            "sim_run_queue_wait_s": round(sum(run_queue_wait_s(self.sim.process.pid).values()), 3),
            "sim_rss_kib": rss_kib(self.sim.process.pid),
        }

    def stop(self) -> dict[str, Any]:
        return self.rig.stop()

    def child_pids(self) -> dict[str, int]:
        """The simulator and autopilot children, whose run-queue waits the start-up report shows."""
        return {"simulator": self.sim.process.pid, "autopilot": self.rig.autopilot.pid}


def counters(bridge: Bridge, setup: InProcess | Deployed) -> dict[str, int]:
    """The figures a window is judged by. Read from the scheduler's counters directly, not
    ``bridge.summary()``: that computes every percentile under the scheduler's lock, which
    would itself delay the command loop at every window boundary."""
    store = bridge.schedulers["bus0"].metrics_store
    servos = list(store.servos.values())
    arrived, wrong = setup.commands()
    return {
        "missed_command_slots": int(store.missed_command_slots),
        "sent": sum(s.commands_sent + s.refreshes_sent + s.requests_sent for s in servos),
        "received": sum(s.received for s in servos),
        "lost": sum(s.lost for s in servos),
        "late": sum(s.late_replies for s in servos),
        "rejected_replies": sum(s.rejected for s in servos),
        "rejected_bytes": int(bridge.buses["bus0"].stats().get("bytes_discarded", 0)),
        "commands_arrived": arrived,
        "wrong_commands": wrong,
    }


def window_at(starts: list[float], t: float) -> int:
    """Index of the window (by start times, ascending) that ``t`` falls in; -1 before the first."""
    return bisect.bisect_right(starts, t) - 1


def delta(after: dict[str, int], before: dict[str, int]) -> dict[str, int]:
    return {k: after[k] - before[k] for k in after}


def lost_by_request_time(
    windows: list[dict[str, Any]], lost: Iterable[tuple[float, str]], window_s: float
) -> None:
    """Add ``lost_by_request`` to each window: its losses counted where the request went out.

    The scheduler declares a loss at its deadline, ``REPLY_TIMEOUT_S`` after the request (plus
    up to one step), so the counter puts the last ~50 ms of a faulty window's losses (a silent
    servo's last polls) into the next window. The window a loss belongs to is the one its
    request was sent in.
    """
    starts = [w["t0"] for w in windows]
    ends = starts[1:] + [starts[-1] + window_s] if starts else []
    for w in windows:
        w["lost_by_request"] = 0
    for t, _servo in lost:
        sent = t - REPLY_TIMEOUT_S
        i = window_at(starts, sent)
        if i >= 0 and sent < ends[i]:
            windows[i]["lost_by_request"] += 1


def baseline_due(args: argparse.Namespace, index: int, memory: list[Any]) -> bool:
    """Is this window boundary (``memory[-1]``) where the heap baseline is taken?"""
    if args.heap_baseline_s is None:
        return index == len(args.phases) - 1  # after one full cycle of phases
    return memory[-1][0] >= args.heap_baseline_s


def heap_growth(
    baseline: tracemalloc.Snapshot, t0: float | None, t1: float, frames: int
) -> dict[str, Any]:
    """The top growers of the heap from the baseline to now, by line and (with more than one
    frame traced) by traceback: where memory still grows once the stores are full."""
    snapshot = tracemalloc.take_snapshot()
    out: dict[str, Any] = {
        "from_s": t0,
        "to_s": t1,
        "by_line": [str(stat) for stat in snapshot.compare_to(baseline, "lineno")[:12]],
    }
    if frames > 1:
        out["by_traceback"] = [
            {"stat": str(stat), "traceback": stat.traceback.format()}
            for stat in snapshot.compare_to(baseline, "traceback")[:6]
        ]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=30.0)
    parser.add_argument("--window-s", type=float, default=20.0)
    parser.add_argument("--servos", type=int, default=16)
    parser.add_argument("--setup", choices=("deployed", "in-process"), default="deployed")
    parser.add_argument(
        "--phases",
        nargs="+",
        choices=sorted(set(PHASES)),
        default=PHASES,
        help="the cycle of windows (default: %(default)s)",
    )
    parser.add_argument("--tracemalloc", action="store_true", help="also sample the Python heap")
    parser.add_argument(
        "--heap-baseline-s",
        type=float,
        default=None,
        help="with --tracemalloc: take the heap baseline at the first window boundary after "
        "this many seconds (default: after the first cycle of phases); top growers are "
        "against it",
    )
    parser.add_argument(
        "--tracemalloc-frames",
        type=int,
        default=1,
        help="frames per traceback: >1 also lists growers by their callers",
    )
    args = parser.parse_args()
    # SIGTERM ends the run through the finally below: children stopped, figures printed
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(1))
    if args.tracemalloc:
        tracemalloc.start(args.tracemalloc_frames)
    diagnostics = Diagnostics()
    kind = Deployed if args.setup == "deployed" else InProcess
    setup = kind(args.servos, diagnostics, args.window_s)
    bridge = setup.bridge
    diagnostics.start()
    pids = {"bridge": 0, **setup.child_pids()}  # 0: this process

    def waits() -> dict[str, dict[str, float]]:
        return {name: run_queue_wait_s(pid or "self") for name, pid in pids.items()}

    waited_at = waits()
    t_start = time.monotonic()
    setup.start()
    started = time.monotonic()
    diagnostics.scheduler = bridge.schedulers["bus0"]
    missed_at_start = int(diagnostics.scheduler.metrics_store.missed_command_slots)
    end = started + args.minutes * 60
    windows: list[dict[str, Any]] = []
    memory: list[tuple[float, int, int]] = []
    processes: list[dict[str, Any]] = []

    def sample_processes(t: float) -> None:
        row: dict[str, Any] = {"t_s": round(t, 1)}
        for name, pid in pids.items():
            row[name] = process_figures(pid or "self")
        row["bridge"]["py_threads"] = threading.active_count()
        processes.append(row)

    sample_processes(time.monotonic() - started)
    index = 0
    baseline: tracemalloc.Snapshot | None = None
    baseline_t: float | None = None
    start_up: dict[str, Any] = {}
    try:
        time.sleep(2.0)  # servos come online
        warm_up_end = time.monotonic()
        start_up = diagnostics.start_up(t_start, started, warm_up_end, missed_at_start)
        # CPU taken from each thread by others (run-queue wait), from before start() to here
        start_up["run_queue_wait_s"] = {
            name: {
                thread: round(s - waited_at[name].get(thread, 0.0), 4)
                for thread, s in now.items()
                if s - waited_at[name].get(thread, 0.0) >= 0.001
            }
            for name, now in waits().items()
        }
        setup.poll(diagnostics, None)  # counters start afresh
        follow: tuple[float, float] | None = None
        while time.monotonic() + args.window_s <= end:
            phase = args.phases[index % len(args.phases)]
            before = counters(bridge, setup)
            waited_before = run_queue_wait_s()
            t0 = time.monotonic()
            setup.set_phase(phase, seed=index)
            time.sleep(max(0.0, args.window_s - (time.monotonic() - t0)))
            setup.clear_phase()
            extra = setup.poll(diagnostics, follow)
            # a clean window's losses are followed at the next poll, once all are declared
            follow = (t0, time.monotonic()) if phase == "clean" else None
            waited = {
                k: round(v - waited_before.get(k, 0.0), 4) for k, v in run_queue_wait_s().items()
            }
            windows.append(
                {
                    "phase": phase,
                    "t_s": round(t0 - started, 1),
                    "t0": t0,
                    **delta(counters(bridge, setup), before),
                    **extra,
                    "run_queue_wait_s": {k: v for k, v in waited.items() if v >= 0.001},
                }
            )
            heap = tracemalloc.get_traced_memory()[0] if args.tracemalloc else 0
            memory.append((round(time.monotonic() - started, 1), rss_kib(), heap))
            sample_processes(time.monotonic() - started)
            if args.tracemalloc and baseline is None and baseline_due(args, index, memory):
                baseline = tracemalloc.take_snapshot()
                baseline_t = memory[-1][0]
            index += 1
        growth: dict[str, Any] = {}
        if baseline is not None:
            growth = heap_growth(baseline, baseline_t, memory[-1][0], args.tracemalloc_frames)
    finally:
        summary = setup.stop()
        diagnostics.stop()
    lost_by_request_time(windows, diagnostics.lost, args.window_s)
    clean = [w for w in windows if w["phase"] == "clean"]
    third = max(1, len(memory) // 3)
    out = {
        "machine": f"{platform.machine()} python {platform.python_version()}",
        "setup": setup.name,
        "realtime": summary["buses"]["bus0"].get("realtime")
        or bridge.schedulers["bus0"].realtime_status,
        "minutes_requested": args.minutes,
        "seconds_run": round(time.monotonic() - started, 1),
        "servos": args.servos,
        "by_phase": {
            p: {
                k: sum(w[k] for w in windows if w["phase"] == p)
                for k in (
                    "sent",
                    "lost",
                    "lost_by_request",
                    "late",
                    "missed_command_slots",
                    "wrong_commands",
                )
            }
            | {"windows": sum(1 for w in windows if w["phase"] == p)}
            for p in dict.fromkeys(args.phases)
        },
        "rss_kib_first_third_max": max(m[1] for m in memory[:third]) if memory else None,
        "rss_kib_last_third_max": max(m[1] for m in memory[-third:]) if memory else None,
        "clean_windows": {
            "count": len(clean),
            "lost": sum(w["lost"] for w in clean),
            "lost_by_request": sum(w["lost_by_request"] for w in clean),
            "late": sum(w["late"] for w in clean),
            "missed_command_slots": sum(w["missed_command_slots"] for w in clean),
            "frames_sent": sum(w["sent"] for w in clean),
        },
        "wrong_commands_total": sum(w["wrong_commands"] for w in windows),
        "missed_command_slots_total": summary["buses"]["bus0"]["missed_command_slots"],
        "start_up": start_up,
        "diagnosis": diagnostics.report(windows),
        "windows": windows,
        "memory_samples": memory,
        "flat_from_s": {
            **{
                f"{name}_rss": flat_from([(p["t_s"], p[name]["rss_kib"]) for p in processes])
                for name in pids
            },
            "bridge_heap": flat_from([(t, heap) for t, _, heap in memory])
            if args.tracemalloc
            else None,
        },
        "processes": {
            "first": processes[0] if processes else None,
            "last": processes[-1] if processes else None,
            "samples": processes,
        },
        "heap_growth_top": growth,
        "events": summary.get("events", []),
    }
    print(json.dumps(out, indent=1, default=str))


if __name__ == "__main__":
    main()
