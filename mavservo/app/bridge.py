"""Wiring and lifecycle: config -> buses -> schedulers -> servo backend -> MAVLink side.

:class:`Bridge` builds every piece from a validated :class:`~mavservo.config.Config`, starts them
in dependency order (simulators, buses, MAVLink, then the schedulers' command clocks, last so
that no start-up work delays their first slots) and stops them with the schedulers last,
leaving each servo in its configured failsafe state and flushing the run log. Each piece it
wires is usable alone (tests start a scheduler on a ``virtual`` bus, the MAVLink side with a
test backend); the bridge adds only what needs all of them: the ``sim`` endpoints, reconnects,
the run log and the summary.
"""

from __future__ import annotations

import dataclasses
import gc
import logging
import socket
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import can

from mavservo.app import node_state
from mavservo.app.bridge_buses import BridgeBuses
from mavservo.app.bridge_events import MAV_SEVERITY_ERROR, MAV_SEVERITY_NOTICE, BridgeEvents
from mavservo.app.bridge_identity import BridgeIdentity
from mavservo.app.component_metadata import metadata_files
from mavservo.app.health_reporting import HealthReporter
from mavservo.app.run_records import open_run_log, tap_mavlink
from mavservo.app.startup_errors import link_open_error
from mavservo.app.stop_lines import servo_stop_lines
from mavservo.config import (
    Config,
    gimbal_settings,
    mavlink_settings,
    overlay_path,
    refuse_simulated_autopilot_on_hardware,
    servo_specs,
    timing_config,
)
from mavservo.control import (
    ConfigTargets,
    HealthWatch,
    LiveParameters,
    OverlaySaver,
    ServoBackend,
    health_limits,
)
from mavservo.mavlink import CanTunnel, GimbalDevice, MavlinkSide
from mavservo.records import RunLog, round_trip_figures
from mavservo.scheduling import FrameKind, Scheduler, SchedulerObserver, WriteObserver
from mavservo.servos import CountingNode, ServoState

log = logging.getLogger(__name__)

SIM = "sim"


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that nobody holds right now (for the built-in autopilot)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


class _FanOut(SchedulerObserver):
    """Passes scheduler events to several observers (run log, latency tracer, live status).

    Every observer implements the whole :class:`SchedulerObserver` Protocol (a subclass
    inherits no-ops for the hooks it does not need), so each hook is simply called on each;
    ``on_written`` goes to those that have the :class:`WriteObserver` capability.
    """

    def __init__(self, *observers: SchedulerObserver | None) -> None:
        self.observers = [o for o in observers if o is not None]
        self._writers = [o for o in self.observers if isinstance(o, WriteObserver)]

    def on_setpoint(self, servo: str, seq: int, angle_deg: float, source: str, t: float) -> None:
        for observer in self.observers:
            observer.on_setpoint(servo, seq, angle_deg, source, t)

    def on_tx(
        self,
        bus: str,
        msg: can.Message,
        t: float,
        kind: FrameKind,
        servo: str,
        seq: int | None,
    ) -> None:
        for observer in self.observers:
            observer.on_tx(bus, msg, t, kind, servo, seq)

    def on_written(self, bus: str, t: float, kind: FrameKind, servo: str, seq: int | None) -> None:
        for observer in self._writers:
            observer.on_written(bus, t, kind, servo, seq)

    def on_rx(
        self, bus: str, msg: can.Message, t: float, servo: str, state: ServoState | None
    ) -> None:
        for observer in self.observers:
            observer.on_rx(bus, msg, t, servo, state)

    def on_lost(self, bus: str, servo: str, t: float) -> None:
        for observer in self.observers:
            observer.on_lost(bus, servo, t)

    def on_reject(self, bus: str, reason: str, raw_bytes: bytes, t: float) -> None:
        for observer in self.observers:
            observer.on_reject(bus, reason, raw_bytes, t)


def settle_heap() -> None:
    """Put everything alive after start-up out of the garbage collector's way (``gc.freeze``).

    Why: start-up builds a large, long-lived heap (pymavlink's message classes, the config,
    profiles, buffers). Every full collection walks all of it, and in the soak such a pass
    stopped the bridge for 58-106 ms, long enough to miss a 20 ms command slot
    (docs/engineering/reliability.md). Frozen objects are never collected, so call this once, in a
    process that runs one bridge (``mavservo run``), after :meth:`Bridge.start`. No ``gc.collect()``
    first: with the scheduler already running, that full pass is itself the pause to avoid (the
    soak saw it take 140 ms, 7 command slots); the little start-up garbage frozen with the rest
    is never freed, which costs less.
    """
    gc.freeze()


def health_figures(
    schedulers: Iterable[Scheduler], latency_total: Mapping[str, Any] | None = None
) -> dict[str, float]:
    """``Bridge._health``'s figures from its schedulers and the run log's ``total`` latency
    summary (seconds); a function of its inputs so that tests build them without a bridge."""
    out: dict[str, float] = {}
    round_trips: list[float] = []
    for k, scheduler in enumerate(schedulers):
        out[f"bus{k}_load"] = scheduler.load_ratio()
        round_trips += scheduler.round_trip_samples()
    out.update(round_trip_figures(round_trips))
    for p in ("p50", "p95", "p99"):
        value = (latency_total or {}).get(p)
        if value is not None:
            out[f"lat_{p}"] = value * 1000.0
    return out


class Bridge:
    """The whole bridge for one config. ``start()``, then ``stop()`` (idempotent).

    ``log_dir``: base directory for run logs (None: the config's ``logging.dir``; False: none).
    ``status``: called with one-line events (link lost, adapter back, failsafe) for the console.
    ``observers``: more :class:`SchedulerObserver` hooks on every bus (non-blocking, see there).
    """

    def __init__(
        self,
        config: Config,
        *,
        config_path: str | Path | None = None,
        log_dir: str | Path | None | bool = None,
        status: Callable[[str], None] | None = None,
        observers: Sequence[SchedulerObserver] = (),
        parameter_base: Config | None = None,
        overlay: Mapping[str, float] | None = None,
        persist_parameters: bool = True,
    ) -> None:
        self._config = config
        #: the config file without its overlay, and the overlay's values (PARAM_SET keeps the
        #: differences from the file in the overlay; see mavservo/config/overlay.py)
        self._parameter_base = parameter_base or config
        self._overlay = dict(overlay or {})
        self._persist_parameters = persist_parameters and config_path is not None
        #: the owner of every PARAM_SET (validated, applied, saved): its config is the one
        #: in force (:attr:`config`)
        self.parameters: LiveParameters | None = None
        #: writes the overlay in its own thread (None: parameters are not persisted)
        self.overlay_saver: OverlaySaver | None = None
        #: extra scheduler observers (tests, live tools) next to the run log's
        self._observers = tuple(observers)
        self.config_path = config_path
        #: the console line, the event list and STATUSTEXT every piece reports through
        self.notes = BridgeEvents(status or (lambda line: log.info("%s", line)))
        #: CAN frames through the autopilot for ``mavlink-can`` buses (None: no such bus)
        self.can_tunnel = (
            CanTunnel() if any(b.interface == "mavlink-can" for b in config.can.buses) else None
        )
        #: every configured bus, opened at start (``buses``, ``emulators`` by bus name)
        self.bus_set = BridgeBuses(
            config, on_event=self.notes.event, on_reject=self._rejected, carrier=self.can_tunnel
        )
        self.buses = self.bus_set.buses
        self.emulators = self.bus_set.emulators
        self.schedulers: dict[str, Scheduler] = {}
        #: what the bus nodes keep across restarts (DroneCAN allocation table), if any
        self.node_states: node_state.NodeStateKeeper | None = None
        self.autopilot_sim: Any = None
        #: the simulated flight-controller CAN port of a mavlink-can bus under ``url: sim``
        self.sim_can_port: Any = None
        self.mavlink: MavlinkSide | None = None
        self.backend: ServoBackend | None = None
        #: the bridge's own servo health judgement and what follows from it (docs/health.md)
        self.health_reporter: HealthReporter | None = None
        self.runlog: RunLog | None = None
        self.run_dir: Path | None = None
        #: how the bridge shows itself on the vehicle (said at start and on each change)
        self.identity: BridgeIdentity | None = None
        self._log_dir = log_dir
        self._stop = threading.Event()
        self._tick_thread: threading.Thread | None = None
        self._started = False
        self._start_error: str | None = None
        self._stopped = False
        self.started_at: float | None = None

    @property
    def config(self) -> Config:
        """The config in force: the one given, then each PARAM_SET's validated rebuild."""
        return self.parameters.config if self.parameters is not None else self._config

    @property
    def events(self) -> list[tuple[float, str]]:
        """Every event said so far (monotonic s, text), the newest kept."""
        return self.notes.events

    @property
    def health(self) -> HealthWatch | None:
        """The bridge's own servo health monitor (docs/health.md)."""
        return None if self.health_reporter is None else self.health_reporter.watch

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> Bridge:
        try:
            self._start()
        except BaseException as exc:
            self._start_error = str(exc) or type(exc).__name__
            self.stop()
            raise
        return self

    def _start(self) -> None:
        cfg = self.config
        # before anything opens: the simulated autopilot never drives a real bus (issue 37)
        refuse_simulated_autopilot_on_hardware(cfg)
        opened = open_run_log(
            cfg,
            self._log_dir,
            config_path=self.config_path,
            on_problem=self.notes.event,  # a full disk is said at once: console, STATUSTEXT
        )
        if opened is not None:
            self.run_dir, self.runlog = opened
        observer = _FanOut(self.runlog, *self._observers)
        self.bus_set.open_all(self.runlog)
        sinks: dict[str, Scheduler] = {}
        saved: dict[str, Any] = {}
        state_file = None
        if self.config_path is not None and any(bus.node for bus in cfg.can.buses):
            state_file = node_state.state_path(self.config_path)
            saved = node_state.load(state_file)
        for bus_cfg in cfg.can.buses:
            specs = servo_specs(cfg, bus_cfg.name)
            if not specs:
                continue
            timing = timing_config(cfg, bus_cfg)
            node_options = bus_cfg.node_options()
            if state_file is not None:
                node_options = node_state.bus_node_options(bus_cfg, saved, state_file)
            scheduler = Scheduler(
                self.buses[bus_cfg.name],
                specs,
                timing,
                observer=observer,
                name=bus_cfg.name,
                node_options=node_options,
            )
            scheduler.on_event = self.notes.event
            self.schedulers[bus_cfg.name] = scheduler
            for spec in specs:
                sinks[spec.name] = scheduler
        if state_file is not None:
            self.node_states = node_state.NodeStateKeeper(state_file, saved)
        watch = HealthWatch(health_limits(cfg), clock=time.monotonic)
        self.backend = ServoBackend(
            cfg,
            sinks,
            on_event=self.notes.event,
            on_command=self.runlog.mavlink_received if self.runlog is not None else None,
            health=self._health,
            slew_step_s=cfg.scheduler.command_period_s,
            health_flags=watch.flags,
        )
        self.health_reporter = HealthReporter(watch, self.backend, self.notes, runlog=self.runlog)
        self.mavlink = self._make_mavlink()
        self.notes.announcer = self.mavlink
        if self.runlog is not None:
            tap_mavlink(self.mavlink, self.runlog, [s.name for s in cfg.servos])
        try:
            self.mavlink.start()
        except OSError as exc:  # a serial port, a UDP/TCP port: named, with its usual causes
            raise link_open_error(cfg.mavlink, exc) from exc
        if self.overlay_saver is not None:
            self.overlay_saver.start()
        self.identity = BridgeIdentity(self.mavlink, servos=len(cfg.servos), notes=self.notes)
        self.identity.note_change()
        if self.autopilot_sim is not None:
            self.autopilot_sim.start()
        self._tick_thread = threading.Thread(target=self._tick, name="bridge-tick", daemon=True)
        self._tick_thread.start()
        # The command clock starts last, once the rest of start-up is done: each scheduler
        # anchors its first slot when it starts, and start-up work after that anchor ran while
        # the first slots were due (opening the MAVLink link imports pymavlink's 2.4 MB dialect
        # module, holding the interpreter lock: 5-10 ms stalls of the whole process, see
        # docs/engineering/reliability.md, "Start-up"). Setpoints that arrive meanwhile are queued
        # by the scheduler and go out in its first slot.
        for scheduler in self.schedulers.values():
            scheduler.start()
        self._started = True
        self.started_at = time.monotonic()

    def stop(self, reason: str = "stop requested") -> dict[str, Any]:
        """Failsafe every servo, flush the last frames, close logs and devices; return summary.

        ``reason``: why the run ends (``end of --duration 5 s``, ``SIGTERM``), for the one
        event line that says so at INFO level with what the servos were told: a normal end
        must not read as the alarm an autopilot-lost failsafe is."""
        if self._stopped:
            return self.summary()
        self._stopped = True
        self._stop.set()
        if self.autopilot_sim is not None:
            _quietly(self.autopilot_sim.stop)
        if self.sim_can_port is not None:
            _quietly(self.sim_can_port.stop)
        if self.backend is not None and self._started:
            self.backend.failsafe_all(reason, time.monotonic(), announce=False)
            self._stopped_event(reason)
            time.sleep(2 * self.config.scheduler.command_period_s)  # let the failsafe go out
        if self._tick_thread is not None:
            self._tick_thread.join(1.0)
        summary = self.summary()
        # through a mavlink-can bus the schedulers' last frames (release, shutdown) travel on
        # the MAVLink link: it closes after them
        link_last = self.can_tunnel is not None
        if self.mavlink is not None and not link_last:
            _quietly(self.mavlink.stop)
        if self.overlay_saver is not None:
            _quietly(self.overlay_saver.stop)
        for scheduler in self.schedulers.values():
            _quietly(scheduler.stop)
        self._count_stop_frames(summary)
        if self.mavlink is not None and link_last:
            _quietly(self.mavlink.stop)
        self.bus_set.close()
        runlog = self.runlog
        if runlog is not None and not self._started:  # nothing ran: say why, record nothing
            reason = self._start_error or "stopped before start-up finished"
            _quietly(lambda: runlog.abandon(reason))
        elif runlog is not None:
            _quietly(lambda: runlog.close(summary))
            summary["runlog"] = {  # the summary must not point at a run log that failed
                k: v for k, v in runlog.outcome().items() if k != "metrics"
            }
        return summary

    def _count_stop_frames(self, summary: dict[str, Any]) -> None:
        """The bus nodes' counters again, now that the schedulers have sent their stop frames
        (DroneCAN's SAFETY_ON goes out then: the summary taken before the stop never counted
        it), and ``safety_on``, the SafetyState SAFETY_ON broadcasts of the run, on top; the
        servos' reply outcomes once the stop booked what the bus held
        (:func:`reply_outcomes_at_stop`)."""
        safety_on = 0
        for name, scheduler in self.schedulers.items():
            reply_outcomes_at_stop(summary["servos"], scheduler.metrics().get("servos", {}))
            nodes = [node.stats() for node in scheduler.nodes if isinstance(node, CountingNode)]
            if name in summary["buses"]:
                summary["buses"][name]["nodes"] = nodes
            safety_on += sum(int(node.get("safety_on", 0)) for node in nodes)
        summary["safety_on"] = safety_on

    def __enter__(self) -> Bridge:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ------------------------------------------------------------------ pieces

    def _rejected(self, bus_name: str, reason: object, raw: bytes) -> None:
        scheduler = self.schedulers.get(bus_name)
        if scheduler is not None:
            scheduler.report_reject(reason, raw)  # it reports an enum reason by its value

    def _make_mavlink(self) -> MavlinkSide:
        cfg = self.config
        settings = mavlink_settings(cfg)
        if cfg.mavlink.url == SIM:
            from mavservo.sim import simulated_can_port, simulator_for

            port = free_udp_port()
            settings = dataclasses.replace(settings, url=f"udpin:127.0.0.1:{port}")
            # a mavlink-can bus: the simulated autopilot forwards a CAN port with its servos
            tunnelled = [b for b in cfg.can.buses if b.interface == "mavlink-can"]
            if tunnelled:
                self.sim_can_port = simulated_can_port(cfg, tunnelled[0].name).start()
            self.autopilot_sim = simulator_for(
                cfg.simulation.autopilot,
                f"udpout:127.0.0.1:{port}",
                # it reads DO_REPEAT_SERVO's cycle the way the bridge is told to, and shares
                # the signing key
                repeat_servo_cycle=cfg.mavlink.repeat_servo_cycle,
                signing_key=settings.signing.key if settings.signing is not None else None,
                can_forward=None if self.sim_can_port is None else self.sim_can_port.link,
            )
        assert self.backend is not None
        gimbals = [GimbalDevice(settings, self.backend) for settings in gimbal_settings(cfg)]
        # PARAM_SET: the MAVLink side checks the request, the owner validates, applies and saves
        if self._persist_parameters and self.config_path is not None:
            self.overlay_saver = OverlaySaver(
                overlay_path(self.config_path),
                Path(self.config_path).name,
                on_failure=self._parameters_not_saved,
            )
        targets = ConfigTargets(self.backend, health=self.health, gimbals=gimbals)
        self.parameters = LiveParameters(
            cfg,
            base=self._parameter_base,
            overlay=self._overlay,
            saver=self.overlay_saver,
            target=targets,
        )
        side = MavlinkSide(
            settings,
            self.backend,
            gimbals,
            on_event=self.notes.note,
            parameters=self.parameters,
            metadata_files=metadata_files(cfg, self._parameter_base),  # issue 30, 32
            can_tunnel=self.can_tunnel,
        )
        targets.attach_telemetry(side.core)
        return side

    def _parameters_not_saved(self, text: str) -> None:
        """The overlay saver's failure, to the ground station (STATUSTEXT) and the console."""
        self.notes.announce(text, MAV_SEVERITY_ERROR)
        self.notes.note(text)

    def _health(self) -> dict[str, float]:
        """Transport figures for telemetry (``ServoBackend.health`` hands them on).

        ``bus<k>_load`` (ratio) per bus; ``rtt_p50``/``rtt_p95``/``rtt_p99`` (ms: frame written
        -> reply decoded, the wire round trip L of the summary, over every bus); with a run
        log, ``lat_p50``/``lat_p95``/``lat_p99`` (ms: MAVLink command receipt -> telemetry
        published, every stage). Both latencies are published because they answer different
        questions (how fast the bus and servos are; how fast a ground station sees a command
        take effect) and differ ~100-fold; docs/logs.md, "Which latency is which".
        """
        total = self.runlog.latency.summary().get("total", {}) if self.runlog is not None else {}
        return health_figures(self.schedulers.values(), total)

    def _tick(self) -> None:
        period = self.config.scheduler.command_period_s
        next_t = time.monotonic()
        while not self._stop.is_set():
            next_t += period
            if self.backend is not None:
                self.backend.tick(time.monotonic())
            if self.health_reporter is not None:
                self.health_reporter.update()
            for scheduler in self.schedulers.values():
                for notice in scheduler.take_notices():
                    self.notes.event(f"bus {scheduler.name}: {notice}")
            if self.node_states is not None:
                self.node_states.update(self.schedulers.values())
            if self.identity is not None:
                self.identity.note_change()  # gcs (issue 30)
            self._stop.wait(max(0.0, next_t - time.monotonic()))

    def _stopped_event(self, reason: str) -> None:
        """``stopped (end of --duration 5 s): servos told their failsafe action: hold 6,
        neutral 3``: console, event list, and a NOTICE STATUSTEXT (not a WARNING)."""
        actions = Counter(servo.failsafe.action for servo in self.config.servos)
        told = ", ".join(f"{action} {count}" for action, count in actions.items())
        text = f"stopped ({reason}): servos told their failsafe action: {told}"
        self.notes.note(text)
        for line in servo_stop_lines(self.config):  # one INFO line per servo
            self.notes.note(line)
        self.notes.announce(text, MAV_SEVERITY_NOTICE)

    def autopilot_heartbeat(self) -> tuple[tuple[int, int], float | None] | None:
        """The watched autopilot (system, component) and when its HEARTBEAT was last heard
        (monotonic s, None while never); None without a MAVLink side."""
        mavlink = self.mavlink
        if mavlink is None:
            return None
        core = mavlink.core
        return core.watched, core.watchdog.last_heartbeat

    # ------------------------------------------------------------------ views

    def status_rows(self) -> list[dict[str, Any]]:
        """One row per servo for the live status line."""
        rows: list[dict[str, Any]] = []
        if self.backend is None:
            return rows
        now = time.monotonic()  # the scheduler stamps states with its monotonic clock
        for status in self.backend.servo_statuses():
            state = status.state
            rows.append(
                {
                    "servo": status.name,
                    "setpoint_deg": status.setpoint_deg,
                    "position_deg": None if state is None else state.position_deg,
                    "velocity_dps": None if state is None else state.velocity_dps,
                    "current_a": None if state is None else state.current_a,
                    "temperature_c": None if state is None else state.temperature_c,
                    "faults": "" if state is None else _fault_names(state.faults),
                    "health": _fault_names(status.health),
                    "online": status.online,
                    "age_s": None if state is None else max(0.0, now - state.timestamp),
                }
            )
        return rows

    def summary(self) -> dict[str, Any]:
        """Frames, errors, latency, bus load: what the end-of-run summary prints."""
        out: dict[str, Any] = {
            "uptime_s": None if self.started_at is None else time.monotonic() - self.started_at,
            "buses": {},
            "servos": {},
            "events": self.notes.recent(20),
            "identity": None if self.identity is None else self.identity.shown,
            "run_dir": None if self.run_dir is None else str(self.run_dir),
        }
        for name, scheduler in self.schedulers.items():
            metrics = scheduler.metrics()
            out["buses"][name] = {
                **{k: v for k, v in metrics.items() if k != "servos"},
                "transport": self.bus_set.transport_stats(name),
                # what the bus nodes (DroneCAN: the bridge's node) counted of hostile traffic
                "nodes": [
                    node.stats() for node in scheduler.nodes if isinstance(node, CountingNode)
                ],
            }
            out["servos"].update(metrics.get("servos", {}))
        if self.mavlink is not None:
            out["mavlink"] = _quietly(self.mavlink.stats) or {}
        if self.backend is not None:
            out["backend"] = dict(self.backend.counters)
        if self.health_reporter is not None:
            out["health"] = self.health_reporter.summary()
        return out


#: A servo's reply outcomes, final only once its scheduler stopped (see below).
REPLY_OUTCOMES = ("timed_out", "late", "lost")


def reply_outcomes_at_stop(servos: dict[str, Any], stopped: dict[str, Any]) -> None:
    """Put the schedulers' reply outcomes after their stop into the summary's ``servos``.

    The summary is taken before the schedulers stop; a reply the receive thread had not read
    by then (its timeout passed, the reply waiting in the bus: a tunnel or a loaded machine)
    read as lost. A stopping scheduler books what the bus holds (``FrameReceiver.drain``), so
    its counts say which of those replies came late and which never came. Frames sent stay
    the summary's (the stop frames are counted apart); received grows by the late replies
    booked since (a late reply is received too, never the stop frames' answers)."""
    for name, figures in stopped.items():
        frames = servos.get(name, {}).get("frames")
        final = figures.get("frames", {})
        if frames is None or not all(key in final for key in REPLY_OUTCOMES):
            continue
        frames["received"] = frames.get("received", 0) + final["late"] - frames.get("late", 0)
        frames.update({key: final[key] for key in REPLY_OUTCOMES})


def _fault_names(faults: Any) -> str:
    if not faults:
        return ""
    return "|".join(m.name for m in type(faults) if m in faults and m.value and m.name)


def _quietly(fn: Callable[[], Any]) -> Any:
    """Run a shutdown step; a failing step is logged and must not stop the others."""
    try:
        return fn()
    except Exception as exc:  # noqa: BLE001 - shutdown must go on
        log.warning("shutdown step failed: %s", exc)
        return None
