"""``mavservo monitor [MAVLINK_URL]``: a live terminal dashboard of a running bridge.

The monitor is an ordinary MAVLink client: it listens to what the bridge publishes (see
``mavservo/mavlink/telemetry.py``), so it works on the companion computer and from a ground
station laptop alike. Default URL ``udpin:127.0.0.1:14552``: the bridge's second output
``udpout:127.0.0.1:14552`` on the same machine (``config/sim.yaml`` has it); from another
machine, listen on its address explicitly (``mavservo monitor udpin:0.0.0.0:14552``) and point
the bridge's output there. Not every interface by default: the monitor answers what it hears
with a heartbeat, and a dashboard has no business being reachable from the whole network.

Two halves, so the interesting part is testable without a terminal:

* :class:`MonitorState` (pure): pymavlink messages and the time in, table rows out;
* :func:`main`: the connection, a rich ``Live`` dashboard refreshed at ``--rate`` (default 10 Hz),
  or plain lines once a second when stdout is not a terminal; ends on Ctrl-C or ``--duration``.

What it understands (all optional; missing ones show as "-"):

* NAMED_VALUE_FLOAT ``s<n>_pos|vel|cur|tmp|sp`` (deg, deg/s, A, degC, setpoint deg) for servo n
  (1-based config position); ``s<n>_flt``, the servo's fault bits (NO_REPLY = offline),
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
  text; ``servo NAME fault ...``/``cleared``/``offline`` also set the fault column of
  the servo that NAME belongs to when its name is known (``--config``); without names, the
  periodic ``s<n>_flt`` sets it: a name never makes a row of its own, which stayed NO REPLY
  beside the servo's real row);
* GIMBAL_DEVICE_ATTITUDE_STATUS (roll/pitch/yaw and failure flags, by name);
* NAMED_VALUE_FLOAT ``s<n>_hlt``, the bridge's own health findings (docs/health.md: jammed,
  slipping, tracking, ...), shown in the fault column after the servo's own faults.
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

DEFAULT_URL = "udpin:127.0.0.1:14552"
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
_NVF_HEALTH = re.compile(r"^s(\d+)_hlt$")
_NVF_BUS = re.compile(r"^bus(\d+)_load$")
_NVF_LATENCY = re.compile(r"^lat_(p50|p95|p99)$")
_NVF_ROUND_TRIP = re.compile(r"^rtt_(p50|p95|p99)$")
_ESC_GROUP = re.compile(r"^ESC_TELEMETRY_(\d+)_TO_\d+$")
#: the bridge's servo texts (mavservo/mavlink/telemetry.py), with the count of repeats that
#: may follow them ("(x5 in 10 s)", mavservo/records/repeats.py); "not responding" and
#: "responding again" are an older bridge's words for "offline" and "back online"
_TEXT_FAULT = re.compile(r"^servo (\S+) (fault|cleared) (\S+)(?: \(.*\))?$")
_TEXT_ONLINE = re.compile(
    r"^servo (\S+) (offline|back online|not responding|responding again)(?: \(.*\))?$"
)

MAV_TYPE_NAMES = {1: "fixed wing", 2: "quadrotor", 6: "GCS", 26: "gimbal", 33: "servo"}
#: MAV_SEVERITY, by value: STATUSTEXT severities are shown by name, not as 0..7
MAV_SEVERITY_NAMES = (
    "EMERGENCY",
    "ALERT",
    "CRITICAL",
    "ERROR",
    "WARNING",
    "NOTICE",
    "INFO",
    "DEBUG",
)
#: the header's message rate is over this many recent seconds, so it falls to 0 when the bridge
#: stops instead of keeping the average of the whole session
RATE_WINDOW_S = 5


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
    #: what the bridge's health monitor finds (``s<n>_hlt``: jammed, slipping, ...)
    health: set[str] = field(default_factory=set)
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
        #: every STATUSTEXT ever completed (the tail above keeps the last few)
        self.text_count = 0
        self.bus_load: dict[int, float] = {}
        #: ``lat_p*``: MAVLink command receipt -> telemetry published (every stage, in ms)
        self.latency_ms: dict[str, float] = {}
        #: ``rtt_p*``: frame written -> reply decoded, the wire round trip L (ms)
        self.round_trip_ms: dict[str, float] = {}
        self.gimbal: dict[str, Any] = {}
        #: ESC number of servo 1 (the bridge's ``esc_first`` NAMED_VALUE_FLOAT): ESC data is
        #: mapped to servos only once it is known (17 by default, moved when the autopilot
        #: uses those numbers), so ESC 17 never shows as a servo 17 row
        self.esc_first: int | None = None
        #: (source, id) -> (severity, {chunk_seq: text}) for chunked STATUSTEXT not complete yet
        self._chunks: dict[tuple[int, int, int], tuple[int, dict[int, str]]] = {}
        self.messages = 0
        self.bad_messages = 0
        self.first: float | None = None
        self.last: float | None = None
        #: [whole second, messages in it] for the last RATE_WINDOW_S + 1 seconds (bounded
        #: whatever the flood: one bucket per second, not one entry per message)
        self._per_second: deque[list[int]] = deque(maxlen=RATE_WINDOW_S + 1)

    def _servo(self, number: int) -> ServoView:
        view = self.servos.get(number)
        if view is None:
            view = self.servos[number] = ServoView(number)
        return view

    def _servo_by_name(self, name: str) -> ServoView | None:
        """The row of servo ``name``; None when no row has that name (no ``--config``): the
        servo's numbered row gets its state from ``s<n>_flt`` instead (issue 37: a row made
        for the name stayed NO REPLY forever, a phantom beside the servo's real row)."""
        for view in self.servos.values():
            if view.name == name:
                return view
        return None

    def update(self, msg: Any, now: float) -> None:
        """Account for one pymavlink message received at ``now``."""
        kind = msg.get_type()
        if kind == "BAD_DATA":
            self.bad_messages += 1
            return
        self.messages += 1
        self.first = now if self.first is None else self.first
        self.last = now
        second = int(math.floor(now))
        if self._per_second and self._per_second[-1][0] == second:
            self._per_second[-1][1] += 1
        else:
            self._per_second.append([second, 1])
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
        elif match := _NVF_HEALTH.match(name):
            self._on_health_bits(self._servo(int(match.group(1))), value)
        elif match := _NVF_BUS.match(name):
            self.bus_load[int(match.group(1))] = value
        elif match := _NVF_LATENCY.match(name):
            self.latency_ms[match.group(1)] = value
        elif match := _NVF_ROUND_TRIP.match(name):
            self.round_trip_ms[match.group(1)] = value
        elif name == "esc_first" and math.isfinite(value) and 1 <= value <= 32:
            self.esc_first = int(value)

    def _on_esc(self, msg: Any, now: float, first_number: int) -> None:
        if self.esc_first is None:
            return  # which ESC is servo 1 is not known yet (``esc_first`` comes every period)
        for slot in range(4):
            if not msg.count[slot] and not msg.temperature[slot] and not msg.current[slot]:
                continue  # an empty slot: ESC_TELEMETRY carries four, not every one is a servo
            number = first_number + slot - self.esc_first + 1
            if number < 1:
                continue  # an ESC below the servos': the autopilot's motors, not ours
            view = self._servo(number)
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
        from mavservo.servos import Fault

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
        self.text_count += 1
        if (match := _TEXT_FAULT.match(text)) and (view := self._servo_by_name(match.group(1))):
            names = {n for n in match.group(3).split("|") if n}
            if match.group(2) == "fault":
                view.faults |= names
            else:
                view.faults -= names
        elif (match := _TEXT_ONLINE.match(text)) and (view := self._servo_by_name(match.group(1))):
            view.responding = match.group(2) in ("back online", "responding again")

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
            from mavservo.mavlink import join_statustext_chunks

            return join_statustext_chunks([chunks[seq] for seq in range(last + 1)])
        self._chunks[key] = (severity, chunks)
        while len(self._chunks) > STATUSTEXT_PENDING:
            self._chunks.pop(next(iter(self._chunks)))
        return None

    def _on_gimbal_device_attitude_status(self, msg: Any, now: float) -> None:
        from mavservo.mavlink import quaternion_to_euler

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

    @staticmethod
    def _on_health_bits(view: ServoView, value: float) -> None:
        """``s<n>_hlt``: the bridge's health findings (docs/health.md), the whole current set."""
        from mavservo.mavlink import Health

        if not math.isfinite(value) or value < 0:
            return
        bits = Health(int(value) & sum(h.value for h in Health))
        view.health = {h.name.lower() for h in Health if h.name and h in bits}

    def servo_rows(self, now: float) -> list[dict[str, str]]:
        """One dict of display strings per servo, in servo number order."""
        rows = []
        for number in sorted(self.servos, key=lambda n: (n < 0, abs(n))):
            view = self.servos[number]
            age = view.age(now)
            if view.responding is False or (age is not None and age > STALE_AFTER_S):
                status = "STALE" if view.responding is not False else "NO REPLY"
            elif view.faults or view.health:
                status = "FAULT"
            else:
                status = "ok" if age is not None else "-"
            rows.append(
                {
                    "servo": str(number) if number > 0 else "?",
                    # without --config: the bridge's own NAMED_VALUE prefix (s1 for s1_pos)
                    "name": view.name or (f"s{number}" if number > 0 else ""),
                    "setpoint": _fmt(view.setpoint_deg, "{:+.1f}"),
                    "position": _fmt(view.position_deg, "{:+.2f}"),
                    "normalized": _fmt(view.normalized, "{:+.3f}"),
                    "velocity": _fmt(view.velocity_dps, "{:+.1f}"),
                    "current": _fmt(view.current_a, "{:.2f}"),
                    "temperature": _fmt(view.temperature_c, "{:.0f}"),
                    "faults": "|".join(sorted(view.faults) + sorted(view.health)) or "-",
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

    def message_rate(self, now: float) -> float | None:
        """Messages a second over the last ``RATE_WINDOW_S`` s before ``now`` (fewer right after
        the first message); None before any message. 0 once the bridge has gone quiet."""
        if self.first is None:
            return None
        newest = int(math.floor(now))
        oldest = newest - RATE_WINDOW_S  # whole seconds oldest .. newest - 1, the last complete
        span = min(float(RATE_WINDOW_S), max(now - self.first, 1e-3))
        count = sum(n for second, n in self._per_second if oldest <= second < newest)
        if now - self.first < RATE_WINDOW_S:  # young session: everything so far, over its age
            count = sum(n for second, n in self._per_second)
        return count / span

    def link_line(self, now: float) -> str:
        """``147 msg/s, 832 msgs, 0 bad``; ``silent 12.3 s`` once nothing has come for a while."""
        rate = self.message_rate(now)
        parts = []
        if rate is None:
            parts.append("no message yet")
        elif self.last is not None and now - self.last > STALE_AFTER_S:
            parts.append(f"0 msg/s, silent {now - self.last:.1f} s")
        else:
            parts.append(f"{rate:.0f} msg/s")
        parts.append(f"{self.messages} msgs, {self.bad_messages} bad")
        return ", ".join(parts)

    def health_line(self, now: float) -> str:
        """Link rate, bus load and latency in one line."""
        return " | ".join([self.link_line(now), *self.figure_parts()])

    def figure_parts(self) -> list[str]:
        """Bus load, the two latencies and the gimbal, each a self-contained piece."""
        parts = []
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
        return parts


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


@dataclass(frozen=True)
class ScreenColumn:
    """One column of the dashboard's servo table: its row key, header and unit (the header's
    two lines), and width."""

    key: str
    header: str
    unit: str
    width: int
    left: bool = False


#: The servo table at 80 columns (76 characters with names up to 15 characters); the unit is
#: the header's second line, each width holds the longest value its format makes (``-180.00``,
#: ``NO REPLY``), so nothing is cut. Narrower terminals lose ``norm`` first, then ``age``.
SCREEN_COLUMNS = (
    ScreenColumn("servo", "#", "", 2),
    ScreenColumn("name", "name", "", 15, left=True),
    ScreenColumn("setpoint", "set", "deg", 6),
    ScreenColumn("position", "pos", "deg", 7),
    ScreenColumn("velocity", "vel", "deg/s", 7),
    ScreenColumn("normalized", "norm", "-1..1", 6),
    ScreenColumn("current", "I", "A", 6),
    ScreenColumn("temperature", "T", "degC", 5),
    ScreenColumn("age", "age", "s", 5),
    ScreenColumn("status", "status", "", 8, left=True),
)
DROPPED_WHEN_NARROW = ("normalized", "age")
NAME_WIDTH_MAX = 24
STATUS_STYLES = {"ok": "", "-": "dim", "FAULT": "yellow"}


def _fit(text: str, width: int) -> str:
    """A cell at most ``width`` long: a number too long for its column (a hostile or broken
    peer's 1e30) in scientific notation, anything else cut with an ellipsis."""
    if len(text) <= width:
        return text
    try:
        value = float(text.rstrip("s"))
    except ValueError:
        return text[: width - 1] + "\u2026"
    sign = "+" if text.startswith("+") else ""
    for digits in (3, 2, 1):
        short = f"{value:{sign}.{digits}g}"
        if len(short) <= width:
            return short
    return "#" * width


def _columns(state: MonitorState, now: float, width: int) -> list[ScreenColumn]:
    """The columns that fit ``width``, the name column as wide as the longest name shown."""
    rows = state.servo_rows(now)
    names = max((len(r["name"]) for r in rows), default=4)
    columns = [
        ScreenColumn(c.key, c.header, c.unit, min(max(names, 4), NAME_WIDTH_MAX), c.left)
        if c.key == "name"
        else c
        for c in SCREEN_COLUMNS
    ]
    for key in DROPPED_WHEN_NARROW:
        if sum(c.width + 1 for c in columns) - 1 <= width:
            break
        columns = [c for c in columns if c.key != key]
    return columns


def _cells(columns: Sequence[ScreenColumn], values: dict[str, str]) -> str:
    cells = []
    for column in columns:
        text = values[column.key]
        text = _fit(text, column.width)
        cells.append(text.ljust(column.width) if column.left else text.rjust(column.width))
    return " ".join(cells).rstrip()


def _wrapped(pieces: Sequence[str], width: int, indent: str = "  ") -> list[str]:
    """Pieces joined by `` | `` into lines of at most ``width``, breaking between pieces."""
    import textwrap

    lines: list[str] = []
    for piece in pieces:
        if lines and len(lines[-1]) + 3 + len(piece) <= width:
            lines[-1] += " | " + piece
        else:
            lines += textwrap.wrap(
                piece, width, subsequent_indent=indent, break_on_hyphens=False
            ) or [""]
    return lines


def severity_name(severity: int) -> str:
    """MAV_SEVERITY by name (``WARNING``); a value outside 0..7 as its number."""
    return (
        MAV_SEVERITY_NAMES[severity] if 0 <= severity < len(MAV_SEVERITY_NAMES) else str(severity)
    )


def screen_lines(
    state: MonitorState, now: float, width: int, height: int, title: str = "mavservo monitor"
) -> list[tuple[str, str]]:
    """The dashboard as (line, style) pairs that fit ``width`` x ``height``: title and link rate,
    the servo table (units in its header), heartbeats, figures, faults, then as many of the
    latest STATUSTEXT lines as the remaining height holds. Lines never exceed ``width``."""
    import textwrap

    width = max(width, 20)
    top = [(line, "bold") for line in _wrapped([title, state.link_line(now)], width)]
    columns = _columns(state, now, width)
    table = [
        (_cells(columns, {c.key: c.header for c in columns}), "bold"),
        (_cells(columns, {c.key: c.unit for c in columns}), "dim underline"),
    ]
    rows = state.servo_rows(now)
    table += [
        # the age's unit is in the header
        (
            _cells(columns, {**row, "age": row["age"].rstrip("s")}),
            STATUS_STYLES.get(row["status"], "bold red"),
        )
        for row in rows
    ]
    if not rows:
        table.append(("waiting for servo telemetry...", "dim"))
    heartbeats = [
        f"{r['component']} {r['type']} {r['age']} {r['status']}" for r in state.component_rows(now)
    ]
    below = [
        (line, "")
        for line in _wrapped(["heartbeats: " + (" | ".join(heartbeats) or "none yet")], width)
    ]
    below += [(line, "") for line in _wrapped(state.figure_parts(), width)]
    faults = [f"{r['servo']} {r['name']}: {r['faults']}" for r in rows if r["faults"] != "-"]
    if faults:
        below += [
            (line, "yellow") for line in _wrapped(["faults " + faults[0], *faults[1:]], width)
        ]
    texts: list[tuple[str, str]] = []
    for _, severity, text in state.texts:
        style = "bold red" if severity <= 3 else "yellow" if severity == 4 else ""
        label = f"[{severity_name(severity)}] {text}"
        texts += [(line, style) for line in textwrap.wrap(label, width, subsequent_indent="  ")]
    if not texts:
        texts = [("no STATUSTEXT yet", "dim")]
    room = height - len(top) - len(below)
    if len(table) > room - 1:  # the table first, with a line that says what did not fit
        shown = max(room - 3, 1)  # two header lines and the "more" line
        hidden = len(table) - 2 - shown
        table = table[: 2 + shown]
        table.append((f"... {hidden} more servos: a taller terminal shows them", "dim"))
    room -= len(table)
    return top + table + below + (texts[-room:] if room > 0 else [])


def render(
    state: MonitorState,
    now: float,
    title: str = "mavservo monitor",
    width: int = 80,
    height: int = 24,
) -> Any:
    """The rich renderable for one dashboard frame of ``width`` x ``height`` characters."""
    from rich.text import Text

    text = Text(no_wrap=True, overflow="crop")
    for index, (line, style) in enumerate(screen_lines(state, now, width, height, title)):
        if index:
            text.append("\n")
        text.append(line, style=style or None)
    return text


def plain_lines(state: MonitorState, now: float, texts_shown: int | None = None) -> list[str]:
    """The same information as plain text lines, for logs and pipes.

    ``texts_shown``: how many STATUSTEXT the caller has printed so far (``state.text_count``
    at its last call); the ones since then follow as ``statustext severity=WARNING text=...``
    lines (at most the tail the state keeps). None: no STATUSTEXT lines."""
    stamp = time.strftime("%H:%M:%S")
    lines = [f"{stamp} {state.health_line(now)}"]
    for row in state.servo_rows(now):
        lines.append(f"{stamp} servo " + " ".join(f"{c}={row[c]}" for c in SERVO_COLUMNS))
    for row in state.component_rows(now):
        lines.append(f"{stamp} heartbeat " + " ".join(f"{k}={v}" for k, v in row.items()))
    if texts_shown is not None:
        new = min(state.text_count - texts_shown, len(state.texts))
        for _, severity, text in list(state.texts)[len(state.texts) - new :] if new > 0 else []:
            lines.append(f"{stamp} statustext severity={severity_name(severity)} text={text}")
    return lines


def _names_and_key(config_path: str | None, key_file: str | None) -> tuple[list[str], bytes | None]:
    """Servo names and signing key from the bridge's config and ``--signing-key-file`` (which
    wins); ValueError says what is wrong with either (the config's errors as FILE:LINE)."""
    names: list[str] = []
    key: bytes | None = None
    if config_path:
        from mavservo.config import ConfigError, load_config

        try:
            config = load_config(config_path)
        except ConfigError as exc:
            raise ValueError(str(exc)) from None
        names = [servo.name for servo in config.servos]
        if config.mavlink.signing is not None:
            key = config.mavlink.signing.secret_key()
    if key_file:
        from mavservo.config import read_key_file

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

    from mavservo.mavlink import open_connection

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
        else Live(
            render(state, start, width=console.width, height=console.height),
            console=console,
            auto_refresh=False,
            transient=False,
        )
    )
    try:
        if live is not None:
            live.start(refresh=True)
        next_draw = start
        texts_shown = 0
        while True:
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                break
            if not args.no_heartbeat and now >= next_heartbeat:
                next_heartbeat = now + 1.0
                _send_heartbeat(conn, mavutil)
            if now >= next_draw:
                if live is not None:
                    live.update(_frame(state, now, args.url, console), refresh=True)
                    next_draw = now + refresh_period
                else:
                    for line in plain_lines(state, now, texts_shown):
                        print(line, flush=True)
                    texts_shown = state.text_count
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
            live.update(_frame(state, time.monotonic(), args.url, console), refresh=True)
            live.stop()
        conn.close()
    return 0


def _frame(state: MonitorState, now: float, url: str, console: Any) -> Any:
    """One frame at the terminal's current size (it may have been resized since the last)."""
    return render(state, now, f"mavservo monitor  {url}", console.width, console.height)


def _send_heartbeat(conn: Any, mavutil: Any) -> None:
    """Announce the monitor as a GCS-type client; udpin links can only answer once heard."""
    with contextlib.suppress(OSError):  # udpin before the first packet has no peer yet
        conn.mav.heartbeat_send(
            mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0
        )


if __name__ == "__main__":
    sys.exit(main())
