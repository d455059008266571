"""``mavservo report LOGDIR``: figures and a short markdown summary of one recorded run.

It works from the files of a run directory alone (see ``docs/logs.md``), so a user can run it
on a directory copied off the drone. Figures follow the paper: commanded vs measured response
(Fig. 3), the state interval's histogram (Fig. 4) and sequence (Fig. 5), one panel per servo,
plus what the paper did not show: each latency stage on a log axis and the bus load over time.
Every figure quoted is ``metrics.json``'s, under the run summary's name (docs/logs.md, "Every
figure, once"); a run directory that holds only ``run.json`` with ``start_failed`` is refused.
matplotlib is used through its object API on the Agg canvas: headless, no global pyplot state.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from collections import defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mavservo.errors import MavservoError
from mavservo.records import (
    LATENCY_FILE,
    METRICS_FILE,
    REJECTIONS_FILE,
    RUN_HEADER,
    STAGE_DESCRIPTIONS,
    STAGES,
    TRACE_FILE,
    can_log_files,
    glossary_text,
    percentile,
    read_can_log,
    summarize,
)

FIGURES: dict[str, str] = {
    "response": "fig3_response.png",
    "interval_histogram": "fig4_interval_histogram.png",
    "interval_sequence": "fig5_interval_sequence.png",
    "latency_stages": "latency_stages.png",
    "bus_load": "bus_load.png",
}
REPORT_FILE = "report.md"
LOAD_WINDOW_S = 1.0
DEFAULT_BITRATE = 1_000_000


class ReportError(MavservoError):
    """The directory cannot be reported on (not a run, unreadable files)."""


@dataclass
class ServoTrace:
    """One servo's time series, times in seconds since the run started."""

    setpoint_t: list[float] = field(default_factory=list)
    setpoint_deg: list[float] = field(default_factory=list)
    state_t: list[float] = field(default_factory=list)
    position_deg: list[float] = field(default_factory=list)
    velocity_dps: list[float] = field(default_factory=list)
    current_a: list[float] = field(default_factory=list)
    lost: int = 0
    fault_samples: int = 0

    def intervals_s(self) -> list[float]:
        """State intervals: between successive decoded states, every reply (command replies,
        poll answers, pushes), as ``state_interval_s`` in metrics.json and ``state p50`` in
        the run summary; so shorter than the poll period (``telemetry_interval_s``)."""
        return [b - a for a, b in zip(self.state_t, self.state_t[1:], strict=False)]


@dataclass
class Run:
    """Everything the report needs, loaded from a run directory."""

    directory: Path
    header: dict[str, Any]
    servos: dict[str, ServoTrace]
    latency_rows: list[dict[str, str]]
    frames: list[Any]
    frames_format: str | None
    metrics: dict[str, Any]
    rejections: int

    @property
    def start(self) -> float:
        return float(self.header.get("start_monotonic", 0.0))

    @property
    def start_wall(self) -> float:
        return float(self.header.get("start_wall", 0.0))


def _float(text: str) -> float | None:
    if text == "" or text is None:
        return None
    try:
        return float(text)
    except ValueError:
        return None


def _nan(text: str) -> float:
    value = _float(text)
    return math.nan if value is None else value


def load_run(directory: str | Path) -> Run:
    """Read a run directory; raise :class:`ReportError` if it is not one."""
    directory = Path(directory)
    header_path = directory / RUN_HEADER
    if not directory.is_dir():
        raise ReportError(f"{directory}: no such directory")
    if not header_path.is_file():
        raise ReportError(
            f"{directory} is not a mavservo run directory (no {RUN_HEADER}); "
            "point at a directory written by 'mavservo run' under logging.dir"
        )
    try:
        header = json.loads(header_path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError) as exc:  # RecursionError: nested too deep
        raise ReportError(f"{header_path}: unreadable run header ({exc})") from exc
    if not isinstance(header, dict) or header.get("format") != "mavservo-run":
        raise ReportError(f"{header_path}: not a mavservo run header")
    if header.get("start_failed"):
        raise ReportError(
            f"{directory}: this run never started ({header['start_failed']}); nothing was "
            "recorded, so there is nothing to report"
        )
    start = float(header.get("start_monotonic", 0.0))

    servos: dict[str, ServoTrace] = defaultdict(ServoTrace)
    trace_path = directory / TRACE_FILE
    if trace_path.is_file():
        with trace_path.open(newline="", encoding="utf-8") as handle:
            for row in csv.DictReader(handle):
                t = _float(row.get("t", ""))
                name = row.get("servo") or "?"
                if t is None:
                    continue
                trace = servos[name]
                event = row.get("event")
                if event == "setpoint":
                    value = _float(row.get("setpoint_deg", ""))
                    if value is not None:
                        trace.setpoint_t.append(t - start)
                        trace.setpoint_deg.append(value)
                elif event == "state":
                    trace.state_t.append(t - start)
                    trace.position_deg.append(_nan(row.get("position_deg", "")))
                    trace.velocity_dps.append(_nan(row.get("velocity_dps", "")))
                    trace.current_a.append(_nan(row.get("current_a", "")))
                    if row.get("faults"):
                        trace.fault_samples += 1
                elif event == "lost":
                    trace.lost += 1

    latency_rows: list[dict[str, str]] = []
    latency_path = directory / LATENCY_FILE
    if latency_path.is_file():
        with latency_path.open(newline="", encoding="utf-8") as handle:
            latency_rows = list(csv.DictReader(handle))

    frames: list[Any] = []
    frames_format = None
    for fmt in ("blf", "asc", "log", "csv"):
        if can_log_files(directory, fmt):
            frames = read_can_log(directory, fmt)
            frames_format = fmt
            break

    metrics: dict[str, Any] = {}
    metrics_path = directory / METRICS_FILE
    if metrics_path.is_file():
        try:
            metrics = json.loads(metrics_path.read_text(encoding="utf-8"))
        except (OSError, ValueError, RecursionError):
            metrics = {}
        if not isinstance(metrics, dict):
            metrics = {}

    rejections = 0
    rejections_path = directory / REJECTIONS_FILE
    if rejections_path.is_file():
        with rejections_path.open(encoding="utf-8") as handle:
            rejections = sum(1 for line in handle if line.strip())

    return Run(
        directory, header, dict(servos), latency_rows, frames, frames_format, metrics, rejections
    )


# -- derived series (pure) -----------------------------------------------------------------

#: Per CAN channel: times (s since the run's start) of every frame and the bus load R of the
#: window ending there (the scheduler's ``LoadMeter`` definition, so its peak is metrics.json's).
LoadSeries = dict[int, tuple[list[float], list[float]]]


def stage_samples(rows: Sequence[dict[str, str]]) -> dict[str, list[float]]:
    """Per-stage durations (seconds) from latency.csv rows, skipping missing stages."""
    out: dict[str, list[float]] = {stage: [] for stage in STAGES}
    for row in rows:
        for stage in STAGES:
            value = _float(row.get(f"{stage}_s", ""))
            if value is not None:
                out[stage].append(value)
    return out


def bus_load_series(
    frames: Sequence[Any],
    start_wall: float,
    bitrates: dict[int, int] | None = None,
    window_s: float = LOAD_WINDOW_S,
) -> LoadSeries:
    """Per CAN channel, at every frame: the bits of the frames in ``(t - window_s, t]`` over
    ``window_s * bitrate``, TX and RX alike (both occupy the bus), each frame at its
    worst-case stuffed length (``busload.message_bits``). This is ``metrics.LoadMeter``'s
    measure, so the series' maximum is the run's ``load.peak`` (up to the log's timestamp
    resolution) and not a fixed-bin average below it (the report said 6.58 % where the
    summary said 6.8 %)."""
    from mavservo.scheduling import message_bits

    by_channel: dict[int, list[tuple[float, int]]] = defaultdict(list)
    for msg in frames:
        channel = msg.channel if isinstance(msg.channel, int) else 0
        by_channel[channel].append((msg.timestamp - start_wall, message_bits(msg)))
    series: LoadSeries = {}
    for channel, events in by_channel.items():
        events.sort()
        capacity = window_s * (bitrates or {}).get(channel, DEFAULT_BITRATE)
        times: list[float] = []
        loads: list[float] = []
        first = 0
        in_window = 0
        for t, bits in events:
            in_window += bits
            while events[first][0] <= t - window_s:
                in_window -= events[first][1]
                first += 1
            times.append(t)
            loads.append(in_window / capacity)
        series[channel] = (times, loads)
    return series


def bus_names_by_channel(header: dict[str, Any]) -> dict[int, tuple[str, dict[str, Any]]]:
    out = {}
    for name, info in (header.get("buses") or {}).items():
        if isinstance(info, dict) and isinstance(info.get("channel"), int):
            out[info["channel"]] = (name, info)
    return out


def channel_bitrates(header: dict[str, Any]) -> dict[int, int]:
    """CAN channel number -> its bus's bitrate from run.json."""
    return {
        channel: int(info.get("bitrate") or DEFAULT_BITRATE)
        for channel, (_, info) in bus_names_by_channel(header).items()
    }


def bus_metrics(metrics: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Each bus's scheduler snapshot in metrics.json (``buses.<name>``), when recorded."""
    buses = metrics.get("buses")
    if not isinstance(buses, dict):
        return {}
    return {name: bus for name, bus in buses.items() if isinstance(bus, dict)}


# -- figures -------------------------------------------------------------------------------

#: Panels a row in the per-servo figures (Figs. 4 and 5): nine servos make a 3 x 3 grid.
MAX_GRID_COLUMNS = 3


def _figure(rows: int = 1, cols: int = 1, height: float = 4.0, sharex: bool = False):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, height), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols, sharex=sharex, squeeze=False)
    return fig, axes


def _empty(ax: Any, text: str) -> None:
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, color="gray")


def _colour(index: int) -> Any:
    """A distinct colour per servo: tab10 up to ten servos, tab20 beyond (C0..C9 repeat)."""
    from matplotlib import colormaps

    return f"C{index}" if index < 10 else colormaps["tab20"](index % 20)


def plot_response(run: Run, path: Path) -> Any:
    """Fig. 3: commanded vs measured position, velocity and current over time.

    One legend for the figure, outside on the right: a colour per servo and the two line
    styles (dashed commanded, solid measured), not two entries per servo (9 servos made 18,
    and the legend beside the first panel pushed a gap under it)."""
    from matplotlib.lines import Line2D

    fig, axes = _figure(3, 1, height=8.0, sharex=True)
    ax_pos, ax_vel, ax_cur = axes[0][0], axes[1][0], axes[2][0]
    handles: list[Any] = []
    for index, (name, trace) in enumerate(sorted(run.servos.items())):
        colour = _colour(index)
        if not (trace.setpoint_t or trace.state_t):
            continue
        if trace.setpoint_t:
            ax_pos.step(
                trace.setpoint_t,
                trace.setpoint_deg,
                where="post",
                color=colour,
                linestyle="--",
                linewidth=1.0,
            )
        if trace.state_t:
            ax_pos.plot(trace.state_t, trace.position_deg, color=colour, linewidth=1.2)
            ax_vel.plot(trace.state_t, trace.velocity_dps, color=colour, linewidth=1.0)
            ax_cur.plot(trace.state_t, trace.current_a, color=colour, linewidth=1.0)
        handles.append(Line2D([], [], color=colour, linewidth=2.0, label=name))
    if handles:
        handles += [
            Line2D([], [], color="black", linestyle="--", label="commanded"),
            Line2D([], [], color="black", linestyle="-", label="measured"),
        ]
        fig.legend(handles=handles, loc="outside right upper", fontsize="small")
    else:
        _empty(ax_pos, "no setpoints or telemetry recorded")
    ax_pos.set_ylabel("position [deg]")
    ax_vel.set_ylabel("velocity [deg/s]")
    ax_cur.set_ylabel("current [A]")
    ax_cur.set_xlabel("time since start [s]")
    fig.suptitle("Commanded vs measured response (paper Fig. 3)")
    for ax in (ax_pos, ax_vel, ax_cur):
        ax.grid(True, alpha=0.3)
    fig.savefig(path, dpi=100)
    return fig  # for tests: legends and panels are asserted on the objects


def _servo_grid(count: int, panel_height: float = 2.2):
    """One small panel per servo (at most three a row), sharing both axes: nine servos'
    intervals in one axes were nine overlapping scatter series."""
    cols = max(1, min(MAX_GRID_COLUMNS, count))
    rows = max(1, math.ceil(count / cols))
    fig, axes = _figure(rows, cols, height=max(3.5, panel_height * rows + 1.0))
    flat = [ax for row in axes for ax in row]
    for ax in flat[count:]:
        ax.set_visible(False)
    return fig, flat[: max(1, count)]


def state_interval_p50_ms(run: Run, name: str, intervals_ms: list[float]) -> float:
    """A servo's state interval p50 in ms as metrics.json has it (``state_interval_s.p50``,
    the summary's ``state p50``), else from the trace's intervals."""
    recorded = (scheduler_servo_metrics(run.metrics).get(name) or {}).get("state_interval_s")
    if isinstance(recorded, dict) and isinstance(recorded.get("p50"), int | float):
        return float(recorded["p50"]) * 1e3
    return percentile(sorted(intervals_ms), 50)


def _plot_intervals(
    run: Run,
    path: Path,
    draw: Callable[[Any, Any, list[float], float], None],
    xlabel: str,
    ylabel: str,
    title: str,
) -> Any:
    """One panel per servo with at least two states, ``draw(ax, colour, intervals_ms, p50)``."""
    named = [
        (index, name, [v * 1e3 for v in trace.intervals_s()])
        for index, (name, trace) in enumerate(sorted(run.servos.items()))
    ]
    named = [entry for entry in named if entry[2]]
    fig, axes = _servo_grid(len(named))
    if not named:
        _empty(axes[0], "fewer than two telemetry samples per servo")
    for ax, (index, name, intervals_ms) in zip(axes, named, strict=False):
        p50 = state_interval_p50_ms(run, name, intervals_ms)
        draw(ax, _colour(index), intervals_ms, p50)
        ax.set_title(f"{name}: state p50 {p50:.1f} ms", fontsize="small")
        ax.grid(True, alpha=0.3)
    fig.supxlabel(xlabel)
    fig.supylabel(ylabel)
    fig.suptitle(title)
    fig.savefig(path, dpi=100)
    return fig  # for tests: legends and panels are asserted on the objects


def plot_interval_histogram(run: Run, path: Path) -> Any:
    """Fig. 4: distribution of state intervals (time between decoded states), p50 marked."""

    def draw(ax: Any, colour: Any, intervals_ms: list[float], p50: float) -> None:
        ax.hist(intervals_ms, bins=40, color=colour, alpha=0.8)
        ax.axvline(p50, color="k", linestyle="--", linewidth=1.0)

    return _plot_intervals(
        run,
        path,
        draw,
        "state interval [ms]",
        "count",
        "State interval: time between decoded states, every reply and push (paper Fig. 4)",
    )


def plot_interval_sequence(run: Run, path: Path) -> Any:
    """Fig. 5: state interval over successive states."""

    def draw(ax: Any, colour: Any, intervals_ms: list[float], p50: float) -> None:
        ax.plot(range(1, len(intervals_ms) + 1), intervals_ms, ".", markersize=3, color=colour)
        ax.axhline(p50, color="k", linestyle="--", linewidth=1.0)

    return _plot_intervals(
        run,
        path,
        draw,
        "state (n-th decoded state of the servo)",
        "state interval [ms]",
        "State interval over successive states (paper Fig. 5)",
    )


#: Shortest duration drawn on the stage plot's log axis (a 0 s stage would vanish).
_STAGE_FLOOR_MS = 1e-3


def plot_latency_stages(run: Run, path: Path) -> Any:
    """Each stage's distribution on a log axis, and the round-trip histogram.

    A log axis because the stages differ a thousandfold (accept ~0.1 ms, publish up to a
    telemetry period): stacked linearly, the first stage was invisible."""
    fig, axes = _figure(1, 2, height=4.5)
    ax_stages, ax_hist = axes[0][0], axes[0][1]
    samples = stage_samples(run.latency_rows)
    drawn = [stage for stage in STAGES if samples[stage]]
    if drawn:
        data = [[max(v * 1e3, _STAGE_FLOOR_MS) for v in samples[s]] for s in drawn]
        boxes = ax_stages.boxplot(
            data,
            orientation="horizontal",
            whis=(5, 95),
            showfliers=False,
            patch_artist=True,
            medianprops={"color": "black"},
            tick_labels=[f"{s}\n{STAGE_DESCRIPTIONS[s].split(' (')[0]}" for s in drawn],
        )
        for index, box in enumerate(boxes["boxes"]):
            box.set_facecolor(f"C{STAGES.index(drawn[index])}")
            box.set_alpha(0.7)
        ax_stages.set_xscale("log")
        ax_stages.invert_yaxis()  # the order a command passes through them, top down
        ax_stages.tick_params(axis="y", labelsize="x-small")
    else:
        _empty(ax_stages, "no command stage recorded")
    round_trip_ms = [v * 1e3 for v in samples["round_trip"]]
    if round_trip_ms:
        ax_hist.hist(round_trip_ms, bins=40, color="C2", alpha=0.8)
        stats = summarize(round_trip_ms)
        for q, style in (("p50", "-"), ("p95", "--"), ("p99", ":")):
            ax_hist.axvline(
                stats[q], color="k", linestyle=style, linewidth=1.0, label=f"{q} {stats[q]:.2f} ms"
            )
        ax_hist.legend(fontsize="small")
    else:
        _empty(ax_hist, "no round trips recorded")
    ax_stages.set_xlabel("stage duration [ms], log scale (box p25-p75, whiskers p5-p95)")
    ax_stages.set_title("Latency by stage (paper eq. 1)")
    ax_hist.set_xlabel("stage round_trip: written -> reply decoded [ms]")
    ax_hist.set_ylabel("count")
    ax_hist.set_title("round_trip distribution (new setpoints)")
    for ax in (ax_stages, ax_hist):
        ax.grid(True, alpha=0.3)
    fig.savefig(path, dpi=100)
    return fig  # for tests: legends and panels are asserted on the objects


def plot_bus_load(run: Run, path: Path, series: LoadSeries) -> Any:
    """Bus load R over the sliding window per bus, with its peak, plan and budget."""
    fig, axes = _figure()
    ax = axes[0][0]
    names = bus_names_by_channel(run.header)
    recorded = bus_metrics(run.metrics)
    if series:
        for channel, (times, loads) in sorted(series.items()):
            name, info = names.get(channel, (f"channel {channel}", {}))
            colour = _colour(channel)
            figures = load_figures(recorded.get(name), loads)
            ax.step(
                times,
                [100 * v for v in loads],
                where="post",
                color=colour,
                linewidth=0.8,
                label=f"{name}: peak {100 * figures['peak']:.2f} %",
            )
            if figures.get("planned") is not None:
                ax.axhline(
                    100 * figures["planned"],
                    color=colour,
                    linestyle=":",
                    linewidth=1.0,
                    label=f"{name}: planned {100 * figures['planned']:.2f} %",
                )
            if info.get("max_load"):
                ax.axhline(
                    100.0 * float(info["max_load"]),
                    color=colour,
                    linestyle="--",
                    linewidth=1.0,
                    label=f"{name}: budget max_load {100 * float(info['max_load']):.0f} %",
                )
        ax.legend(fontsize="small", loc="best")
    else:
        _empty(ax, "no CAN frames recorded")
    ax.set_xlabel("time since start [s]")
    ax.set_ylabel("bus load R [%] (worst-case stuffing)")
    ax.set_title(f"Bus load R over the last {LOAD_WINDOW_S:g} s, at every frame")
    ax.set_ylim(bottom=0)
    ax.grid(True, alpha=0.3)
    fig.savefig(path, dpi=100)
    return fig  # for tests: legends and panels are asserted on the objects


# -- summary -------------------------------------------------------------------------------


def _ms(value: Any) -> str:
    return "n/a" if value is None else f"{float(value) * 1e3:.2f}"


def _pct(value: Any) -> str:
    return "n/a" if value is None else f"{float(value) * 100:.2f}"


def scheduler_servo_metrics(metrics: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Per-servo dicts of ``scheduler.metrics()`` snapshots found in metrics.json.

    The bridge may hand over one scheduler's snapshot (``{"servos": ...}``) or one per bus
    (``{"bus0": {"servos": ...}}``); both are accepted.
    """
    found: dict[str, dict[str, Any]] = {}
    candidates = [metrics, *(v for v in metrics.values() if isinstance(v, dict))]
    for candidate in candidates:
        servos = candidate.get("servos")
        if isinstance(servos, dict):
            found.update({k: v for k, v in servos.items() if isinstance(v, dict)})
    return found


def load_figures(recorded: dict[str, Any] | None, loads: Sequence[float]) -> dict[str, Any]:
    """A bus's ``load.mean``/``load.peak``/``load.planned`` as metrics.json has them (the
    summary's figures); a run without them (killed, old) gets peak and mean from the log."""
    load = (recorded or {}).get("load")
    if isinstance(load, dict) and isinstance(load.get("peak"), int | float):
        return {k: load.get(k) for k in ("mean", "peak", "planned")}
    return {
        "mean": sum(loads) / len(loads) if loads else None,
        "peak": max(loads, default=0.0),
        "planned": None,
    }


def stage_figures(run: Run) -> dict[str, dict[str, Any]]:
    """Per stage n, mean, p50/p95/p99 in seconds: metrics.json ``latency.stages`` when
    written (the same numbers the bridge computed), else from latency.csv."""
    recorded = (run.metrics.get("latency") or {}).get("stages")
    if isinstance(recorded, dict) and all(isinstance(recorded.get(s), dict) for s in STAGES):
        return {stage: recorded[stage] for stage in STAGES}
    samples = stage_samples(run.latency_rows)
    return {stage: summarize(samples[stage]) for stage in STAGES}


def summary_rows(run: Run, series: LoadSeries) -> list[tuple[str, str]]:
    """Run-wide rows (quantity, value); per-servo and per-bus figures are in their tables."""
    rows: list[tuple[str, str]] = []
    for stage, s in stage_figures(run).items():
        rows.append(
            (
                f"Stage {stage}: {STAGE_DESCRIPTIONS[stage]} (mean / p50 / p95 / p99) [ms]",
                " / ".join(_ms(s.get(k)) for k in ("mean", "p50", "p95", "p99"))
                + f" (n={s.get('n', 0)})",
            )
        )
    outcomes: dict[str, int] = defaultdict(int)
    for row in run.latency_rows:
        outcomes[row.get("outcome", "?")] += 1
    kinds = ("complete", "superseded", "timed_out", "open")
    rows.append(
        (
            "Commands traced (" + " / ".join(kinds) + ")",
            " / ".join(str(outcomes.get(k, 0)) for k in kinds),
        )
    )
    tx = sum(1 for m in run.frames if not m.is_rx)
    rx = sum(1 for m in run.frames if m.is_rx)
    rows.append(("CAN frames TX / RX", f"{tx} / {rx}"))
    rows.append(
        (
            "Telemetry samples with a fault flag",
            str(sum(t.fault_samples for t in run.servos.values())),
        )
    )
    rows.append(("Decoder rejections", str(run.rejections)))
    dropped = run.metrics.get("runlog", {}).get("dropped_total")
    rows.append(("Log lines dropped (slow disk)", "n/a" if dropped is None else str(dropped)))
    return rows


def servo_table(run: Run) -> list[str]:
    """Per servo, the run summary's columns under the same names, from metrics.json."""
    from mavservo.app.console import FRAME_COLUMNS, TIMING_COLUMNS

    servos = scheduler_servo_metrics(run.metrics)
    if not servos:
        return ["No scheduler metrics recorded (metrics.json missing or from a killed run)."]
    heads = [h for h, _, _ in FRAME_COLUMNS] + [f"{h} [ms]" for h, _, _, _ in TIMING_COLUMNS]
    lines = ["| servo | " + " | ".join(heads) + " |", "|---" * (len(heads) + 1) + "|"]
    for name, data in sorted(servos.items()):
        frames = data.get("frames") or {}
        cells = [str(frames.get(key, 0)) for _, _, key in FRAME_COLUMNS]
        cells += [_ms((data.get(group) or {}).get(key)) for _, _, group, key in TIMING_COLUMNS]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines += ["", glossary_text() + " (the console's and the summary's words, docs/logs.md)."]
    return lines


def bus_table(run: Run, series: LoadSeries) -> list[str]:
    """Per bus, load R mean / peak / planned (the summary's names) and the budget, in %."""
    lines = [
        "| bus | load R mean [%] | peak [%] | planned [%] | budget max_load [%] |",
        "|---|---|---|---|---|",
    ]
    recorded = bus_metrics(run.metrics)
    by_name = {name: channel for channel, (name, _) in bus_names_by_channel(run.header).items()}
    for name in sorted(set(recorded) | set(by_name)):
        loads = series.get(by_name[name], ([], []))[1] if name in by_name else []
        figures = load_figures(recorded.get(name), loads)
        budget = ((run.header.get("buses") or {}).get(name) or {}).get("max_load")
        cells = [_pct(figures[k]) for k in ("mean", "peak", "planned")] + [_pct(budget)]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines


def _event_lines(metrics: dict[str, Any]) -> list[str]:
    """What went wrong during the run, from ``metrics.json``: the bridge's events (adapter
    lost and back, failsafe, ...) and each bus's outages and failed sends and receives."""
    lines = ["## Events", ""]
    events = metrics.get("events") or []
    lines += [f"- {text}" for text in events] or ["- none"]
    for name, bus in (metrics.get("buses") or {}).items():
        for kind in ("send_failures", "receive_failures"):
            failures = bus.get(kind) or {}
            if failures.get("total"):
                what = kind.replace("_failures", "s")
                lines.append(
                    f"- bus {name}: {failures['total']} failed {what} in "
                    f"{failures.get('outages', 0)} outage(s)"
                )
    return [*lines, ""]


def health_lines(metrics: dict[str, Any]) -> list[str]:
    """The bridge's own servo health checks (docs/health.md), from ``metrics.json``'s
    ``health``: episodes per servo and check, and each transition with its text."""
    health = metrics.get("health")
    if not isinstance(health, dict):
        return []
    lines = ["## Servo health", ""]
    judged = health.get("judged") or {}
    episodes = health.get("episodes") or {}
    lines.append(
        f"{sum(judged.values()) if judged else 0} states judged; "
        + (
            "episodes: "
            + "; ".join(
                f"{servo} " + ", ".join(f"{check} {n}" for check, n in checks.items())
                for servo, checks in episodes.items()
            )
            if episodes
            else "no health events"
        )
    )
    lines.append("")
    for event in health.get("events") or []:
        state = "onset" if event.get("active") else "cleared"
        said = "" if event.get("announced", True) else " (not announced: text spacing)"
        lines.append(f"- {state}: {event.get('text', '')}{said}")
    return [*lines, ""]


def write_markdown(
    run: Run,
    out_dir: Path,
    rows: list[tuple[str, str]],
    series: LoadSeries,
    figures: dict[str, Path],
) -> Path:
    header = run.header
    lines = [
        f"# mavservo run report: {run.directory.name}",
        "",
        f"- started: {header.get('start_wall_iso', 'unknown')}",
        f"- config: {header.get('config_path') or 'n/a'}",
        "- versions: " + ", ".join(f"{k} {v}" for k, v in (header.get("versions") or {}).items()),
        f"- servos: {', '.join(sorted(run.servos)) or 'none recorded'}",
        f"- CAN log read: {run.frames_format or 'none'} ({len(run.frames)} frames)",
        "",
        "## Summary (paper Table 2 quantities)",
        "",
        "Every figure is defined in docs/logs.md, under the name the run summary and",
        "metrics.json give it.",
        "",
        "| quantity | value |",
        "|---|---|",
        *(f"| {name} | {value} |" for name, value in rows),
        "",
        "## Per servo",
        "",
        *servo_table(run),
        "",
        "## Per bus",
        "",
        *bus_table(run, series),
        "",
        *_event_lines(run.metrics),
        *health_lines(run.metrics),
        "## Figures",
        "",
    ]
    titles = {
        "response": "Commanded vs measured position, velocity, current (Fig. 3)",
        "interval_histogram": "State interval histogram per servo (Fig. 4)",
        "interval_sequence": "State interval over successive states per servo (Fig. 5)",
        "latency_stages": "Latency by stage and the round_trip distribution",
        "bus_load": "Bus load over time",
    }
    for key, path in figures.items():
        rel = path.relative_to(out_dir)
        lines += [f"### {titles[key]}", "", f"![{titles[key]}]({rel.as_posix()})", ""]
    report = out_dir / REPORT_FILE
    report.write_text("\n".join(lines), encoding="utf-8")
    return report


def generate(directory: str | Path, out_dir: str | Path | None = None) -> dict[str, Path]:
    """Write every figure and ``report.md``; returns their paths keyed by figure name."""
    run = load_run(directory)
    out = Path(out_dir) if out_dir is not None else run.directory / "report"
    out.mkdir(parents=True, exist_ok=True)
    series = bus_load_series(run.frames, run.start_wall, channel_bitrates(run.header))
    figures = {key: out / name for key, name in FIGURES.items()}
    plot_response(run, figures["response"])
    plot_interval_histogram(run, figures["interval_histogram"])
    plot_interval_sequence(run, figures["interval_sequence"])
    plot_latency_stages(run, figures["latency_stages"])
    plot_bus_load(run, figures["bus_load"], series)
    report = write_markdown(run, out, summary_rows(run, series), series, figures)
    return {**figures, "report": report}


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point for ``mavservo report LOGDIR [--out DIR]``."""
    parser = argparse.ArgumentParser(
        prog="mavservo report",
        description="Write PNG figures and a markdown summary for a recorded run directory.",
    )
    parser.add_argument("logdir", help="run directory (contains run.json)")
    parser.add_argument("--out", help="output directory (default: LOGDIR/report)")
    args = parser.parse_args(argv)
    from rich.console import Console
    from rich.markup import escape

    console = Console(stderr=True)
    try:
        import matplotlib  # noqa: F401 - the figures need it; it is an optional extra
    except ImportError:
        console.print(
            # escaped: rich would take "[report]" for markup and print pip install 'mavservo'
            escape(
                "mavservo report needs matplotlib: pip install 'mavservo[report]' "
                "(from a clone: pip install '.[report]')"
            ),
            highlight=False,
            soft_wrap=True,
        )
        return 2
    try:
        paths = generate(args.logdir, args.out)
    except ReportError as exc:
        console.print(f"[bold red]error:[/] {exc}", highlight=False, soft_wrap=True)
        return 2
    for key, path in paths.items():
        console.print(f"wrote {key}: {path}", highlight=False, soft_wrap=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
