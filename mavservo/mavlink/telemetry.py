"""Servo telemetry out as MAVLink: what the servos measure, and events as STATUSTEXT.

No standard MAVLink message carries servo feedback, so the state of each servo is spread over the
carriers ground stations already understand (DESIGN.md, "MAVLink facts"):

* ACTUATOR_OUTPUT_STATUS (375): measured position normalized through the channel mapping, slot i
  = the servo's position in the config (0-based), ``active`` bit set when the position is known;
* ESC_TELEMETRY_1_TO_4 .. 29_TO_32 (11030..): temperature, voltage, current and "rpm" (|velocity|
  in deg/s / 6), four servos per message in config order; ground stations already show it;
* NAMED_VALUE_FLOAT (251): ``s<n>_pos`` (deg), ``s<n>_vel`` (deg/s), ``s<n>_cur`` (A),
  ``s<n>_tmp`` (degC), ``s<n>_sp`` (setpoint, deg, once there is one), n = config position + 1
  (all within the 10-character limit);
* STATUSTEXT (253): fault onset and clearance, servo offline / back online, link events; at most
  ``STATUSTEXT_BURST`` per second so a flapping servo cannot flood the link.

Rates come from the config and can be changed per message id by SET_MESSAGE_INTERVAL (-1 off,
0 back to the configured rate); REQUEST_MESSAGE sends one immediately. Pure: time comes in.
"""

from __future__ import annotations

import logging
import math
from collections import Counter, deque
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.mavlink.backend import ActuatorBackend, ServoStatus
from mavservo.mavlink.settings import TelemetryRates

log = logging.getLogger(__name__)

MSG_ACTUATOR_OUTPUT_STATUS = 375
MSG_ESC_TELEMETRY_1_TO_4 = 11030
MSG_NAMED_VALUE_FLOAT = 251
ESC_MESSAGES = [
    mavlink2.MAVLink_esc_telemetry_1_to_4_message,
    mavlink2.MAVLink_esc_telemetry_5_to_8_message,
    mavlink2.MAVLink_esc_telemetry_9_to_12_message,
    mavlink2.MAVLink_esc_telemetry_13_to_16_message,
    mavlink2.MAVLink_esc_telemetry_17_to_20_message,
    mavlink2.MAVLink_esc_telemetry_21_to_24_message,
    mavlink2.MAVLink_esc_telemetry_25_to_28_message,
    mavlink2.MAVLink_esc_telemetry_29_to_32_message,
]
ACTUATOR_SLOTS = 32
UINT16_MAX = 65535

MAV_SEVERITY_CRITICAL = 2
MAV_SEVERITY_WARNING = 4
MAV_SEVERITY_NOTICE = 5
MAV_SEVERITY_INFO = 6
STATUSTEXT_LENGTH = 50
STATUSTEXT_BURST = 4  # per second
STATUSTEXT_QUEUE = 32


def _clamp_u16(value: float) -> int:
    return int(max(0, min(UINT16_MAX, round(value))))


class _Stream:
    """One periodic message stream on absolute deadlines."""

    def __init__(self, default_hz: float) -> None:
        self.default_period = 1.0 / default_hz if default_hz > 0 else None
        self.period = self.default_period
        self.next_due = 0.0

    def set_interval_us(self, interval_us: float, now: float) -> None:
        if interval_us < 0:
            self.period = None
        elif interval_us == 0:
            self.period = self.default_period
        else:
            self.period = interval_us / 1e6
        self.next_due = now

    def due(self, now: float) -> bool:
        if self.period is None or now < self.next_due:
            return False
        self.next_due += self.period
        if self.next_due <= now:  # fell behind (stall): do not burst to catch up
            self.next_due = now + self.period
        return True


class Telemetry:
    """Builds the servo component's telemetry messages from backend snapshots."""

    def __init__(self, backend: ActuatorBackend, rates: TelemetryRates, boot_time: float):
        self._backend = backend
        self._boot = boot_time
        self._streams = {
            MSG_ACTUATOR_OUTPUT_STATUS: _Stream(rates.actuator_output_status_hz),
            MSG_ESC_TELEMETRY_1_TO_4: _Stream(rates.esc_telemetry_hz),
            MSG_NAMED_VALUE_FLOAT: _Stream(rates.named_value_float_hz),
        }
        self._known: dict[str, tuple[bool, Any]] = {}  # name -> (online, faults)
        self._texts: deque[tuple[int, str]] = deque()
        self._text_sent_at: deque[float] = deque()
        self._esc_count = 0
        self.counters: Counter[str] = Counter()

    # ------------------------------------------------------------------ services

    def publishes(self, msg_id: int) -> bool:
        return msg_id in self._streams

    def set_interval(self, msg_id: int, interval_us: float, now: float) -> bool:
        """SET_MESSAGE_INTERVAL: False when this component does not publish ``msg_id``."""
        stream = self._streams.get(msg_id)
        if stream is None:
            return False
        stream.set_interval_us(interval_us, now)
        log.info("telemetry: message %d interval set to %.0f us", msg_id, interval_us)
        return True

    def request(self, msg_id: int, now: float) -> list[Any] | None:
        """REQUEST_MESSAGE: the message(s) to send once, or None when not published."""
        if msg_id not in self._streams:
            return None
        return self._build(msg_id, self._backend.servo_statuses(), now)

    def announce(self, severity: int, text: str) -> None:
        """Queue a STATUSTEXT (sent by :meth:`periodic` within the rate limit)."""
        if len(self._texts) >= STATUSTEXT_QUEUE:
            self._texts.popleft()
            self.counters["statustext_dropped"] += 1
        self._texts.append((severity, text))
        log.info("statustext: %s", text)

    # ------------------------------------------------------------------ periodic

    def periodic(self, now: float) -> list[Any]:
        """Everything due at ``now``: event texts first, then the streams."""
        statuses = self._backend.servo_statuses()
        self._detect_events(statuses)
        out = self._drain_texts(now)
        for msg_id, stream in self._streams.items():
            if stream.due(now):
                out.extend(self._build(msg_id, statuses, now))
        return out

    def _detect_events(self, statuses: list[ServoStatus]) -> None:
        for status in statuses:
            faults = status.state.faults if status.state is not None else None
            previous = self._known.get(status.name)
            self._known[status.name] = (status.online, faults)
            if previous is None:
                continue
            was_online, old_faults = previous
            if was_online and not status.online:
                self.announce(MAV_SEVERITY_CRITICAL, f"servo {status.name} not responding")
            elif status.online and not was_online:
                self.announce(MAV_SEVERITY_NOTICE, f"servo {status.name} responding again")
            if faults is None or old_faults is None or faults == old_faults:
                continue
            new = faults & ~old_faults
            gone = old_faults & ~faults
            if new:
                self.announce(MAV_SEVERITY_CRITICAL, f"servo {status.name} fault {_names(new)}")
            if gone:
                self.announce(MAV_SEVERITY_NOTICE, f"servo {status.name} cleared {_names(gone)}")

    def _drain_texts(self, now: float) -> list[Any]:
        while self._text_sent_at and now - self._text_sent_at[0] >= 1.0:
            self._text_sent_at.popleft()
        out = []
        while self._texts and len(self._text_sent_at) < STATUSTEXT_BURST:
            severity, text = self._texts.popleft()
            self._text_sent_at.append(now)
            out.append(
                mavlink2.MAVLink_statustext_message(
                    severity, text[:STATUSTEXT_LENGTH].encode("ascii", "replace"), 0, 0
                )
            )
        return out

    # ------------------------------------------------------------------ builders

    def _build(self, msg_id: int, statuses: list[ServoStatus], now: float) -> list[Any]:
        if msg_id == MSG_ACTUATOR_OUTPUT_STATUS:
            return [self._actuator_output_status(statuses, now)]
        if msg_id == MSG_ESC_TELEMETRY_1_TO_4:
            return self._esc_telemetry(statuses)
        return self._named_values(statuses, now)

    def _actuator_output_status(self, statuses: list[ServoStatus], now: float) -> Any:
        values = [math.nan] * ACTUATOR_SLOTS
        active = 0
        for status in statuses:
            if status.index < ACTUATOR_SLOTS and status.normalized is not None:
                values[status.index] = float(status.normalized)
                active |= 1 << status.index
        return mavlink2.MAVLink_actuator_output_status_message(
            int((now - self._boot) * 1e6), active, values
        )

    def _esc_telemetry(self, statuses: list[ServoStatus]) -> list[Any]:
        by_index = {s.index: s for s in statuses}
        if not by_index:
            return []
        self._esc_count = (self._esc_count + 1) % (UINT16_MAX + 1)
        out = []
        for group in range(min(len(ESC_MESSAGES), max(by_index) // 4 + 1)):
            temps, volts, amps, rpms, counts = [0] * 4, [0] * 4, [0] * 4, [0] * 4, [0] * 4
            for slot in range(4):
                status = by_index.get(group * 4 + slot)
                state = status.state if status is not None else None
                if state is None:
                    continue
                temps[slot] = int(max(0, min(255, round(state.temperature_c))))
                volts[slot] = _clamp_u16((state.voltage_v or 0.0) * 100)
                amps[slot] = _clamp_u16(abs(state.current_a) * 100)
                rpms[slot] = _clamp_u16(abs(state.velocity_dps) / 6.0)
                counts[slot] = self._esc_count  # 0 stays in slots no servo fills
            out.append(ESC_MESSAGES[group](temps, volts, amps, [0] * 4, rpms, counts))
        return out

    def _named_values(self, statuses: list[ServoStatus], now: float) -> list[Any]:
        boot_ms = int((now - self._boot) * 1000) & 0xFFFFFFFF
        out = []
        for status in statuses:
            state = status.state
            if state is None:
                continue
            n = status.index + 1
            values = [
                ("pos", state.position_deg),
                ("vel", state.velocity_dps),
                ("cur", state.current_a),
                ("tmp", state.temperature_c),
            ]
            if status.setpoint_deg is not None:
                values.append(("sp", status.setpoint_deg))
            for suffix, value in values:
                out.append(
                    mavlink2.MAVLink_named_value_float_message(
                        boot_ms, f"s{n}_{suffix}".encode(), float(value)
                    )
                )
        # bus load and latency figures, when the backend offers them (``bus0_load``, ``lat_p99``)
        health = getattr(self._backend, "health", None)
        for name, value in (health() if health is not None else {}).items():
            out.append(
                mavlink2.MAVLink_named_value_float_message(
                    boot_ms, name[:10].encode(), float(value)
                )
            )
        return out


def _names(flags: Any) -> str:
    """Readable names of an enum.Flag value (``stall|over_current``)."""
    members = [m.name for m in type(flags) if m.value and m in flags and m.name]
    return "|".join(members).lower() or str(flags)
