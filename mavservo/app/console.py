"""Terminal output of ``mavservo run``: a live one-line-per-servo status and the final summary.

On a terminal the status is a rich table refreshed in place; elsewhere (a pipe, a log file,
systemd's journal) it degrades to plain lines, one block every few seconds, so logs stay readable.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.live import Live
from rich.table import Table

from mavservo.mavlink.stream_request import WINDOW_S

PLAIN_EVERY_S = 5.0


def _num(value: float | None, fmt: str) -> str:
    return "-" if value is None else format(value, fmt)


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
        from mavservo.config.endpoints import endpoint_lines

        line = f"mavservo: running {config_path}"
        if bridge.run_dir is not None:
            line += f"; logging to {bridge.run_dir}"
        lines = [line, *(f"  {text}" for text in endpoint_lines(bridge.config))]
        print("\n".join(lines), file=self.stream, flush=True)

    def event(self, text: str) -> None:
        stamp = time.strftime("%H:%M:%S")
        if self.live is not None:
            self.live.console.print(f"[{stamp}] {text}")
        else:
            print(f"[{stamp}] {text}", file=self.stream, flush=True)

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
                r["faults"],
            )
        return table


def _ms(value: float | None) -> str:
    return "-" if value is None else f"{value * 1000:.2f}"


def _ms_unit(value: float | None) -> str:
    return "-" if value is None else f"{_ms(value)} ms"


def format_summary(summary: dict[str, Any]) -> str:
    """The end-of-run summary: frames both ways, errors, latency L / sigma_L, bus load R."""
    lines = ["", "mavservo summary"]
    uptime = summary.get("uptime_s")
    if uptime is not None:
        lines.append(f"  ran {uptime:.1f} s")
    for name, bus in summary.get("buses", {}).items():
        load = bus.get("load", {})
        transport = bus.get("transport", {})
        rejected = transport.get("rejected", {})
        lines.append(
            f"  bus {name}: load R now {load.get('current', 0) * 100:.1f} % "
            f"(peak {load.get('peak', 0) * 100:.1f} %, worst case "
            f"{bus.get('info', {}).get('worst_case_load', 0) * 100:.1f} %), "
            f"missed command slots {bus.get('missed_command_slots', 0)} "
            f"(late {bus.get('late_command_slots', 0)}, "
            f"longest gap {_ms_unit(bus.get('longest_command_gap_s'))}), "
            f"decoder rejections {sum(rejected.values()) if rejected else 0}, "
            f"bytes discarded {transport.get('bytes_discarded', 0)}, "
            f"reconnects {transport.get('reconnects', 0)}, "
            f"failed sends {bus.get('send_failures', {}).get('total', 0)}"
        )
    lines.append(
        f"  {'servo':<16} {'sent':>6} {'recv':>6} {'lost':>5} {'rej':>4} "
        f"{'L mean ms':>9} {'sigma_L':>8} {'L p99':>7} {'telem p50 ms':>12}"
    )
    for name, servo in summary.get("servos", {}).items():
        frames = servo.get("frames", {})
        lat = servo.get("latency_s", {})
        interval = servo.get("telemetry_interval_s", {}).get("interval", {})
        lines.append(
            f"  {name:<16} {frames.get('sent', 0):>6} {frames.get('received', 0):>6} "
            f"{frames.get('lost', 0):>5} {frames.get('rejected', 0):>4} "
            f"{_ms(lat.get('mean')):>9} {_ms(lat.get('sigma')):>8} {_ms(lat.get('p99')):>7} "
            f"{_ms(interval.get('p50')):>12}"
        )
    mav = summary.get("mavlink") or {}
    if mav:
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
            and not k.startswith("mirror_")  # a flat duplicate of mirror.*
        ]
        lines.append("  mavlink: " + ", ".join(shown))
        lines += _stream_lines(mav.get("stream") or {})
    for text in summary.get("events", []):
        lines.append(f"  event: {text}")
    if summary.get("run_dir"):
        lines += _run_log_lines(summary["run_dir"], summary.get("runlog") or {})
    return "\n".join(lines)


def _stream_lines(stream: dict[str, Any]) -> list[str]:
    """One line per mirrored stream: the rate asked of the autopilot against the rate received."""
    lines = []
    for name, figures in (stream.get("streams") or {}).items():
        asked = figures.get("requested_hz")
        received = figures.get("received_hz")
        low = figures.get("low_rate_windows", 0)
        lines.append(
            f"  autopilot stream {name}: asked "
            f"{'nothing' if asked is None else f'{asked:g} Hz'} ({figures.get('answer')}), "
            f"received {'-' if received is None else f'{received:.1f} Hz'} (last "
            f"{WINDOW_S:g} s window), {figures.get('received', 0)} messages"
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


def _run_log_lines(run_dir: str, outcome: dict[str, Any]) -> list[str]:
    """Where the run log is, and, when it failed (disk full, size cap), what it lacks."""
    if outcome.get("complete", True):
        return [f"  run log: {run_dir}  (mavservo report {run_dir})"]
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
