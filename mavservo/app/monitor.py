"""``mavservo monitor [MAVLINK_URL]``: a live terminal dashboard of a running bridge.

The monitor is an ordinary MAVLink client: it listens to what the bridge publishes (see
``mavservo/mavlink/telemetry.py``), so it works on the companion computer and from a ground
station laptop alike. Default URL ``udpin:0.0.0.0:14552``: configure the bridge with a second
output ``udpout:<monitor host>:14552`` (or point the monitor at any link the telemetry is on).

Two halves, so the interesting part is testable without a terminal:

* :class:`MonitorState` (pure): pymavlink messages and the time in, table rows out;
* :func:`main`: the connection, a rich ``Live`` dashboard refreshed at ``--rate`` (default 10 Hz),
  or plain lines once a second when stdout is not a terminal; ends on Ctrl-C or ``--duration``.

What it understands (all optional; missing ones show as "-"):

* NAMED_VALUE_FLOAT ``s<n>_pos|vel|cur|tmp|sp`` (deg, deg/s, A, degC, setpoint deg) for servo n
  (1-based config position); ``s<n>_flt``, the servo's fault bits (NO_REPLY = not responding),
  which sets the fault column from periodic telemetry, so a monitor started after a fault
  still shows it; ``bus<k>_load`` (ratio 0..1), and two latencies in ms that differ
  by two orders of magnitude on purpose (docs/logs.md, "Which latency is which"):
  ``lat_p50``/``lat_p95``/``lat_p99``, shown as ``cmd->telemetry``: a MAVLink command's receipt
  to the first telemetry message carrying its servo's reply, most of it the wait for the command
  slot and for the next ACTUATOR_OUTPUT_STATUS; ``rtt_p50``/``rtt_p95``/``rtt_p99``, shown as
  ``round trip L``: a frame written to the adapter to its reply decoded (the paper's L, the
  run summary's ``L mean``);
* ESC_TELEMETRY_1_TO_4.. (temperature, current, voltage) and ACTUATOR_OUTPUT_STATUS (normalized
  position) for the same servo numbering;
* HEARTBEAT of every component (autopilot, servo group 140.., gimbal 154..), with its age;
* STATUSTEXT (tail of the last lines; MAVLink 2 chunks (``id`` != 0) are joined back into one
  text; ``servo NAME fault ...``/``cleared``/``not responding`` also set the fault column of
  the servo that NAME belongs to, once its name is known);
* GIMBAL_DEVICE_ATTITUDE_STATUS (roll/pitch/yaw and failure flags, by name).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import re
import sys
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

DEFAULT_URL = "udpin:0.0.0.0:14552"
MONITOR_SYSTEM_ID = 255
MONITOR_COMPONENT_ID = 191  # MAV_COMP_ID_ONBOARD_COMPUTER range is taken; 191 = user 1 / GCS tools
STALE_AFTER_S = 2.0
STATUSTEXT_TAIL = 8
STATUSTEXT_CHUNK = 50  # a chunk shorter than this (its NUL) is the last of its text
STATUSTEXT_PENDING = 8  # chunked texts being reassembled at once; the oldest is given up
#: GIMBAL_DEVICE_ERROR_FLAGS, the bits of GIMBAL_DEVICE_ATTITUDE_STATUS.failure_flags
GIMBAL_FAILURE_FLAGS = {
    1: "at_roll_limit",
    2: "at_pitch_limit",
    4: "at_yaw_limit",
    8: "encoder_error",
    16: "power_error",
    32: "motor_error",
    64: "software_error",
    128: "comms_error",
    256: "calibration_running",
    512: "no_manager",
}

_NVF_SERVO = re.compile(r"^s(\d+)_(pos|vel|cur|tmp|sp)$")
_NVF_FAULTS = re.compile(r"^s(\d+)_flt$")
_NVF_BUS = re.compile(r"^bus(\d+)_load$")
_NVF_LATENCY = re.compile(r"^lat_(p50|p95|p99)$")
_NVF_ROUND_TRIP = re.compile(r"^rtt_(p50|p95|p99)$")
_ESC_GROUP = re.compile(r"^ESC_TELEMETRY_(\d+)_TO_\d+$")
_TEXT_FAULT = re.compile(r"^servo (\S+) (fault|cleared) (.+)$")
_TEXT_ONLINE = re.compile(r"^servo (\S+) (not responding|responding again)$")

MAV_TYPE_NAMES = {1: "fixed wing", 2: "quadrotor", 6: "GCS", 26: "gimbal", 33: "servo"}


@dataclass
class ServoView:
    """What the monitor knows about one servo (n = 1-based config position)."""

    number: int
    name: str | None = None
    setpoint_deg: float | None = None
    position_deg: float | None = None
    normalized: float | None = None
    velocity_dps: float | None = None
    current_a: float | None = None
    temperature_c: float | None = None
    voltage_v: float | None = None
    faults: set[str] = field(default_factory=set)
    responding: bool | None = None
    updated: float | None = None

    def age(self, now: float) -> float | None:
        return None if self.updated is None else max(0.0, now - self.updated)


@dataclass
class ComponentView:
    system: int
    component: int
    mav_type: int
    count: int
    last: float


class MonitorState:
    """Pure model of the dashboard: feed messages with :meth:`update`, read rows back."""

    def __init__(self, names: Sequence[str] = ()) -> None:
        """``names``: servo names in config order (servo n = names[n - 1]), when known."""
        self.servos: dict[int, ServoView] = {
            number: ServoView(number, name=name) for number, name in enumerate(names, 1)
        }
        self.components: dict[tuple[int, int], ComponentView] = {}
        self.texts: deque[tuple[float, int, str]] = deque(maxlen=STATUSTEXT_TAIL)
        self.bus_load: dict[int, float] = {}
        #: ``lat_p*``: MAVLink command receipt -> telemetry published (every stage, in ms)
        self.latency_ms: dict[str, float] = {}
        #: ``rtt_p*``: frame written -> reply decoded, the wire round trip L (ms)
        self.round_trip_ms: dict[str, float] = {}
        self.gimbal: dict[str, Any] = {}
        #: (source, id) -> (severity, {chunk_seq: text}) for chunked STATUSTEXT not complete yet
        self._chunks: dict[tuple[int, int, int], tuple[int, dict[int, str]]] = {}
        self.messages = 0
        self.bad_messages = 0
        self.first: float | None = None
        self.last: float | None = None

    def _servo(self, number: int) -> ServoView:
        view = self.servos.get(number)
        if view is None:
            view = self.servos[number] = ServoView(number)
        return view

    def _servo_by_name(self, name: str) -> ServoView:
        for view in self.servos.values():
            if view.name == name:
                return view
        # Not yet tied to a number: keep it under a synthetic negative key until it is.
        key = -1 - len([k for k in self.servos if k < 0])
        view = self.servos[key] = ServoView(key, name=name)
        return view

    def update(self, msg: Any, now: float) -> None:
        """Account for one pymavlink message received at ``now``."""
        kind = msg.get_type()
        if kind == "BAD_DATA":
            self.bad_messages += 1
            return
        self.messages += 1
        self.first = now if self.first is None else self.first
        self.last = now
        handler = getattr(self, f"_on_{kind.lower()}", None)
        if handler is not None:
            handler(msg, now)
        elif esc := _ESC_GROUP.match(kind):
            self._on_esc(msg, now, int(esc.group(1)))

    # -- handlers ------------------------------------------------------------------------------

    def _on_heartbeat(self, msg: Any, now: float) -> None:
        key = (msg.get_srcSystem(), msg.get_srcComponent())
        view = self.components.get(key)
        if view is None:
            self.components[key] = ComponentView(key[0], key[1], msg.type, 1, now)
        else:
            view.mav_type, view.count, view.last = msg.type, view.count + 1, now

    def _on_named_value_float(self, msg: Any, now: float) -> None:
        name = msg.name.decode(errors="replace") if isinstance(msg.name, bytes) else msg.name
        name = name.rstrip("\x00")
        value = float(msg.value)
        if match := _NVF_SERVO.match(name):
            view = self._servo(int(match.group(1)))
            attr = {
                "pos": "position_deg",
                "vel": "velocity_dps",
                "cur": "current_a",
                "tmp": "temperature_c",
                "sp": "setpoint_deg",
            }[match.group(2)]
            setattr(view, attr, value)
            if attr != "setpoint_deg":
                view.updated = now
        elif match := _NVF_FAULTS.match(name):
            self._on_fault_bits(self._servo(int(match.group(1))), value)
        elif match := _NVF_BUS.match(name):
            self.bus_load[int(match.group(1))] = value
        elif match := _NVF_LATENCY.match(name):
            self.latency_ms[match.group(1)] = value
        elif match := _NVF_ROUND_TRIP.match(name):
            self.round_trip_ms[match.group(1)] = value

    def _on_esc(self, msg: Any, now: float, first_number: int) -> None:
        for slot in range(4):
            if not msg.count[slot] and not msg.temperature[slot] and not msg.current[slot]:
                continue  # an empty slot: ESC_TELEMETRY carries four, not every one is a servo
            view = self._servo(first_number + slot)
            view.temperature_c = float(msg.temperature[slot])
            view.current_a = msg.current[slot] / 100.0
            view.voltage_v = msg.voltage[slot] / 100.0 if msg.voltage[slot] else view.voltage_v
            view.updated = now

    def _on_actuator_output_status(self, msg: Any, now: float) -> None:
        for index, value in enumerate(msg.actuator):
            if msg.active & (1 << index) and not math.isnan(value):
                view = self._servo(index + 1)
                view.normalized = float(value)

    @staticmethod
    def _on_fault_bits(view: ServoView, value: float) -> None:
        """``s<n>_flt``: the whole current fault set, replacing what STATUSTEXT built up."""
        from mavservo.servos.base import Fault

        if math.isnan(value):
            return
        bits = Fault(int(value) & sum(f.value for f in Fault))
        view.responding = Fault.NO_REPLY not in bits
        view.faults = {
            f.name.lower() for f in Fault if f.name and f in bits and f is not Fault.NO_REPLY
        }

    def _on_statustext(self, msg: Any, now: float) -> None:
        text = msg.text.decode(errors="replace") if isinstance(msg.text, bytes) else msg.text
        text = text.split("\x00")[0]
        text_id = int(getattr(msg, "id", 0) or 0)
        if text_id:
            text = self._join_chunk(msg, text_id, text)
            if text is None:
                return
        self.texts.append((now, int(msg.severity), text))
        if match := _TEXT_FAULT.match(text):
            view = self._servo_by_name(match.group(1))
            names = {n for n in match.group(3).split("|") if n}
            if match.group(2) == "fault":
                view.faults |= names
            else:
                view.faults -= names
        elif match := _TEXT_ONLINE.match(text):
            view = self._servo_by_name(match.group(1))
            view.responding = match.group(2) == "responding again"

    def _join_chunk(self, msg: Any, text_id: int, text: str) -> str | None:
        """Collect one chunk of a long STATUSTEXT; the whole text once its last chunk is in."""
        key = (msg.get_srcSystem(), msg.get_srcComponent(), text_id)
        severity, chunks = self._chunks.pop(key, (int(msg.severity), {}))
        chunks[int(msg.chunk_seq)] = text
        last = (
            max(seq for seq, part in chunks.items() if len(part) < STATUSTEXT_CHUNK)
            if any(len(part) < STATUSTEXT_CHUNK for part in chunks.values())
            else None
        )
        if last is not None and all(seq in chunks for seq in range(last + 1)):
            return "".join(chunks[seq] for seq in range(last + 1))
        self._chunks[key] = (severity, chunks)
        while len(self._chunks) > STATUSTEXT_PENDING:
            self._chunks.pop(next(iter(self._chunks)))
        return None

    def _on_gimbal_device_attitude_status(self, msg: Any, now: float) -> None:
        from mavservo.mavlink.quaternion import quaternion_to_euler

        roll, pitch, yaw = quaternion_to_euler(list(msg.q))
        self.gimbal = {
            "component": msg.get_srcComponent(),
            "roll": roll,
            "pitch": pitch,
            "yaw": yaw,
            "failure_flags": int(msg.failure_flags),
            "updated": now,
        }

    # -- rows out ------------------------------------------------------------------------------

    def servo_rows(self, now: float) -> list[dict[str, str]]:
        """One dict of display strings per servo, in servo number order."""
        rows = []
        for number in sorted(self.servos, key=lambda n: (n < 0, abs(n))):
            view = self.servos[number]
            age = view.age(now)
            if view.responding is False or (age is not None and age > STALE_AFTER_S):
                status = "STALE" if view.responding is not False else "NO REPLY"
            elif view.faults:
                status = "FAULT"
            else:
                status = "ok" if age is not None else "-"
            rows.append(
                {
                    "servo": str(number) if number > 0 else "?",
                    "name": view.name or "",
                    "setpoint": _fmt(view.setpoint_deg, "{:+.1f}"),
                    "position": _fmt(view.position_deg, "{:+.2f}"),
                    "normalized": _fmt(view.normalized, "{:+.3f}"),
                    "velocity": _fmt(view.velocity_dps, "{:+.1f}"),
                    "current": _fmt(view.current_a, "{:.2f}"),
                    "temperature": _fmt(view.temperature_c, "{:.0f}"),
                    "faults": "|".join(sorted(view.faults)) or "-",
                    "age": _fmt(age, "{:.2f}s"),
                    "status": status,
                }
            )
        return rows

    def component_rows(self, now: float) -> list[dict[str, str]]:
        rows = []
        for (system, component), view in sorted(self.components.items()):
            age = now - view.last
            rows.append(
                {
                    "component": f"{system}/{component}",
                    "type": MAV_TYPE_NAMES.get(view.mav_type, str(view.mav_type)),
                    "heartbeats": str(view.count),
                    "age": f"{age:.1f}s",
                    "status": "ok" if age <= STALE_AFTER_S else "LOST",
                }
            )
        return rows

    def health_line(self, now: float) -> str:
        """Link rate, bus load and latency in one line."""
        parts = []
        if self.first is not None and self.last is not None and self.last > self.first:
            parts.append(f"{self.messages / (self.last - self.first):.0f} msg/s")
        parts.append(f"{self.messages} msgs, {self.bad_messages} bad")
        if self.bus_load:
            parts.append(
                "load "
                + ", ".join(f"bus{k} {100 * v:.1f}%" for k, v in sorted(self.bus_load.items()))
            )
        # two latencies, each named for what it spans: the first includes the waits for the
        # command slot and the next telemetry message (~100 ms), the second is the wire's (~1 ms)
        if self.latency_ms:
            parts.append(
                "cmd->telemetry "
                + " ".join(f"{k} {v:.1f}ms" for k, v in sorted(self.latency_ms.items()))
            )
        if self.round_trip_ms:
            parts.append(
                "round trip L "
                + " ".join(f"{k} {v:.2f}ms" for k, v in sorted(self.round_trip_ms.items()))
            )
        if self.gimbal:
            g = self.gimbal
            parts.append(
                f"gimbal r{g['roll']:+.1f} p{g['pitch']:+.1f} y{g['yaw']:+.1f}"
                f" failure_flags {_gimbal_flags(g['failure_flags'])}"
            )
        return " | ".join(parts)


def _gimbal_flags(flags: int) -> str:
    """``0x20 motor_error``: GIMBAL_DEVICE_ATTITUDE_STATUS.failure_flags with bit names."""
    names = [name for bit, name in GIMBAL_FAILURE_FLAGS.items() if flags & bit]
    unknown = flags & ~sum(GIMBAL_FAILURE_FLAGS)
    if unknown:
        names.append(f"0x{unknown:x}?")
    return f"0x{flags:x}" + (f" {'|'.join(names)}" if names else " ok")


def _fmt(value: float | None, pattern: str) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    return pattern.format(value)


SERVO_COLUMNS = (
    "servo",
    "name",
    "setpoint",
    "position",
    "normalized",
    "velocity",
    "current",
    "temperature",
    "faults",
    "age",
    "status",
)
SERVO_HEADERS = (
    "#",
    "name",
    "set [deg]",
    "pos [deg]",
    "norm",
    "vel [dps]",
    "cur [A]",
    "temp [C]",
    "faults",
    "age",
    "status",
)


def render(state: MonitorState, now: float, title: str = "mavservo monitor") -> Any:
    """The rich renderable for one dashboard frame."""
    from rich.console import Group
    from rich.table import Table
    from rich.text import Text

    servos = Table(title=title, expand=False)
    for header in SERVO_HEADERS:
        servos.add_column(header, justify="right")
    for row in state.servo_rows(now):
        style = {"ok": "", "-": "dim", "FAULT": "yellow"}.get(row["status"], "bold red")
        servos.add_row(*(row[c] for c in SERVO_COLUMNS), style=style)
    if not state.servos:
        servos.caption = "waiting for servo telemetry..."
    links = Table(title="link", expand=False)
    for header in ("sys/comp", "type", "heartbeats", "age", "status"):
        links.add_column(header, justify="right")
    for row in state.component_rows(now):
        links.add_row(*row.values(), style="" if row["status"] == "ok" else "bold red")
    texts = Text("\n".join(f"[{sev}] {text}" for _, sev, text in state.texts) or "no STATUSTEXT")
    return Group(servos, links, Text(state.health_line(now)), texts)


def plain_lines(state: MonitorState, now: float) -> list[str]:
    """The same information as plain text lines, for logs and pipes."""
    stamp = time.strftime("%H:%M:%S")
    lines = [f"{stamp} {state.health_line(now)}"]
    for row in state.servo_rows(now):
        lines.append(f"{stamp} servo " + " ".join(f"{c}={row[c]}" for c in SERVO_COLUMNS))
    for row in state.component_rows(now):
        lines.append(f"{stamp} heartbeat " + " ".join(f"{k}={v}" for k, v in row.items()))
    return lines


def _names_and_key(config_path: str | None, key_file: str | None) -> tuple[list[str], bytes | None]:
    """Servo names and signing key from the bridge's config and ``--signing-key-file`` (which
    wins); ValueError says what is wrong with either (the config's errors as FILE:LINE)."""
    names: list[str] = []
    key: bytes | None = None
    if config_path:
        from mavservo.config.loader import ConfigError, load_config

        try:
            config = load_config(config_path)
        except ConfigError as exc:
            raise ValueError(str(exc)) from None
        names = [servo.name for servo in config.servos]
        if config.mavlink.signing is not None:
            key = config.mavlink.signing.secret_key()
    if key_file:
        from mavservo.config.schema import read_key_file

        try:
            key = read_key_file(key_file)
        except ValueError as exc:
            raise ValueError(f"--signing-key-file: {exc}") from None
    return names, key


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point for ``mavservo monitor [MAVLINK_URL] [--duration S] [--rate HZ] [--plain]``."""
    parser = argparse.ArgumentParser(
        prog="mavservo monitor",
        description="Live dashboard of a running mavservo bridge, as an ordinary MAVLink client.",
    )
    parser.add_argument(
        "url",
        nargs="?",
        default=DEFAULT_URL,
        help=f"pymavlink connection string (default {DEFAULT_URL})",
    )
    parser.add_argument("--duration", type=float, default=None, help="stop after this many s")
    parser.add_argument("--rate", type=float, default=10.0, help="dashboard refresh rate (Hz)")
    parser.add_argument(
        "--config", help="bridge YAML config: servo names, and its signing key if it signs"
    )
    parser.add_argument(
        "--signing-key-file",
        help="sign the monitor's messages with this key (64 hex characters), so that a bridge "
        "that signs answers it on its own link (default: the --config's key, if any)",
    )
    parser.add_argument("--plain", action="store_true", help="plain lines even on a terminal")
    parser.add_argument(
        "--no-heartbeat",
        action="store_true",
        help="do not announce the monitor with a GCS heartbeat",
    )
    args = parser.parse_args(argv)

    from pymavlink import mavutil
    from rich.console import Console
    from rich.live import Live

    from mavservo.mavlink.connection import open_connection

    console = Console()
    plain = args.plain or not console.is_terminal
    # MAVLink 2 (ESC_TELEMETRY_* and friends exist only there), without process-wide changes
    conn = open_connection(
        args.url, source_system=MONITOR_SYSTEM_ID, source_component=MONITOR_COMPONENT_ID
    )
    try:
        names, signing_key = _names_and_key(args.config, args.signing_key_file)
    except ValueError as exc:
        print(f"mavservo monitor: {exc}", file=sys.stderr)
        return 2
    if signing_key is not None:  # a signing bridge ignores (and never answers) unsigned peers
        conn.setup_signing(signing_key, sign_outgoing=True)
    state = MonitorState(names)
    start = time.monotonic()
    deadline = None if args.duration is None else start + args.duration
    refresh_period = 1.0 / max(args.rate, 1.0)
    plain_period = 1.0
    next_heartbeat = start
    live = (
        None
        if plain
        else Live(render(state, start), console=console, auto_refresh=False, transient=False)
    )
    try:
        if live is not None:
            live.start(refresh=True)
        next_draw = start
        while True:
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                break
            if not args.no_heartbeat and now >= next_heartbeat:
                next_heartbeat = now + 1.0
                _send_heartbeat(conn, mavutil)
            if now >= next_draw:
                if live is not None:
                    live.update(render(state, now, f"mavservo monitor  {args.url}"), refresh=True)
                    next_draw = now + refresh_period
                else:
                    for line in plain_lines(state, now):
                        print(line, flush=True)
                    next_draw = now + plain_period
            wait = max(0.0, min(next_draw, deadline or next_draw) - time.monotonic())
            msg = conn.recv_match(blocking=True, timeout=wait)
            while msg is not None:
                state.update(msg, time.monotonic())
                msg = conn.recv_match(blocking=False)
    except KeyboardInterrupt:
        pass
    finally:
        if live is not None:
            live.update(
                render(state, time.monotonic(), f"mavservo monitor  {args.url}"), refresh=True
            )
            live.stop()
        conn.close()
    return 0


def _send_heartbeat(conn: Any, mavutil: Any) -> None:
    """Announce the monitor as a GCS-type client; udpin links can only answer once heard."""
    with contextlib.suppress(OSError):  # udpin before the first packet has no peer yet
        conn.mav.heartbeat_send(
            mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0
        )


if __name__ == "__main__":
    sys.exit(main())
