"""``mavservo report LOGDIR``: figures and a short markdown summary of one recorded run.

It works from the files of a run directory alone (see ``docs/logs.md``), so a user can run it
on a directory copied off the drone. Figures follow the paper: commanded vs measured response
(Fig. 3), telemetry reception interval histogram (Fig. 4) and sequence (Fig. 5), plus what the
paper did not show: the latency split into host-visible stages and the bus load over time.
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
from mavservo.records import runlog
from mavservo.records.latency import STAGE_DESCRIPTIONS, STAGES, summarize

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
        """Reception intervals of successive decoded states: every reply (telemetry polls,
        command replies and pushes), so shorter than the poll period; the scheduler's poll-only
        intervals are in metrics.json (telemetry_interval_s) and the run summary."""
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
    header_path = directory / runlog.RUN_HEADER
    if not directory.is_dir():
        raise ReportError(f"{directory}: no such directory")
    if not header_path.is_file():
        raise ReportError(
            f"{directory} is not a mavservo run directory (no {runlog.RUN_HEADER}); "
            "point at a directory written by 'mavservo run' under logging.dir"
        )
    try:
        header = json.loads(header_path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise ReportError(f"{header_path}: unreadable run header ({exc})") from exc
    if header.get("format") != "mavservo-run":
        raise ReportError(f"{header_path}: not a mavservo run header")
    start = float(header.get("start_monotonic", 0.0))

    servos: dict[str, ServoTrace] = defaultdict(ServoTrace)
    trace_path = directory / runlog.TRACE_FILE
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
    latency_path = directory / runlog.LATENCY_FILE
    if latency_path.is_file():
        with latency_path.open(newline="", encoding="utf-8") as handle:
            latency_rows = list(csv.DictReader(handle))

    frames: list[Any] = []
    frames_format = None
    for fmt in ("blf", "asc", "log", "csv"):
        if runlog.can_log_files(directory, fmt):
            frames = runlog.read_can_log(directory, fmt)
            frames_format = fmt
            break

    metrics: dict[str, Any] = {}
    metrics_path = directory / runlog.METRICS_FILE
    if metrics_path.is_file():
        try:
            metrics = json.loads(metrics_path.read_text(encoding="utf-8"))
        except json.JSONDecodeError:
            metrics = {}

    rejections = 0
    rejections_path = directory / runlog.REJECTIONS_FILE
    if rejections_path.is_file():
        with rejections_path.open(encoding="utf-8") as handle:
            rejections = sum(1 for line in handle if line.strip())

    return Run(
        directory, header, dict(servos), latency_rows, frames, frames_format, metrics, rejections
    )


# -- derived series (pure) -----------------------------------------------------------------

#: Per CAN channel: window start times (s since the run's start) and the bits in each window.
LoadSeries = dict[int, tuple[list[float], list[int]]]


def stage_samples(rows: Sequence[dict[str, str]]) -> dict[str, list[float]]:
    """Per-stage durations (seconds) from latency.csv rows, skipping missing stages."""
    out: dict[str, list[float]] = {stage: [] for stage in STAGES}
    for row in rows:
        for stage in STAGES:
            value = _float(row.get(f"{stage}_s", ""))
            if value is not None:
                out[stage].append(value)
    return out


def complete_commands(rows: Sequence[dict[str, str]]) -> list[dict[str, float]]:
    """Stage durations of commands that reached at least a decoded reply (for stacking)."""
    out = []
    for row in rows:
        stages = {stage: _float(row.get(f"{stage}_s", "")) for stage in STAGES}
        if stages["round_trip"] is None:
            continue
        out.append({stage: value or 0.0 for stage, value in stages.items()})
    return out


def bus_load_series(
    frames: Sequence[Any], start_wall: float, window_s: float = LOAD_WINDOW_S
) -> LoadSeries:
    """Per CAN channel: window start times (s since run start) and bits on the wire per window.

    Every frame counts with its worst-case stuffed length (``busload.message_bits``), TX and RX
    alike: both occupy the same bus.
    """
    from mavservo.scheduling.busload import message_bits

    bins: dict[int, dict[int, int]] = defaultdict(lambda: defaultdict(int))
    for msg in frames:
        channel = msg.channel if isinstance(msg.channel, int) else 0
        index = int(math.floor((msg.timestamp - start_wall) / window_s))
        bins[channel][index] += message_bits(msg)
    series: LoadSeries = {}
    for channel, by_index in bins.items():
        if not by_index:
            continue
        first, last = min(by_index), max(by_index)
        indices = range(first, last + 1)
        series[channel] = ([i * window_s for i in indices], [by_index.get(i, 0) for i in indices])
    return series


def bus_names_by_channel(header: dict[str, Any]) -> dict[int, tuple[str, dict[str, Any]]]:
    out = {}
    for name, info in (header.get("buses") or {}).items():
        if isinstance(info, dict) and isinstance(info.get("channel"), int):
            out[info["channel"]] = (name, info)
    return out


# -- figures -------------------------------------------------------------------------------


def _figure(rows: int = 1, cols: int = 1, height: float = 4.0, sharex: bool = False):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, height), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols, sharex=sharex, squeeze=False)
    return fig, axes


def _empty(ax: Any, text: str) -> None:
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, color="gray")


def plot_response(run: Run, path: Path) -> None:
    """Fig. 3: commanded vs measured position, velocity and current over time."""
    fig, axes = _figure(3, 1, height=8.0, sharex=True)
    ax_pos, ax_vel, ax_cur = axes[0][0], axes[1][0], axes[2][0]
    plotted = False
    for index, (name, trace) in enumerate(sorted(run.servos.items())):
        color = f"C{index % 10}"
        if trace.setpoint_t:
            ax_pos.step(
                trace.setpoint_t,
                trace.setpoint_deg,
                where="post",
                color=color,
                linestyle="--",
                linewidth=1.0,
                label=f"{name} commanded",
            )
            plotted = True
        if trace.state_t:
            ax_pos.plot(
                trace.state_t,
                trace.position_deg,
                color=color,
                linewidth=1.2,
                label=f"{name} measured",
            )
            ax_vel.plot(trace.state_t, trace.velocity_dps, color=color, linewidth=1.0, label=name)
            ax_cur.plot(trace.state_t, trace.current_a, color=color, linewidth=1.0, label=name)
            plotted = True
    if not plotted:
        _empty(ax_pos, "no setpoints or telemetry recorded")
    ax_pos.set_ylabel("position [deg]")
    ax_vel.set_ylabel("velocity [deg/s]")
    ax_cur.set_ylabel("current [A]")
    ax_cur.set_xlabel("time since start [s]")
    ax_pos.set_title("Commanded vs measured response (paper Fig. 3)")
    for ax in (ax_pos, ax_vel, ax_cur):
        ax.grid(True, alpha=0.3)
    if plotted:
        # outside the axes: with many servos an inside legend hides the traces
        ax_pos.legend(fontsize="x-small", loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.savefig(path, dpi=100)


def _plot_intervals(
    run: Run,
    path: Path,
    draw: Callable[[Any, str, str, list[float]], None],
    xlabel: str,
    ylabel: str,
    title: str,
) -> None:
    """One axes, one colour per servo, ``draw(ax, colour, name, intervals_ms)`` per servo."""
    fig, axes = _figure()
    ax = axes[0][0]
    any_data = False
    for index, (name, trace) in enumerate(sorted(run.servos.items())):
        intervals_ms = [v * 1e3 for v in trace.intervals_s()]
        if intervals_ms:
            any_data = True
            draw(ax, f"C{index % 10}", name, intervals_ms)
    if any_data:
        ax.legend(fontsize="small")
    else:
        _empty(ax, "fewer than two telemetry samples per servo")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    fig.savefig(path, dpi=100)


def plot_interval_histogram(run: Run, path: Path) -> None:
    """Fig. 4: distribution of reply reception intervals."""

    def draw(ax: Any, colour: str, name: str, intervals_ms: list[float]) -> None:
        mean = sum(intervals_ms) / len(intervals_ms)
        ax.hist(
            intervals_ms, bins=40, alpha=0.6, color=colour, label=f"{name} (mean {mean:.1f} ms)"
        )
        ax.axvline(mean, color=colour, linestyle="--", linewidth=1.0)

    _plot_intervals(
        run,
        path,
        draw,
        "reception interval [ms]",
        "count",
        "Reception intervals of every decoded reply (paper Fig. 4)",
    )


def plot_interval_sequence(run: Run, path: Path) -> None:
    """Fig. 5: reception interval over successive samples."""

    def draw(ax: Any, colour: str, name: str, intervals_ms: list[float]) -> None:
        ax.plot(
            range(1, len(intervals_ms) + 1),
            intervals_ms,
            ".",
            markersize=3,
            color=colour,
            label=name,
        )

    _plot_intervals(
        run,
        path,
        draw,
        "sample",
        "reception interval [ms]",
        "Reception intervals over successive samples (paper Fig. 5)",
    )


def plot_latency_stages(run: Run, path: Path) -> None:
    """Per-command latency with its stages stacked (sorted by total), and the L histogram."""
    fig, axes = _figure(1, 2, height=4.5)
    ax_stack, ax_hist = axes[0][0], axes[0][1]
    commands = complete_commands(run.latency_rows)
    if commands:
        commands.sort(key=lambda c: sum(c.values()))
        # One filled area per stage, not one bar per command: a 400 s run has ~100,000
        # commands, and bars took two minutes and 1 GB to draw; the areas look the same.
        ax_stack.stackplot(
            range(len(commands)),
            *([c[stage] * 1e3 for c in commands] for stage in STAGES),
            labels=[STAGE_DESCRIPTIONS[stage] for stage in STAGES],
            colors=[f"C{index}" for index in range(len(STAGES))],
            step="post",
            linewidth=0,
        )
        ax_stack.legend(fontsize="x-small", loc="upper left")
        round_trip_ms = [c["round_trip"] * 1e3 for c in commands]
        ax_hist.hist(round_trip_ms, bins=40, color="C2", alpha=0.8)
        stats = summarize(round_trip_ms)
        for q, style in (("p50", "-"), ("p95", "--"), ("p99", ":")):
            ax_hist.axvline(
                stats[q], color="k", linestyle=style, linewidth=1.0, label=f"{q} {stats[q]:.2f} ms"
            )
        ax_hist.legend(fontsize="small")
    else:
        _empty(ax_stack, "no command reached a decoded reply")
        _empty(ax_hist, "no round trips recorded")
    ax_stack.set_xlabel("command (sorted by total latency)")
    ax_stack.set_ylabel("latency [ms]")
    ax_stack.set_title("Latency by stage (paper eq. 1)")
    ax_hist.set_xlabel("round trip L: written -> reply decoded [ms]")
    ax_hist.set_ylabel("count")
    ax_hist.set_title("Latency distribution")
    for ax in (ax_stack, ax_hist):
        ax.grid(True, alpha=0.3)
    fig.savefig(path, dpi=100)


def plot_bus_load(run: Run, path: Path, series: LoadSeries) -> None:
    """Bus load R per 1 s window for each bus, with its configured budget."""
    fig, axes = _figure()
    ax = axes[0][0]
    names = bus_names_by_channel(run.header)
    if series:
        for channel, (times, bits) in sorted(series.items()):
            name, info = names.get(channel, (f"channel {channel}", {}))
            bitrate = int(info.get("bitrate") or DEFAULT_BITRATE)
            load_pct = [100.0 * b / (LOAD_WINDOW_S * bitrate) for b in bits]
            ax.step(
                times,
                load_pct,
                where="post",
                color=f"C{channel % 10}",
                label=f"{name} @ {bitrate / 1000:.0f} kbit/s",
            )
            if info.get("max_load"):
                ax.axhline(
                    100.0 * float(info["max_load"]),
                    color=f"C{channel % 10}",
                    linestyle="--",
                    linewidth=1.0,
                    label=f"{name} budget R_max",
                )
        ax.legend(fontsize="small")
    else:
        _empty(ax, "no CAN frames recorded")
    ax.set_xlabel("time since start [s]")
    ax.set_ylabel("bus load R [%] (worst-case stuffing)")
    ax.set_title(f"Bus load over {LOAD_WINDOW_S:g} s windows")
    ax.set_ylim(bottom=0)
    ax.grid(True, alpha=0.3)
    fig.savefig(path, dpi=100)


# -- summary -------------------------------------------------------------------------------


def _ms(value: Any) -> str:
    return "n/a" if value is None else f"{float(value) * 1e3:.2f}"


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


def summary_rows(run: Run, series: LoadSeries) -> list[tuple[str, str]]:
    """Table-2 style rows: (quantity, value)."""
    rows: list[tuple[str, str]] = []
    stages = stage_samples(run.latency_rows)
    round_trip = summarize(stages["round_trip"])
    rows.append(
        (
            "Latency L, round trip (mean / p50 / p95 / p99) [ms]",
            " / ".join(_ms(round_trip.get(k)) for k in ("mean", "p50", "p95", "p99")),
        )
    )
    rows.append(("Jitter sigma_L [ms]", _ms(round_trip.get("sigma"))))
    for stage in STAGES:
        s = summarize(stages[stage])
        rows.append(
            (
                f"Stage {stage}: {STAGE_DESCRIPTIONS[stage]} (p50 / p95 / p99) [ms]",
                " / ".join(_ms(s.get(k)) for k in ("p50", "p95", "p99")) + f" (n={s['n']})",
            )
        )
    intervals = [v for trace in run.servos.values() for v in trace.intervals_s()]
    iv = summarize(intervals)
    rows.append(
        (
            "Reply reception interval, all replies (mean / sigma / p99) [ms]",
            " / ".join(_ms(iv.get(k)) for k in ("mean", "sigma", "p99")),
        )
    )
    outcomes: dict[str, int] = defaultdict(int)
    for row in run.latency_rows:
        outcomes[row.get("outcome", "?")] += 1
    rows.append(
        (
            "Commands traced (complete / superseded / lost / open)",
            " / ".join(str(outcomes.get(k, 0)) for k in ("complete", "superseded", "lost", "open")),
        )
    )
    tx = sum(1 for m in run.frames if not m.is_rx)
    rx = sum(1 for m in run.frames if m.is_rx)
    rows.append(("CAN frames TX / RX", f"{tx} / {rx}"))
    rows.append(("Replies lost (timeouts)", str(sum(t.lost for t in run.servos.values()))))
    rows.append(
        (
            "Telemetry samples with a fault flag",
            str(sum(t.fault_samples for t in run.servos.values())),
        )
    )
    rows.append(("Decoder rejections", str(run.rejections)))
    dropped = run.metrics.get("runlog", {}).get("dropped_total")
    rows.append(("Log lines dropped (slow disk)", "n/a" if dropped is None else str(dropped)))
    for servo, data in sorted(scheduler_servo_metrics(run.metrics).items()):
        lat = data.get("latency_s") or {}
        frames = data.get("frames") or {}
        if lat.get("n"):
            rows.append(
                (
                    f"Scheduler {servo}: L, commands and refreshes (written -> reply decoded) "
                    "(mean / sigma / p99) [ms]",
                    " / ".join(_ms(lat.get(k)) for k in ("mean", "sigma", "p99"))
                    + f" (n={lat['n']})",
                )
            )
        if frames:
            rows.append(
                (
                    f"Scheduler {servo}: frames sent / received / lost / late",
                    " / ".join(
                        str(frames.get(k, 0)) for k in ("sent", "received", "lost", "late_replies")
                    ),
                )
            )
    names = bus_names_by_channel(run.header)
    for channel, (_, bits) in sorted(series.items()):
        name, info = names.get(channel, (f"channel {channel}", {}))
        bitrate = int(info.get("bitrate") or DEFAULT_BITRATE)
        loads = [b / (LOAD_WINDOW_S * bitrate) for b in bits]
        budget = info.get("max_load")
        rows.append(
            (
                f"Bus utilization {name} (mean / peak) [%]",
                f"{100 * sum(loads) / len(loads):.2f} / {100 * max(loads):.2f}"
                + ("" if budget is None else f" (budget {100 * float(budget):.0f})"),
            )
        )
    return rows


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


def write_markdown(
    run: Run, out_dir: Path, rows: list[tuple[str, str]], figures: dict[str, Path]
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
        "| quantity | value |",
        "|---|---|",
        *(f"| {name} | {value} |" for name, value in rows),
        "",
        *_event_lines(run.metrics),
        "## Figures",
        "",
    ]
    titles = {
        "response": "Commanded vs measured position, velocity, current (Fig. 3)",
        "interval_histogram": "Telemetry reception interval histogram (Fig. 4)",
        "interval_sequence": "Reception intervals over successive samples (Fig. 5)",
        "latency_stages": "Latency by stage and its distribution",
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
    series = bus_load_series(run.frames, run.start_wall)
    figures = {key: out / name for key, name in FIGURES.items()}
    plot_response(run, figures["response"])
    plot_interval_histogram(run, figures["interval_histogram"])
    plot_interval_sequence(run, figures["interval_sequence"])
    plot_latency_stages(run, figures["latency_stages"])
    plot_bus_load(run, figures["bus_load"], series)
    report = write_markdown(run, out, summary_rows(run, series), figures)
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
