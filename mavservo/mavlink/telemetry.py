"""Servo telemetry out as MAVLink: what the servos measure, and events as STATUSTEXT.

No standard MAVLink message carries servo feedback, so the state of each servo is spread over the
carriers ground stations already understand (DESIGN.md, "MAVLink facts"):

* ACTUATOR_OUTPUT_STATUS (375): measured position normalized through the channel mapping, slot i
  = the servo's position in the config (0-based), ``active`` bit set when the position is known;
* ESC_TELEMETRY_1_TO_4 .. 29_TO_32 (11030..): temperature, voltage, current and "rpm" (|velocity|
  in deg/s / 6), four servos per message in config order; ground stations already show it. Each
  message id that has a servo in it is its own stream (its own interval, its own REQUEST_MESSAGE);
* NAMED_VALUE_FLOAT (251): ``s<n>_pos`` (deg), ``s<n>_vel`` (deg/s), ``s<n>_cur`` (A),
  ``s<n>_tmp`` (degC), ``s<n>_sp`` (setpoint, deg, once there is one), ``s<n>_flt`` (the
  :class:`~mavservo.servos.base.Fault` bits as a number, NO_REPLY set while the servo is
  offline, so a late ground station or monitor learns current problems without waiting for an
  event), ``s<n>_hlt`` (the bridge's own health findings, :class:`~mavservo.mavlink.backend.
  Health` bits, docs/health.md), n = config position + 1 (all within the 10-character limit);
* STATUSTEXT (253): fault onset and clearance, servo offline / back online (also when the very
  first state is already bad; repeats of one servo's problem within 10 s are counted and summed
  up, ``servo aileron offline (x5 in 10 s)``, :mod:`mavservo.records.repeats`), link events;
  every active problem is repeated every
  ``REMINDER_S`` for ground stations that connect later; texts longer than 50 characters go out
  as MAVLink 2 chunks (``id`` != 0, ``chunk_seq``); at most ``STATUSTEXT_BURST`` texts per
  second so a flapping servo cannot flood the link.

Values a servo has not reported yet are NaN: float fields carry NaN (MAVLink's "unknown"),
integer fields of ESC_TELEMETRY carry 0 (the message has no "unknown" value), and a position
that is not finite leaves the ACTUATOR_OUTPUT_STATUS slot inactive.

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
from mavservo.mavlink.esc_status import ESC_INFO_HZ, esc_info, esc_status
from mavservo.mavlink.settings import TelemetryRates
from mavservo.mavlink.statustext_queue import TextQueue
from mavservo.records import BACK_ONLINE, OFFLINE, Key, Repeats
from mavservo.servos import NO_FAULT, Fault

log = logging.getLogger(__name__)

MSG_ACTUATOR_OUTPUT_STATUS = 375
MSG_NAMED_VALUE_FLOAT = 251
#: ESC_INFO / ESC_STATUS (QGroundControl's ESC view): one message per ESC_TELEMETRY group
MSG_ESC_INFO = 290
MSG_ESC_STATUS = 291
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
STATUSTEXT_LENGTH = 50
#: a longer text is sent in chunks; beyond this many it is cut. Six hold 300 characters, the
#: longest text the bridge says (the 237-character AP_Periph safety warning, with the setting
#: that fixes it at its end, lost it when four chunks cut it at 199)
STATUSTEXT_MAX_CHUNKS = 6
#: every active problem (fault, offline) is announced again this often, for late listeners
REMINDER_S = 20.0
STATUSTEXT_BURST = 4  # per second
STATUSTEXT_QUEUE = 32
FLOAT32_MAX = 3.4028234663852886e38


def _clamp_u16(value: float | None) -> int:
    """An unsigned 16-bit field; unknown (None, NaN) is 0, infinities clamp."""
    if value is None or math.isnan(value):
        return 0
    return (
        int(max(0, min(UINT16_MAX, round(value))))
        if math.isfinite(value)
        else (UINT16_MAX if value > 0 else 0)
    )


def float32_field(value: float) -> float:
    """``value`` as a float32 field can carry it: beyond float32's range (a servo's garbage
    reading scaled to degrees, 3e38 motor turns) it is an infinity of its sign, which a
    float32 encodes; the encoder would refuse the value itself and drop the message."""
    number = float(value)
    if math.isfinite(number) and abs(number) > FLOAT32_MAX:
        return math.copysign(math.inf, number)
    return number


def _clamp_u8(value: float | None) -> int:
    """An unsigned 8-bit field (ESC temperature); unknown is 0 like an empty slot."""
    if value is None or math.isnan(value):
        return 0
    return (
        int(max(0, min(255, round(value)))) if math.isfinite(value) else (255 if value > 0 else 0)
    )


ESC_IDS = {cls.id: group for group, cls in enumerate(ESC_MESSAGES)}
#: ESC number of the first servo with ``esc_first_index: auto``: ESC_TELEMETRY_17_TO_20, above
#: the motors of every common frame (an octocopter's or quadplane's ESCs are 1..16).
AUTO_ESC_FIRST = 17
DEFAULT_NAME_PREFIX = "s"


def _problems(status: ServoStatus) -> tuple[bool, Any]:
    """(online, faults) as the events compare them; NO_REPLY is reported as "offline"."""
    faults = status.state.faults if status.state is not None else NO_FAULT
    return status.online, faults & ~Fault.NO_REPLY


def statustext_chunks(text: str) -> list[bytes]:
    """``text`` as the ``text`` fields of its STATUSTEXT messages, each broken after a space.

    MAVLink's STATUSTEXT (common.xml, message 253): ``text`` is 50 characters, "Any null
    character in the text field is taken to mean this was the last chunk", so every chunk but
    the last must be full; receivers rely on it (QGroundControl's StatusTextHandler takes a
    chunk shorter than 50 as the last, as MAVProxy's mavproxy_link.py ``PendingText`` does).
    A chunk is therefore broken after the last space that fits and padded with spaces to 50:
    a ground station that shows chunks one by one never shows half a word, one that joins
    them shows a few extra spaces (``mavservo monitor`` drops them). A word longer than a
    chunk is broken where the chunk is full. A text that fills its last chunk exactly gets an
    empty chunk, the NUL that ends it. Beyond :data:`STATUSTEXT_MAX_CHUNKS` the text is cut
    at a word, with "...".
    """
    data = text.encode("ascii", "replace")
    if len(data) <= STATUSTEXT_LENGTH:
        return [data]  # one message, id 0: "the only chunk in the sequence"
    chunks: list[bytes] = []
    while len(data) >= STATUSTEXT_LENGTH:
        cut = data.rfind(b" ", 0, STATUSTEXT_LENGTH) + 1 or STATUSTEXT_LENGTH
        chunks.append(data[:cut].ljust(STATUSTEXT_LENGTH))
        data = data[cut:]
    chunks.append(data)
    if len(chunks) > STATUSTEXT_MAX_CHUNKS:
        last = chunks[STATUSTEXT_MAX_CHUNKS - 1].rstrip()
        chunks[STATUSTEXT_MAX_CHUNKS - 1 :] = [last[: STATUSTEXT_LENGTH - 4] + b"..."]
    return chunks


def join_statustext_chunks(chunks: list[str]) -> str:
    """A chunked text as it was said, from its chunks' texts in ``chunk_seq`` order: a chunk
    padded with spaces (:func:`statustext_chunks`) ends with one space."""
    return "".join(
        chunk.rstrip(" ") + " " if chunk.endswith(" ") and seq < len(chunks) - 1 else chunk
        for seq, chunk in enumerate(chunks)
    )


def statustext_messages(severity: int, text: str, text_id: int) -> list[Any]:
    """STATUSTEXT for ``text``: one message (id 0) up to 50 characters, else MAVLink 2 chunks
    (:func:`statustext_chunks`) numbered by ``chunk_seq`` under ``text_id`` (1..65535)."""
    chunks = statustext_chunks(text)
    if len(chunks) == 1:
        return [mavlink2.MAVLink_statustext_message(severity, chunks[0], 0, 0)]
    return [
        mavlink2.MAVLink_statustext_message(severity, chunk, text_id, seq)
        for seq, chunk in enumerate(chunks)
    ]


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
            **{msg_id: _Stream(rates.esc_telemetry_hz) for msg_id in ESC_IDS},
            MSG_NAMED_VALUE_FLOAT: _Stream(rates.named_value_float_hz),
            **{msg_id: _Stream(hz) for msg_id, hz in _esc_view_rates(rates).items()},
        }
        self._esc_info_count = 0
        self._known: dict[str, tuple[bool, Any]] = {}  # name -> (online, faults)
        self._repeats = Repeats()
        self._texts = TextQueue(STATUSTEXT_QUEUE)
        self._text_sent_at: deque[float] = deque()
        self._text_id = 0
        self._next_reminder: float | None = None
        self._esc_counts = [0] * len(ESC_MESSAGES)
        self.counters: Counter[str] = Counter()
        self.name_prefix = rates.name_prefix
        #: ESC number (1-based) of the first servo; "auto" starts above common motor counts and
        #: moves when someone else is heard on the same ESC numbers (see :meth:`heard_esc`)
        self.esc_auto = rates.esc_first_index == "auto"
        self.esc_first = AUTO_ESC_FIRST if self.esc_auto else int(rates.esc_first_index)
        self._esc_others: set[int] = set()  # groups someone else publishes
        self._esc_warned: set[tuple[int, int]] = set()

    # ------------------------------------------------------------------ services

    def publishes(self, msg_id: int) -> bool:
        """Whether ``msg_id`` is one of ours: an ESC_TELEMETRY group only if a servo is in it."""
        if msg_id in ESC_IDS:
            return ESC_IDS[msg_id] in self.esc_groups(self._backend.servo_statuses())
        if msg_id in (MSG_ESC_INFO, MSG_ESC_STATUS):
            return bool(self.esc_groups(self._backend.servo_statuses()))
        return msg_id in self._streams

    # ------------------------------------------------------------------ ESC numbers

    def esc_number(self, index: int) -> int:
        """The ESC number (1-based, as ground stations show it) of the servo at ``index``."""
        return self.esc_first + index

    def esc_groups(self, statuses: list[ServoStatus]) -> set[int]:
        """The ESC_TELEMETRY messages (0 = 1_TO_4) the servos fill; ESC numbers past 32 have no
        message and are not published."""
        return {
            (self.esc_number(s.index) - 1) // 4
            for s in statuses
            if self.esc_number(s.index) <= 4 * len(ESC_MESSAGES)
        }

    def heard_esc(self, source: tuple[int, int], group: int, *, yield_to: bool) -> None:
        """Someone else (``source``) publishes ESC_TELEMETRY group ``group`` on this vehicle.

        A ground station files ESC data by system id only, so the same ESC numbers from two
        components show one's data as the other's. With ``esc_first_index: auto`` the servos
        move above every group heard (``yield_to``: the other one has precedence, e.g. the
        autopilot or a bridge with a lower component id; otherwise the other one moves);
        with a fixed index, or no room left, a warning says what to set.
        """
        self._esc_others.add(group)
        statuses = self._backend.servo_statuses()
        if group not in self.esc_groups(statuses) or not yield_to:
            return
        if self.esc_auto:
            first = 4 * (max(self._esc_others) + 1) + 1
            if first + len(statuses) - 1 <= 4 * len(ESC_MESSAGES):
                self.esc_first = first
                self.counters["esc_moved"] += 1
                last = self.esc_number(len(statuses) - 1)
                self.announce(
                    MAV_SEVERITY_NOTICE,
                    f"servo ESC telemetry moved to ESC {first}-{last}: ESC {4 * group + 1}-"
                    f"{4 * group + 4} are {source[0]}/{source[1]}'s",
                )
                return
        if (source[1], group) in self._esc_warned:
            return
        self._esc_warned.add((source[1], group))
        self.counters["esc_collisions"] += 1
        self.announce(
            MAV_SEVERITY_WARNING,
            f"ESC {4 * group + 1}-{4 * group + 4} also come from {source[0]}/{source[1]}: set "
            "mavlink.telemetry.esc_first_index above its ESCs",
        )

    def set_rates(self, rates: TelemetryRates, now: float) -> None:
        """New default rates (a ground station's TEL_*_HZ parameters), in force at once; a
        rate a SET_MESSAGE_INTERVAL chose keeps its interval until that is reset."""
        defaults = {
            MSG_ACTUATOR_OUTPUT_STATUS: rates.actuator_output_status_hz,
            **{msg_id: rates.esc_telemetry_hz for msg_id in ESC_IDS},
            MSG_NAMED_VALUE_FLOAT: rates.named_value_float_hz,
            **_esc_view_rates(rates),
        }
        for msg_id, hz in defaults.items():
            stream = self._streams[msg_id]
            overridden = stream.period != stream.default_period
            stream.default_period = 1.0 / hz if hz > 0 else None
            if not overridden:
                stream.period = stream.default_period
                stream.next_due = now

    def rates_hz(self) -> dict[str, float]:
        """The rates in force (after parameters and SET_MESSAGE_INTERVAL), by ``..._hz`` key
        of the telemetry section, for re-planning the link budget (ESC: the fastest group)."""

        def hz(msg_id: int) -> float:
            period = self._streams[msg_id].period
            return 1.0 / period if period else 0.0

        return {
            "actuator_output_status_hz": hz(MSG_ACTUATOR_OUTPUT_STATUS),
            "esc_telemetry_hz": max((hz(msg_id) for msg_id in ESC_IDS), default=0.0),
            "named_value_float_hz": hz(MSG_NAMED_VALUE_FLOAT),
        }

    def interval_refusal(self, msg_id: int, interval_us: float) -> str | None:
        """Why SET_MESSAGE_INTERVAL may not set ``interval_us`` (None: it may). A stream may be
        slowed, stopped or reset by anyone the link lets command, never made faster than its
        configured rate (the YAML's, or TEL_*_HZ set by a parameter writer).

        Why (review3): one stranger's SET_MESSAGE_INTERVAL of 1 us for NAMED_VALUE_FLOAT
        re-planned the link budget for a 1 MHz stream: every stream's ratio fell to 1.5e-6,
        and ACTUATOR_OUTPUT_STATUS and ESC_TELEMETRY stopped on the autopilot link (6 and 3 in
        4 s before, 0 after) until a restart; parameters that raise rates are for writers."""
        stream = self._streams.get(msg_id)
        if stream is None or interval_us <= 0:
            return None
        period = stream.default_period
        if period is not None and interval_us / 1e6 >= period * (1 - 1e-9):
            return None
        ceiling = "off" if period is None else f"{1.0 / period:g} Hz"
        return (
            f"{interval_us:.0f} us is faster than the configured rate ({ceiling}); "
            "a rate is raised by the config or its TEL_*_HZ parameter"
        )

    def set_interval(self, msg_id: int, interval_us: float, now: float) -> bool:
        """SET_MESSAGE_INTERVAL: False when this component does not publish ``msg_id``."""
        stream = self._streams.get(msg_id)
        if stream is None or not self.publishes(msg_id):
            return False
        stream.set_interval_us(interval_us, now)
        log.info("telemetry: message %d interval set to %.0f us", msg_id, interval_us)
        return True

    def request(self, msg_id: int, now: float) -> list[Any] | None:
        """REQUEST_MESSAGE: the message(s) to send once, or None when not published."""
        if not self.publishes(msg_id):
            return None
        return self._build(msg_id, self._backend.servo_statuses(), now)

    def announce(self, severity: int, text: str, essential: bool = False) -> None:
        """Queue a STATUSTEXT (sent by :meth:`periodic` within the rate limit); CRITICAL ones
        and ``essential`` ones go first and are never dropped for others (:class:`TextQueue`)."""
        dropped = self._texts.dropped
        self._texts.put(severity, text, essential)
        if self._texts.dropped != dropped:
            self.counters["statustext_dropped"] += self._texts.dropped - dropped
        log.info("statustext: %s", text)

    # ------------------------------------------------------------------ periodic

    def periodic(self, now: float) -> list[Any]:
        """Everything due at ``now``: event texts first, then the streams.

        A message that fails to build (a bug, a value no encoder expected) is left out, logged
        with its traceback the first time and counted (``build_errors``): the other messages,
        and the heartbeats the caller sends, must go on whatever one servo reports.
        """
        statuses = self._backend.servo_statuses()
        self._detect_events(statuses, now)
        out = self._drain_texts(now)
        groups = self.esc_groups(statuses)
        for msg_id, stream in self._streams.items():
            if msg_id in ESC_IDS and ESC_IDS[msg_id] not in groups:
                continue
            if stream.due(now):
                try:
                    out.extend(self._build(msg_id, statuses, now))
                except Exception:  # noqa: BLE001 - one message must not stop the output
                    self.counters["build_errors"] += 1
                    key = f"build_errors_{msg_id}"
                    if not self.counters[key]:
                        log.exception("telemetry: building message %d failed (left out)", msg_id)
                    self.counters[key] += 1
        return out

    def _detect_events(self, statuses: list[ServoStatus], now: float) -> None:
        """Announce changes; a servo first seen offline or faulted counts as a change from
        "online, no fault", and active problems are repeated every ``REMINDER_S``. Each
        servo's onsets and clearings of one kind (offline, each fault bit) go through
        :class:`~mavservo.records.Repeats`: a flapping servo's repeats within its interval are
        counted and summed up in one text, as the console's scheduler log does."""
        for status in statuses:
            online, faults = _problems(status)
            was_online, old_faults = self._known.get(status.name, (True, NO_FAULT))
            self._known[status.name] = (online, faults)
            subject = f"servo {status.name}"
            if was_online and not online:
                self._onset((subject, OFFLINE), f"{subject} {OFFLINE}", now)
            elif online and not was_online:
                self._clear((subject, OFFLINE), f"{subject} {BACK_ONLINE}")
            if faults == old_faults:
                continue
            for bit in _bits(faults & ~old_faults):
                self._onset((subject, f"fault {bit}"), f"{subject} fault {bit}", now)
            for bit in _bits(old_faults & ~faults):
                self._clear((subject, f"fault {bit}"), f"{subject} cleared {bit}")
        for summary in self._repeats.flush(now):
            severity = MAV_SEVERITY_CRITICAL if summary.active else MAV_SEVERITY_WARNING
            self.announce(severity, summary.text)
        self.counters["statustext_repeats_counted"] = self._repeats.counted
        if self._next_reminder is None:
            self._next_reminder = now + REMINDER_S
        elif now >= self._next_reminder:
            self._next_reminder = max(self._next_reminder + REMINDER_S, now)
            self._remind()

    def _onset(self, key: Key, text: str, now: float) -> None:
        said = self._repeats.onset(key, text, now)
        if said is not None:
            self.announce(MAV_SEVERITY_CRITICAL, said)

    def _clear(self, key: Key, text: str) -> None:
        said = self._repeats.clear(key, text)
        if said is not None:
            self.announce(MAV_SEVERITY_NOTICE, said)

    def _remind(self) -> None:
        """Repeat the active problems, in the wording of the events, so a late listener (and
        ``mavservo monitor``) learns them; never at the cost of events already queued."""
        for name, (online, faults) in self._known.items():
            texts = [] if online else [f"servo {name} {OFFLINE}"]
            texts.extend(f"servo {name} fault {bit}" for bit in _bits(faults))
            for text in texts:
                if len(self._texts) >= STATUSTEXT_QUEUE // 2:
                    self.counters["reminders_skipped"] += 1
                    continue
                self.counters["reminders"] += 1
                self.announce(MAV_SEVERITY_WARNING, text)

    def _drain_texts(self, now: float) -> list[Any]:
        while self._text_sent_at and now - self._text_sent_at[0] >= 1.0:
            self._text_sent_at.popleft()
        out = []
        while self._texts and len(self._text_sent_at) < STATUSTEXT_BURST:
            next_text = self._texts.pop()
            if next_text is None:
                break
            severity, text = next_text
            self._text_sent_at.append(now)
            self.counters["statustext_sent"] += 1
            if len(text) > STATUSTEXT_LENGTH:
                self._text_id = self._text_id % UINT16_MAX + 1
            out.extend(statustext_messages(severity, text, self._text_id))
        return out

    # ------------------------------------------------------------------ builders

    def _build(self, msg_id: int, statuses: list[ServoStatus], now: float) -> list[Any]:
        if msg_id == MSG_ACTUATOR_OUTPUT_STATUS:
            return [self._actuator_output_status(statuses, now)]
        if msg_id in ESC_IDS:
            return self._esc_telemetry(statuses, ESC_IDS[msg_id])
        if msg_id in (MSG_ESC_INFO, MSG_ESC_STATUS):
            return self._esc_view(msg_id, statuses, now)
        return self._named_values(statuses, now)

    def _esc_view(self, msg_id: int, statuses: list[ServoStatus], now: float) -> list[Any]:
        """ESC_INFO or ESC_STATUS for every group ESC_TELEMETRY fills (same ESC numbers)."""
        time_usec = int((now - self._boot) * 1e6)
        groups = sorted(self.esc_groups(statuses))
        if msg_id == MSG_ESC_STATUS:
            return [esc_status(statuses, g, self.esc_number, time_usec=time_usec) for g in groups]
        self._esc_info_count += 1
        return [
            esc_info(
                statuses, g, self.esc_number, counter=self._esc_info_count, time_usec=time_usec
            )
            for g in groups
        ]

    def _actuator_output_status(self, statuses: list[ServoStatus], now: float) -> Any:
        values = [math.nan] * ACTUATOR_SLOTS
        active = 0
        for status in statuses:
            if (
                status.index < ACTUATOR_SLOTS
                and status.normalized is not None
                and math.isfinite(status.normalized)
            ):
                values[status.index] = float32_field(status.normalized)
                active |= 1 << status.index
        return mavlink2.MAVLink_actuator_output_status_message(
            int((now - self._boot) * 1e6), active, values
        )

    def _esc_telemetry(self, statuses: list[ServoStatus], group: int) -> list[Any]:
        """ESC_TELEMETRY for ESC numbers ``4 * group + 1`` .. ``+ 4`` (none if no servo is)."""
        if group not in self.esc_groups(statuses):
            return []
        by_slot = {self.esc_number(s.index) - 1 - 4 * group: s for s in statuses}
        self._esc_counts[group] = (self._esc_counts[group] + 1) % (UINT16_MAX + 1)
        temps, volts, amps, rpms, counts = [0] * 4, [0] * 4, [0] * 4, [0] * 4, [0] * 4
        for slot in range(4):
            status = by_slot.get(slot)
            # an offline servo's last state is old news: its slot reads as empty (count 0)
            state = status.state if status is not None and status.online else None
            if state is None:
                continue
            temps[slot] = _clamp_u8(state.temperature_c)
            volts[slot] = _clamp_u16(None if state.voltage_v is None else state.voltage_v * 100)
            amps[slot] = _clamp_u16(abs(state.current_a) * 100)
            rpms[slot] = _clamp_u16(abs(state.velocity_dps) / 6.0)
            counts[slot] = self._esc_counts[group]  # 0 stays in slots no servo fills
        return [ESC_MESSAGES[group](temps, volts, amps, [0] * 4, rpms, counts)]

    def _named_values(self, statuses: list[ServoStatus], now: float) -> list[Any]:
        boot_ms = int((now - self._boot) * 1000) & 0xFFFFFFFF
        out = []
        for status in statuses:
            n = status.index + 1
            online, faults = _problems(status)
            flags = faults.value | (0 if online else Fault.NO_REPLY.value)
            out.append(
                mavlink2.MAVLink_named_value_float_message(
                    boot_ms, f"{self.name_prefix}{n}_flt".encode(), flags
                )
            )
            # health (issue 33): what the bridge finds itself, kept even while offline (an
            # episode clears only when the servo is back and the condition is gone)
            out.append(
                mavlink2.MAVLink_named_value_float_message(
                    boot_ms, f"{self.name_prefix}{n}_hlt".encode(), status.health.value
                )
            )
            state = status.state
            if state is None or not online:  # s<n>_flt says NO_REPLY; old values would mislead
                continue
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
                        boot_ms, f"{self.name_prefix}{n}_{suffix}".encode(), float32_field(value)
                    )
                )
        # where the servos are in ESC_TELEMETRY (``esc_first``: ESC number of servo 1), so a
        # dashboard maps ESC data back to servos, and bus load and latency figures
        # (``bus0_load``, ``lat_p99``); a backend may have none of the latter
        figures = {"esc_first": float(self.esc_first), **self._backend.health()}
        for name, value in figures.items():
            # a second bridge's figures carry its prefix too (``tbus0_load``), so two bridges'
            # bus loads never read as one; the default keeps the names documented in the README
            label = name if self.name_prefix == DEFAULT_NAME_PREFIX else self.name_prefix + name
            out.append(
                mavlink2.MAVLink_named_value_float_message(
                    boot_ms, label[:10].encode(), float(value)
                )
            )
        return out


def _esc_view_rates(rates: TelemetryRates) -> dict[int, float]:
    """ESC_STATUS at the ESC telemetry rate, ESC_INFO at 1 Hz (never faster than that)."""
    return {
        MSG_ESC_STATUS: rates.esc_telemetry_hz,
        MSG_ESC_INFO: min(ESC_INFO_HZ, rates.esc_telemetry_hz),
    }


def _bits(flags: Any) -> list[str]:
    """Readable names of the bits set in an enum.Flag value (``["stall", "over_current"]``)."""
    members = [m.name.lower() for m in type(flags) if m.value and m in flags and m.name]
    return members or ([str(flags)] if flags else [])
