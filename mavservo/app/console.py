"""Terminal output of ``mavservo run``: a live one-line-per-servo status and the final summary.

On a terminal the status is a rich table refreshed in place; elsewhere (a pipe, a log file,
systemd's journal) it degrades to plain lines, one block every few seconds, so logs stay readable.

Every event and log line on the console has one format, :func:`console_line`::

    [18:05:40] WARNING scheduling.runner: scheduler bus0: servo aileron offline (no reply)
    [18:05:41] INFO    bridge: autopilot 1/1: heartbeat heard, 0.4 s after start

the bridge's own events (:meth:`StatusDisplay.event`) and Python logging records
(:class:`ConsoleFormatter`) alike, so a reader, ``grep`` or a journal sees one clock and one
place for the level instead of two styles.
"""

from __future__ import annotations

import logging
import math
import re
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.live import Live
from rich.table import Table

from mavservo.mavlink import WINDOW_S
from mavservo.records import LATE, LOST, OFFLINE, glossary_text

PLAIN_EVERY_S = 5.0
CLOCK_FORMAT = "%H:%M:%S"
#: Bridge events that report a recovery or a normal step; every other event is a problem.
_INFO_EVENTS = re.compile(
    r"back online|responding again|failsafe cleared|link recovered|heartbeat heard"
    r"|^stopped \(|^after the stop: |cleared "
    # a health check clearing (mavservo/control/health.py, its clearing texts)
    r"|: following again|: moving again|: no longer slipping|: overload over|: temperature back"
    r"|: supply back"
    r"|^MAVLink: servo component "  # the identity line: who the bridge is, not a problem
)
#: A later "no heartbeat" warning at most this often (the first comes after the link timeout).
NO_HEARTBEAT_REPEAT_S = 30.0


def console_line(level: str, source: str, text: str, when: float | None = None) -> str:
    """``[HH:MM:SS] LEVEL   source: text``: the one format of every console line."""
    stamp = time.strftime(CLOCK_FORMAT, time.localtime(when))
    return f"[{stamp}] {level:<7} {source}: {text}"


def event_level(text: str) -> str:
    """The level of a bridge event: INFO for recoveries and normal steps, WARNING otherwise
    (the bridge's events are one-line texts; their words are what tells them apart)."""
    return "INFO" if _INFO_EVENTS.search(text) else "WARNING"


class ConsoleFormatter(logging.Formatter):
    """Python logging records as :func:`console_line` (logger names without ``mavservo.``)."""

    def format(self, record: logging.LogRecord) -> str:
        source = record.name.removeprefix("mavservo.")
        line = console_line(record.levelname, source, record.getMessage(), record.created)
        if record.exc_info:
            line += "\n" + self.formatException(record.exc_info)
        return line


@dataclass
class HeartbeatNotices:
    """Says when the watched autopilot's HEARTBEAT is first heard, and warns while none has
    come: first after ``warn_after_s`` (the link timeout), then every ``repeat_s`` at most, so a
    bridge started on the wrong port says so instead of staying silent. Pure: times come in."""

    started: float
    warn_after_s: float
    repeat_s: float = NO_HEARTBEAT_REPEAT_S
    heard: bool = False
    _next_warning: float | None = None

    def check(
        self, source: tuple[int, int], last_heartbeat: float | None, now: float
    ) -> tuple[str, str] | None:
        """(level, text) to show now, or None. ``last_heartbeat``: when the autopilot at
        ``source`` (system, component) was last heard, None while never."""
        who = f"autopilot {source[0]}/{source[1]}"
        if last_heartbeat is not None:
            if self.heard:
                return None
            self.heard = True
            after = max(0.0, last_heartbeat - self.started)
            return "INFO", f"{who}: heartbeat heard, {after:.1f} s after start"
        if self.heard or now - self.started < self.warn_after_s:
            return None
        if self._next_warning is not None and now < self._next_warning:
            return None
        self._next_warning = now + self.repeat_s
        return "WARNING", (
            f"{who}: no heartbeat in {now - self.started:.0f} s since start; check mavlink.url "
            "and that the autopilot sends to it (repeated every "
            f"{self.repeat_s:.0f} s until heard)"
        )


def _num(value: float | None, fmt: str) -> str:
    """``value`` formatted, or "-" when it is not known: None (nothing reported yet) or NaN
    (a field the servo's family never reports, e.g. current on a DroneCAN actuator.Status).
    The "-" takes the format's width, so a status line keeps its columns before the first
    report as after it (issue 37)."""
    if value is None or math.isnan(value):
        width = fmt.partition(".")[0]
        return format("-", f">{width}") if width.isdigit() else "-"
    return format(value, fmt)


def liveness(row: dict[str, Any]) -> str:
    """ "online", "OFFLINE", or "waiting": not offline yet, but nothing reported so far (a
    servo is only "online" on the strength of a report; before its first one it is waiting)."""
    if not row["online"]:
        return "OFFLINE"
    return "waiting" if row["age_s"] is None else "online"


def status_line(row: dict[str, Any]) -> str:
    """One servo as a plain text line (also what the tests read)."""
    state = f"{liveness(row):<7}"
    return (
        f"{row['servo']:<16} {state} set {_num(row['setpoint_deg'], '7.1f')} deg  "
        f"pos {_num(row['position_deg'], '7.1f')} deg  "
        f"vel {_num(row['velocity_dps'], '7.1f')} dps  "
        f"I {_num(row['current_a'], '5.2f')} A  T {_num(row['temperature_c'], '5.1f')} C  "
        f"age {_num(None if row['age_s'] is None else row['age_s'] * 1000, '5.0f')} ms"
        + (f"  faults {row['faults']}" if row["faults"] else "")
        + (f"  health {row['health']}" if row.get("health") else "")
    )


class StatusDisplay:
    """Live status while the bridge runs; a context manager around the refresh loop."""

    def __init__(self, enabled: bool = True, stream: Any = None) -> None:
        self.enabled = enabled
        self.stream = stream or sys.stdout
        self.console = Console(file=self.stream)
        self.live: Live | None = None
        self._last_plain = 0.0

    @property
    def interactive(self) -> bool:
        return self.enabled and self.console.is_terminal

    def started(self, config_path: Path, bridge: Any) -> None:
        """Say what runs and where it connects, so hardware and simulation cannot be confused."""
        from mavservo.config import endpoint_lines

        line = f"mavservo: running {config_path}"
        if bridge.run_dir is not None:
            line += f"; logging to {bridge.run_dir}"
        lines = [line, *(f"  {text}" for text in endpoint_lines(bridge.config))]
        print("\n".join(lines), file=self.stream, flush=True)

    def event(self, text: str, level: str | None = None) -> None:
        """One bridge event as a :func:`console_line` (level from its words when not given)."""
        line = console_line(level or event_level(text), "bridge", text)
        if self.live is not None:
            # not markup: "[18:05:40]" would read as a style tag
            self.live.console.print(line, markup=False, highlight=False)
        else:
            print(line, file=self.stream, flush=True)

    def __enter__(self) -> StatusDisplay:
        if self.interactive:
            self.live = Live(Table(), console=self.console, refresh_per_second=5, transient=True)
            self.live.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        if self.live is not None:
            self.live.__exit__(None, None, None)
            self.live = None

    def update(self, rows: list[dict[str, Any]]) -> None:
        if not self.enabled or not rows:
            return
        if self.live is not None:
            self.live.update(self._table(rows))
            return
        now = time.monotonic()
        if now - self._last_plain >= PLAIN_EVERY_S:
            self._last_plain = now
            print("\n".join(status_line(r) for r in rows), file=self.stream, flush=True)

    @staticmethod
    def _table(rows: list[dict[str, Any]]) -> Table:
        table = Table(title="mavservo", expand=False)
        for col in (
            "servo",
            "state",
            "set deg",
            "pos deg",
            "vel dps",
            "I A",
            "T C",
            "age ms",
            "faults",
        ):
            table.add_column(
                col, justify="left" if col in ("servo", "state", "faults") else "right"
            )
        for r in rows:
            table.add_row(
                r["servo"],
                "[red]OFFLINE[/red]" if liveness(r) == "OFFLINE" else liveness(r),
                _num(r["setpoint_deg"], ".1f"),
                _num(r["position_deg"], ".1f"),
                _num(r["velocity_dps"], ".1f"),
                _num(r["current_a"], ".2f"),
                _num(r["temperature_c"], ".1f"),
                _num(None if r["age_s"] is None else r["age_s"] * 1000, ".0f"),
                " ".join(part for part in (r["faults"], r.get("health", "")) if part),
            )
        return table


def _ms(value: float | None) -> str:
    return "-" if value is None else f"{value * 1000:.2f}"


def _ms_unit(value: float | None) -> str:
    return "-" if value is None else f"{_ms(value)} ms"


#: The summary's per-servo columns: (header, width, metrics.json field under ``frames``).
#: ``docs/logs.md`` defines each; the report's table uses the same names.
FRAME_COLUMNS: tuple[tuple[str, int, str], ...] = (
    ("sent", 6, "sent"),
    ("recv", 6, "received"),
    ("pushed", 6, "pushed"),
    (OFFLINE, 7, "went_offline"),
    (LOST, 5, "lost"),
    (LATE, 5, "late"),
    ("rej", 4, "rejected"),
)
#: (header, width, field of ``latency_s`` or ``state_interval_s``), values in ms.
TIMING_COLUMNS: tuple[tuple[str, int, str, str], ...] = (
    ("L mean", 7, "latency_s", "mean"),
    ("sigma_L", 7, "latency_s", "sigma"),
    ("L p99", 7, "latency_s", "p99"),
    ("state p50", 9, "state_interval_s", "p50"),
)
SUMMARY_LEGEND = (
    f"  {glossary_text()};\n"
    "  sent = commands, refreshes, requests (an entry of a shared transfer counts one);"
    " recv = decoded replies, pushed = sent unasked by a push-style servo;\n"
    "  L (ms) = frame written -> reply decoded; state (ms) = between decoded states"
    " (docs/logs.md)"
)
#: MAVLink counters of a run going as it should: in metrics.json, not in the summary a person
#: reads (by their last name; ``link_budget.*`` is the identity line's, shown at the start)
ROUTINE_COUNTERS = frozenset(
    {
        "received",
        "sent",
        "applied",
        "result_accepted",
        "zero_pwm_ignored",
        "held_by_command",
        "udp_datagrams",
        "udp_rcvbuf_bytes",
        "reminders",
        "statustext_sent",
        "statustext_repeats_counted",
    }
)


def load_text(load: dict[str, Any]) -> str:
    """A bus's load R figures by their metrics.json names (``load.mean``, ``load.peak``,
    ``load.planned``), two decimals as the report shows them."""
    return (
        f"load R mean {load.get('mean', 0) * 100:.2f} %, peak {load.get('peak', 0) * 100:.2f} % "
        f"(busiest {load.get('window_s', 1.0):g} s), "
        f"planned {load.get('planned', 0) * 100:.2f} % (configured rates)"
    )


def _servo_table(servos: dict[str, Any]) -> list[str]:
    """One row per servo: frame counters, then L and the state interval in ms."""
    header = f"  {'servo':<16}" + "".join(f" {h:>{w}}" for h, w, _ in FRAME_COLUMNS)
    header += "".join(f" {h:>{w}}" for h, w, _, _ in TIMING_COLUMNS)
    lines = [header]
    for name, servo in servos.items():
        frames = servo.get("frames", {})
        row = f"  {name:<16}" + "".join(f" {frames.get(k, 0):>{w}}" for _, w, k in FRAME_COLUMNS)
        row += "".join(
            f" {_ms((servo.get(group) or {}).get(key)):>{w}}" for _, w, group, key in TIMING_COLUMNS
        )
        lines.append(row)
    if servos:
        lines.append(SUMMARY_LEGEND)
    return lines


def format_summary(summary: dict[str, Any]) -> str:
    """The end-of-run summary: frames both ways, errors, latency L / sigma_L, bus load R."""
    lines = ["", "mavservo summary"]
    uptime = summary.get("uptime_s")
    if uptime is not None:
        lines.append(f"  ran {uptime:.1f} s")
    for name, bus in summary.get("buses", {}).items():
        transport = bus.get("transport", {})
        rejected = transport.get("rejected", {})
        lines.append(
            f"  bus {name}: {load_text(bus.get('load', {}))}, "
            f"frames written {bus.get('frames_written', 0)}, "
            f"missed command slots {bus.get('missed_command_slots', 0)} "
            f"(late {bus.get('late_command_slots', 0)}, "
            f"longest gap {_ms_unit(bus.get('longest_command_gap_s'))}), "
            f"decoder rejections {sum(rejected.values()) if rejected else 0}, "
            f"bytes discarded {transport.get('bytes_discarded', 0)}, "
            f"reconnects {transport.get('reconnects', 0)}, "
            f"failed sends {bus.get('send_failures', {}).get('total', 0)}"
            + (
                f", frames the driver could not parse {transport['garbled']}"
                if transport.get("garbled")
                else ""
            )
        )
        for node in bus.get("nodes") or []:
            counts = ", ".join(f"{k} {v}" for k, v in node.items() if v)
            lines.append(f"  bus {name} node: {counts or 'nothing counted'}")
    lines += _servo_table(summary.get("servos", {}))
    lines += _safety_lines(summary)
    mav = summary.get("mavlink") or {}
    if mav:
        lines += _mavlink_lines(mav)
        lines += _stream_lines(mav.get("stream") or {}, uptime)
    lines += _health_lines(summary.get("health") or {})
    if summary.get("identity"):
        lines.append(f"  identity at the end: {summary['identity']}")
    problems = [text for text in summary.get("events", []) if event_level(text) != "INFO"]
    lines.append(
        "  problems said during the run"
        + (f" (the last {len(problems)}):" if problems else ": none")
    )
    lines += [f"    {text}" for text in problems]
    if summary.get("run_dir"):
        lines += _run_log_lines(summary["run_dir"], summary.get("runlog") or {})
    return "\n".join(lines)


def _safety_lines(summary: dict[str, Any]) -> list[str]:
    """DroneCAN SafetyState broadcasts, when a bus node sent any: SAFETY_ON is what turned the
    peripherals' outputs off (at the stop, or in a failsafe), so the crew sees it was sent."""
    nodes = [node for bus in summary.get("buses", {}).values() for node in bus.get("nodes") or []]
    off = sum(int(node.get("safety_off", 0)) for node in nodes)
    on = summary.get("safety_on", sum(int(node.get("safety_on", 0)) for node in nodes))
    if not off and not on:
        return []
    return [f"  DroneCAN SafetyState sent: SAFETY_OFF {_times(off)}, SAFETY_ON {_times(on)}"]


def _times(count: int) -> str:
    return f"{count} time" if count == 1 else f"{count} times"


def _mavlink_lines(mav: dict[str, Any]) -> list[str]:
    """The ground station's texts, and the MAVLink counters worth a look (refused, denied,
    dropped, bad...); the routine ones (:data:`ROUTINE_COUNTERS`) stay in metrics.json."""
    texts = mav.get("telemetry") or {}
    lines = [
        f"  ground station texts: {texts.get('statustext_sent', 0)} sent, "
        f"{texts.get('statustext_repeats_counted', 0)} repeats counted (summed up, not sent "
        f"one by one), {texts.get('statustext_dropped', 0)} dropped"
    ]
    link = mav.get("link", {})
    counters = {**_flat(mav, exclude=("link", "stream")), **_flat(link)}
    shown = [
        f"{k} {v}"
        for k, v in counters.items()
        # counts that happened; booleans and ids are state, not counters
        if isinstance(v, int | float)
        and not isinstance(v, bool)
        and v
        and k != "system_id"
        and not k.startswith(("mirror_", "link_budget.", "telemetry.statustext_dropped"))
        and k.rsplit(".", 1)[-1] not in ROUTINE_COUNTERS
    ]
    lines.append(
        "  mavlink, worth a look: " + ", ".join(shown)
        if shown
        else "  mavlink: nothing refused, denied or dropped"
    )
    return lines


def _health_lines(health: dict[str, Any]) -> list[str]:
    """The health monitor's run (docs/health.md): episodes per servo and check, what is still
    active at the end, and how many states it judged (a quiet run that judged nothing is not)."""
    if not health:
        return []
    judged = sum((health.get("judged") or {}).values())
    episodes = health.get("episodes") or {}
    found = "; ".join(
        f"{servo} " + ", ".join(f"{check} {n}" for check, n in checks.items())
        for servo, checks in episodes.items()
    )
    lines = [
        f"  health: {judged} states judged, " + (f"episodes: {found}" if found else "no events")
    ]
    for servo, checks in (health.get("active") or {}).items():
        lines.append(f"  health: {servo} still {', '.join(checks)} at the end")
    return lines


def _stream_lines(stream: dict[str, Any], uptime_s: float | None = None) -> list[str]:
    """One line per mirrored stream: the rate asked of the autopilot against the rate received."""
    lines = []
    for name, figures in (stream.get("streams") or {}).items():
        asked = figures.get("requested_hz")
        low = figures.get("low_rate_windows", 0)
        lines.append(
            f"  autopilot stream {name}: asked "
            f"{'nothing' if asked is None else f'{asked:g} Hz'} ({figures.get('answer')}), "
            + _received_text(figures, uptime_s)
            + (
                f", below the {figures.get('needed_hz', 0):g} Hz needed in {low} windows"
                if low
                else ""
            )
        )
    if stream.get("autopilot_restarts"):
        lines.append(
            f"  autopilot restarts seen: {stream['autopilot_restarts']} (streams re-asked)"
        )
    return lines


def _received_text(figures: dict[str, Any], uptime_s: float | None) -> str:
    """The rate received in words. The rate is measured over whole ``WINDOW_S`` windows; a run
    shorter than one has none, so it gets the whole run's average instead of a bare "-" (issue
    37), and a longer run without one says why."""
    count = figures.get("received", 0)
    received = figures.get("received_hz")
    if received is not None:
        return f"received {received:.1f} Hz (last {WINDOW_S:g} s window), {count} messages"
    if uptime_s is not None and 0 < uptime_s < WINDOW_S:
        return (
            f"received {count} messages in the whole {uptime_s:.1f} s run "
            f"(about {count / uptime_s:.1f} Hz; the rate is measured over {WINDOW_S:g} s)"
        )
    return (
        f"received {count} messages, rate not measured (no whole {WINDOW_S:g} s window "
        "with the autopilot heard)"
    )


def _run_log_lines(run_dir: str, outcome: dict[str, Any]) -> list[str]:
    """Where the run log is, and, when it failed (disk full, size cap), what it lacks."""
    if outcome.get("complete", True):
        return [
            f"  run log: {run_dir}  (mavservo report {run_dir}; every counter in "
            f"{Path(run_dir) / 'metrics.json'})"
        ]
    lines = [f"  run log: {run_dir}  INCOMPLETE (complete up to the failure):"]
    lines += [f"    {problem}" for problem in dict.fromkeys(outcome.get("problems", []))]
    metrics_path = outcome.get("metrics_path", "")
    if metrics_path is None:
        lines.append("    metrics.json could not be written anywhere (see the errors above)")
    elif metrics_path and Path(metrics_path).parent != Path(run_dir):
        lines.append(f"    metrics.json is in {metrics_path}")
    return lines


def _flat(d: dict[str, Any], prefix: str = "", exclude: tuple[str, ...] = ()) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in d.items():
        if key in exclude:
            continue
        if isinstance(value, dict):
            out.update(_flat(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out
