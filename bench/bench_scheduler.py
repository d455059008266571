"""Scheduler timing and CPU cost on a simulated bus (issue 4's benchmark), run by hand.

    PYTHONPATH=. python bench/bench_scheduler.py --seconds 60            # idle, real pty path
    PYTHONPATH=. python bench/bench_scheduler.py --seconds 60 --hog      # a busy loop per core
    PYTHONPATH=. python bench/bench_scheduler.py --transport virtual     # in-process bus
    PYTHONPATH=. python bench/bench_scheduler.py --cpu-only --seconds 20 # CPU %, 8 and 32 servos
    PYTHONPATH=. python bench/bench_scheduler.py --profile rmd-x,damiao-dm,cubemars-ak-mit,odrive \
        --runs 3 --seconds 30                                            # a row per family

``--profile`` takes one servo family or several (comma-separated): every servo of a run is of
one family, and with several families each run goes round all of them in turn, so each family
is measured alongside the first one (RMD-X by default: the baseline) on the same machine state.

"pty" runs the full host path: the project's ``aa55`` python-can bus over pyserial on a pty,
with the USB-CAN adapter emulator and simulated RMD-X servos on the other end. Setpoints change
every command period (a slow sine per servo), so every slot carries new commands.

Reports: command period sigma and p99 |deviation|, missed slots, telemetry interval
distribution (and the share in 70-100 ms, the paper's figure), L and sigma_L (eqs. 3, 5),
measured R (eq. 4) and the CPU the scheduler's two threads used, as % of one core.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import can

from mavservo.scheduling.runner import Scheduler, SchedulerObserver, ServoSpec, TimingConfig
from mavservo.servos import ServoProfile, get_profile
from mavservo.sim.servo import SimServo

_POLL_REPLIES = (0x9C, 0x9A, 0x92)  # RMD-X status 2, faults, multi-turn angle: answers to polls
_BURST_GAP_S = 0.0005  # frames written closer together than this came from one scheduler step


class IntervalTracer(SchedulerObserver):
    """Records every write and every decoded reply, to take telemetry intervals apart.

    A reception interval is the poll schedule's interval plus the change in reply latency:
    ``rx_k - rx_(k-1) = (tx_k - tx_(k-1)) + (lat_k - lat_(k-1))``. Knowing what else went out in
    the same step as each request (commands ahead of it, its place in the poll round) says which
    of the two moved, and why. Appends only (non-blocking, as the observer contract asks).
    """

    def __init__(self) -> None:
        self.tx: list[tuple[float, str, str]] = []
        self.rx: list[tuple[float, str, int, float]] = []

    def on_tx(self, bus, msg, t, kind, servo, seq) -> None:  # noqa: ANN001
        self.tx.append((t, kind, servo))

    def on_rx(self, bus, msg, t, servo, state) -> None:  # noqa: ANN001
        self.rx.append((t, servo, msg.data[0] if msg.data else -1, msg.timestamp))


class CommandFrameCounter(SchedulerObserver):
    """Counts the command and refresh frames written (frames per slot: a DroneCAN bus packs
    every servo's command into shared multi-frame transfers), passing every hook on to
    ``inner`` (the tracer, when asked for)."""

    def __init__(self, inner: SchedulerObserver | None) -> None:
        self.inner = inner
        self.frames = 0

    def on_tx(self, bus, msg, t, kind, servo, seq) -> None:  # noqa: ANN001
        if kind in ("command", "refresh"):
            self.frames += 1
        if self.inner is not None:
            self.inner.on_tx(bus, msg, t, kind, servo, seq)

    def on_rx(self, bus, msg, t, servo, state) -> None:  # noqa: ANN001
        if self.inner is not None:
            self.inner.on_rx(bus, msg, t, servo, state)


def _p99(values: list[float]) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))] if ordered else math.nan


def interval_breakdown(
    tracer: IntervalTracer, nominal: float, threshold: float = 0.002
) -> dict[str, Any]:
    """Split telemetry reception intervals into schedule (tx) and reply path (latency) parts.

    For each request: how many command frames the same step wrote before it (a telemetry tick
    that fell on a command slot) and its position among the step's requests (the poll round
    order). Intervals whose deviation exceeds ``threshold`` are attributed to the first cause
    that explains them: one of the two requests queued behind a slot's commands
    (``slot_collision``), its place in the round changed (``round_order``), the request's send
    time moved for another reason (``schedule``: a late wake-up), else the reply path
    (``reply_path``: pty, simulator, receive thread). ``outlier_rounds`` counts the poll rounds
    the outliers fell in: a stall of the whole machine shows as few rounds with every servo.
    """
    polls: dict[str, list[dict[str, float]]] = {}
    burst_commands = burst_requests = 0
    last_t = -math.inf
    for t, kind, servo in tracer.tx:
        if t - last_t > _BURST_GAP_S:
            burst_commands = burst_requests = 0
        last_t = t
        if kind == "request":
            polls.setdefault(servo, []).append(
                {"tx": t, "commands_ahead": burst_commands, "position": burst_requests}
            )
            burst_requests += 1
        else:
            burst_commands += 1
    # wall-clock stamp of the bus read vs monotonic stamp of the decode: the receive hand-over
    offsets = [t - wall for t, _servo, _cmd, wall in tracer.rx]
    base = min(offsets) if offsets else 0.0
    handover = [o - base for o in offsets]
    replies: dict[str, list[float]] = {}
    for t, servo, cmd, _wall in tracer.rx:
        if cmd in _POLL_REPLIES:
            replies.setdefault(servo, []).append(t)
    causes = {"schedule": 0, "slot_collision": 0, "round_order": 0, "reply_path": 0}
    tx_dev: list[float] = []
    lat_delta: list[float] = []
    rx_dev: list[float] = []
    lat_by_commands: dict[str, list[float]] = {"0": [], ">0": []}
    outlier_ticks: set[int] = set()  # which poll rounds the outliers came from
    for servo, reqs in polls.items():
        got = replies.get(servo, [])
        paired = []
        j = 0
        for i, req in enumerate(reqs):  # one request outstanding at a time: match in order
            next_tx = reqs[i + 1]["tx"] if i + 1 < len(reqs) else math.inf
            while j < len(got) and got[j] < req["tx"]:
                j += 1
            if j < len(got) and got[j] < next_tx:
                paired.append({**req, "rx": got[j], "lat": got[j] - req["tx"]})
                lat_by_commands["0" if not req["commands_ahead"] else ">0"].append(
                    got[j] - req["tx"]
                )
                j += 1
            else:
                paired.append({})  # lost: breaks the chain
        for a, b in zip(paired, paired[1:], strict=False):
            if not a or not b:
                continue
            d_tx = b["tx"] - a["tx"] - nominal
            d_lat = b["lat"] - a["lat"]
            dev = b["rx"] - a["rx"] - nominal
            tx_dev.append(abs(d_tx))
            lat_delta.append(abs(d_lat))
            rx_dev.append(abs(dev))
            if abs(dev) <= threshold:
                continue
            outlier_ticks.add(round((b["tx"] - b["position"] * 1e-4) / nominal))
            if a["commands_ahead"] or b["commands_ahead"]:
                causes["slot_collision"] += 1
            elif a["position"] != b["position"]:
                causes["round_order"] += 1
            elif abs(d_tx) > threshold / 2:
                causes["schedule"] += 1
            else:
                causes["reply_path"] += 1
    ms = 1e3
    return {
        "intervals": len(rx_dev),
        "rx_p99_dev_ms": _p99(rx_dev) * ms,
        "tx_p99_dev_ms": _p99(tx_dev) * ms,
        "latency_change_p99_ms": _p99(lat_delta) * ms,
        "poll_latency_p50_ms_no_cmds_ahead": _p99_or(lat_by_commands["0"], 0.5) * ms,
        "poll_latency_p50_ms_cmds_ahead": _p99_or(lat_by_commands[">0"], 0.5) * ms,
        "share_polls_behind_commands": len(lat_by_commands[">0"])
        / max(1, len(lat_by_commands["0"]) + len(lat_by_commands[">0"])),
        "rx_handover_p99_ms": _p99(handover) * ms,
        f"over_{threshold * ms:g}ms": sum(causes.values()),
        "causes": causes,
        "outlier_rounds": len(outlier_ticks),
        "outlier_servos_per_round": sum(causes.values()) / max(1, len(outlier_ticks)),
    }


def _p99_or(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[int(q * (len(ordered) - 1))] if ordered else math.nan


def start_hogs() -> list[subprocess.Popen]:
    """One busy-looping process per core (killed by pid at the end)."""
    count = os.cpu_count() or 1
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(count)]


class RealtimeKworkers:
    """Keep the kernel's worker threads (``kworker/*``) at SCHED_FIFO 1 while it runs.

    Why: bytes written into a tty (a pty here, a USB-serial adapter on the drone) reach the
    reader through the tty flip-buffer work, which the kernel runs in a normal-priority kworker.
    Under a CPU hog that worker waits its fair share, and a whole round of replies arrives
    late together even though the writer and the reader are both SCHED_FIFO. Workers come and
    go, so the policy is re-applied every half second; it is restored at the end.
    """

    def __init__(self) -> None:
        self._stop = threading.Event()
        self._changed: set[int] = set()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> RealtimeKworkers:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5)
        for pid in self._changed:
            with contextlib.suppress(OSError):  # the worker may have exited
                os.sched_setscheduler(pid, os.SCHED_OTHER, os.sched_param(0))

    def _run(self) -> None:
        while not self._stop.is_set():
            for entry in Path("/proc").iterdir():
                if not entry.name.isdigit():
                    continue
                try:
                    if not (entry / "comm").read_text().startswith("kworker"):
                        continue
                    pid = int(entry.name)
                    if os.sched_getscheduler(pid) != os.SCHED_FIFO:
                        os.sched_setscheduler(pid, os.SCHED_FIFO, os.sched_param(1))
                        self._changed.add(pid)
                except OSError:
                    continue  # gone, or not ours to change
            self._stop.wait(0.5)


def stop_hogs(hogs: list[subprocess.Popen]) -> None:
    for hog in hogs:
        hog.kill()
        hog.wait(5)


def bench_profile(name: str, can_id: int) -> ServoProfile:
    """Servo ``can_id`` of family ``name`` as the bench drives it.

    Families that answer on a shared master id (Damiao, CubeMars MIT) get one master id per
    servo, so any number of them can share the bus without one claiming another's replies;
    DroneCAN servos (one ArrayCommand for all) one actuator id each.
    """
    profile_class = get_profile(name)
    fields = profile_class.Options.model_fields
    if "master_id" in fields:
        return profile_class(can_id, master_id=0x80 + can_id)
    if "actuator_id" in fields:
        return profile_class(can_id, actuator_id=can_id)
    return profile_class(can_id)


SIM_PUSH_HZ = 50.0
"""The rate push-style simulated servos report at; the scheduler is told the same, so its
liveness rule and its worst-case budget (R_worst_case) count the pushes that really come."""


def simulated_servos(name: str, n_servos: int) -> list[SimServo]:
    return [
        SimServo(name, i, options=bench_profile(name, i).options, status_rate_hz=SIM_PUSH_HZ)
        for i in range(1, n_servos + 1)
    ]


def bench_spec(name: str, can_id: int) -> ServoSpec:
    """The scheduler's view of bench servo ``can_id``: a push-style one pushes at SIM_PUSH_HZ."""
    profile = bench_profile(name, can_id)
    pushed = profile.telemetry == "pushed"
    return ServoSpec(f"s{can_id}", profile, telemetry_hz=SIM_PUSH_HZ if pushed else None)


def serve_simulator(n_servos: int, bitrate: int, realtime: bool, profile: str) -> None:
    """Child-process mode: run the adapter emulator, print its port, live until stdin closes.

    Real servos are not inside the bridge's process; keeping the simulator out of it keeps its
    work from competing with the scheduler for the interpreter lock.
    """
    from mavservo.sim.adapter import AdapterEmulator

    if realtime:  # hardware does not share our CPU: keep the hog from starving the servos
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(30))
    sims = simulated_servos(profile, n_servos)
    emulator = AdapterEmulator(sims, bitrate=bitrate).start()
    print(emulator.path, flush=True)
    sys.stdin.read()
    emulator.stop()


class _ChildSimulator:
    def __init__(self, n_servos: int, bitrate: int, realtime: bool, profile: str) -> None:
        self.process = subprocess.Popen(
            [
                sys.executable,
                __file__,
                "--serve-sim",
                str(n_servos),
                "--profile",
                profile,
                "--bitrate",
                str(bitrate),
                *(["--realtime"] if realtime else []),
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
        )
        assert self.process.stdout is not None
        self.path = self.process.stdout.readline().strip()

    def stop(self) -> None:
        assert self.process.stdin is not None
        self.process.stdin.close()
        self.process.wait(10)


class Transport:
    """Opens the host-side bus and the simulated servos behind it."""

    def __init__(
        self,
        kind: str,
        n_servos: int,
        bitrate: int,
        in_process: bool,
        realtime: bool,
        profile: str = "rmd-x",
    ) -> None:
        self.kind = kind
        self.sims = simulated_servos(profile, n_servos)
        if kind == "pty":
            from mavservo.sim.adapter import AdapterEmulator
            from mavservo.transport.aa55.bus import AA55Bus

            if in_process:
                self.device = AdapterEmulator(self.sims, bitrate=bitrate).start()
            else:
                self.device = _ChildSimulator(n_servos, bitrate, realtime, profile)
            self.bus: can.BusABC = AA55Bus(self.device.path, bitrate=bitrate)
        else:
            from mavservo.sim.virtual import VirtualServoBus

            channel = f"bench-{os.getpid()}"
            self.device = VirtualServoBus(self.sims, channel=channel, bitrate=bitrate).start()
            self.bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)

    def close(self) -> None:
        self.bus.shutdown()
        self.device.stop()


def run_once(
    args: argparse.Namespace, n_servos: int, seconds: float, profile: str = "rmd-x"
) -> dict[str, Any]:
    timing = TimingConfig(
        command_period_s=args.command_period,
        telemetry_period_s=args.telemetry_period,
        bitrate=args.bitrate,
        max_load=0.8,
        realtime=args.realtime,
        spin_s=args.spin,
        fifo_spin_s=args.fifo_spin,
        telemetry_phase_s=args.telemetry_phase,
    )
    transport = Transport(
        args.transport, n_servos, args.bitrate, args.sim_in_process, args.realtime, profile
    )
    specs = [bench_spec(profile, i) for i in range(1, n_servos + 1)]
    tracer = IntervalTracer() if args.breakdown else None
    counter = CommandFrameCounter(tracer)
    scheduler = Scheduler(transport.bus, specs, timing, name=args.transport, observer=counter)
    if args.realtime:
        # The setpoint driver shares the interpreter lock with the scheduler: left at normal
        # priority, a hog can preempt it while it holds the GIL and stall the command loop
        # (priority inversion), so with --realtime the whole process runs SCHED_FIFO, as
        # `chrt -f` would do for the bridge.
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(40))
        except OSError as exc:
            print(f"driver thread stays at normal priority: {exc!r}", file=sys.stderr)
    cpu_before = time.process_time()
    try:
        scheduler.start()
        started = time.monotonic()
        next_update = started
        # drive setpoints from this thread like the MAVLink layer would: bounded by time
        while (now := time.monotonic()) - started < seconds:
            for i, spec in enumerate(specs):
                angle = 30.0 * math.sin(2 * math.pi * 0.2 * (now - started) + i)
                scheduler.set_setpoint(spec.name, angle, "bench")
            next_update += timing.command_period_s
            time.sleep(max(0.0, next_update - time.monotonic()))
        elapsed = time.monotonic() - started
    finally:
        scheduler.stop()
        transport.close()
    cpu_process = time.process_time() - cpu_before
    snapshot = scheduler.metrics()
    store = scheduler.metrics_store
    tick = snapshot["command_tick"]
    latencies = [s["latency_s"] for s in snapshot["servos"].values()]
    intervals = [store.servos[s.name].telemetry_intervals for s in specs]
    window_intervals = [v for period in intervals for v in period.intervals.recent]
    window_dev = [v for period in intervals for v in period.deviations.recent]
    ordered_dev = sorted(window_dev) or [math.nan]
    cpu = snapshot["info"]["cpu"]
    lost = sum(s["frames"]["lost"] for s in snapshot["servos"].values())
    received = sum(s["frames"]["received"] for s in snapshot["servos"].values())
    ms = 1e3
    result: dict[str, Any] = {
        "profile": profile,
        "servos": n_servos,
        "seconds": round(elapsed, 1),
        "hog": args.hog,
        "rt_kworkers": args.rt_kworkers,
        "transport": args.transport,
        "realtime": snapshot["info"]["realtime"],
        "spin_ms": snapshot["info"]["spin_s"] * 1e3,
        "cmd_period_mean_ms": tick["interval"]["mean"] * ms,
        "cmd_period_sigma_ms": tick["interval"]["sigma"] * ms,
        "cmd_p99_dev_ms": tick["abs_deviation"]["p99"] * ms,
        "cmd_max_dev_ms": tick["abs_deviation"]["max"] * ms,
        "missed_slots": snapshot["missed_command_slots"],
        "frames_per_slot": counter.frames / max(1.0, elapsed / args.command_period),
        "slot_late_p99_ms": snapshot["command_lateness_s"]["p99"] * ms,  # due -> first write
        "tlm_interval_mean_ms": statistics.fmean(window_intervals) * ms,
        "tlm_interval_p1_ms": min(window_intervals) * ms if window_intervals else None,
        "tlm_in_70_100ms": sum(0.07 <= v <= 0.1 for v in window_intervals)
        / max(1, len(window_intervals)),
        "tlm_p99_dev_ms": ordered_dev[min(len(ordered_dev) - 1, int(0.99 * len(ordered_dev)))] * ms,
        "L_mean_ms": statistics.fmean(s["mean"] for s in latencies if s["mean"]) * ms,
        "sigma_L_ms": statistics.fmean(s["sigma"] for s in latencies if s["sigma"]) * ms,
        "L_p99_ms": max(s["p99"] for s in latencies if s["p99"]) * ms,
        "R_mean": snapshot["load"]["total_bits"] / (elapsed * args.bitrate),
        "R_peak": snapshot["load"]["peak"],
        "R_worst_case": snapshot["load"]["planned"],
        "lost": lost,
        "received": received,
        "cpu_sched_pct": (cpu["runner_s"] + cpu["receiver_s"]) / elapsed * 100,
        "cpu_process_pct": cpu_process / elapsed * 100,
        "cpu_sched_pct_per_servo": (cpu["runner_s"] + cpu["receiver_s"]) / elapsed * 100 / n_servos,
    }
    if tracer is not None:
        result["breakdown"] = interval_breakdown(tracer, args.telemetry_period)
    return result


def bare_loop(seconds: float, period: float, spin: float) -> dict[str, Any]:
    """The yardstick: the same sleep-then-spin wait with nothing else in the process.

    What the machine itself allows right now; the scheduler's figures are read against it.
    """
    import threading

    never = threading.Event()
    deadline = start = time.monotonic()
    marks: list[float] = []
    while deadline - start < seconds:
        deadline += period
        remaining = deadline - time.monotonic()
        if remaining > spin:
            never.wait(remaining - spin)
        while time.monotonic() < deadline:
            time.sleep(0)
        marks.append(time.monotonic())
    intervals = [b - a for a, b in zip(marks, marks[1:], strict=False)]
    deviations = sorted(abs(i - period) for i in intervals)
    return {
        "baseline": "bare sleep+spin loop",
        "seconds": seconds,
        "cmd_period_sigma_ms": statistics.pstdev(intervals) * 1e3,
        "cmd_p99_dev_ms": deviations[int(0.99 * (len(deviations) - 1))] * 1e3,
        "cmd_max_dev_ms": deviations[-1] * 1e3,
    }


def _rounded(value: Any) -> Any:
    if isinstance(value, float):
        return round(value, 3)
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    return value


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--servos", type=int, default=8)
    parser.add_argument("--hog", action="store_true", help="busy-loop process on every core")
    parser.add_argument("--transport", choices=("pty", "virtual"), default="pty")
    parser.add_argument("--bitrate", type=int, default=1_000_000)
    parser.add_argument("--command-period", type=float, default=0.05)
    parser.add_argument("--telemetry-period", type=float, default=0.09)
    parser.add_argument("--spin", type=float, default=0.001)
    parser.add_argument(
        "--fifo-spin", type=float, default=0.0, help="spin used when the runner is SCHED_FIFO"
    )
    parser.add_argument(
        "--telemetry-phase",
        type=float,
        default=None,
        help="first telemetry tick this long after slot 0 (default: automatic; 0: on a slot)",
    )
    parser.add_argument("--realtime", action="store_true", help="ask for SCHED_FIFO")
    parser.add_argument(
        "--rt-kworkers",
        action="store_true",
        help="run the kernel's kworker threads (tty flip-buffer work) at SCHED_FIFO 1 (root)",
    )
    parser.add_argument("--runs", type=int, default=1)
    parser.add_argument(
        "--cpu-only",
        action="store_true",
        help="CPU cost with 8 and 32 servos instead of the timing run",
    )
    parser.add_argument("--json", help="append result lines to this file")
    parser.add_argument(
        "--sim-in-process",
        action="store_true",
        help="pty: run the adapter emulator in this process (shares the GIL)",
    )
    parser.add_argument(
        "--baseline",
        action="store_true",
        help="also time a bare sleep+spin loop for the same duration first",
    )
    parser.add_argument(
        "--breakdown",
        action="store_true",
        help="trace every frame and split telemetry intervals by cause",
    )
    parser.add_argument(
        "--profile",
        default="rmd-x",
        help="servo family, or several comma-separated (each run goes round them in turn)",
    )
    parser.add_argument("--serve-sim", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve_sim:
        serve_simulator(args.serve_sim, args.bitrate, args.realtime, args.profile)
        return
    for name in args.profile.split(","):
        get_profile(name)  # an unknown family fails here, before any run

    counts = [8, 32] if args.cpu_only else [args.servos]
    hogs = start_hogs() if args.hog else []
    kworkers = RealtimeKworkers() if args.rt_kworkers else contextlib.nullcontext()
    with kworkers:
        _run_all(args, counts, hogs)


def _run_all(args: argparse.Namespace, counts: list[int], hogs: list[subprocess.Popen]) -> None:
    try:
        if args.baseline:
            base = bare_loop(args.seconds, args.command_period, args.spin)
            base["hog"] = args.hog
            print(json.dumps(_rounded(base)), flush=True)
        profiles = args.profile.split(",")
        for n in counts:
            for _ in range(args.runs):
                for profile in profiles:  # alternated, so each family sees the same machine
                    result = run_once(args, n, args.seconds, profile)
                    line = json.dumps(_rounded(result))
                    print(line, flush=True)
                    if args.json:
                        with open(args.json, "a") as out:
                            out.write(line + "\n")
    finally:
        stop_hogs(hogs)


if __name__ == "__main__":
    main()
