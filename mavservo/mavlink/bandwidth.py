"""The autopilot link's bandwidth budget: telemetry rates that leave a telemetry radio room.

ArduPilot forwards everything a companion sends to the ground station's link; on a 57,600-baud
radio (about 5.7 kB/s for everything the vehicle says) the bridge's telemetry at its configured
rates (about 100 NAMED_VALUE_FLOAT a second for nine servos) would take all of it. So the bridge
gives its periodic telemetry on the autopilot link a budget in bytes per second
(``mavlink.link_budget_bytes_s``) and scales the streams down to fit, evenly, except that the
gimbal's attitude status never drops below the 5 Hz ArduPilot needs. The monitor outputs are
local: they keep the configured rates.

The scaling is a decimation of what :class:`~mavservo.mavlink.telemetry.Telemetry` produces: each
stream (a NAMED_VALUE_FLOAT name, an ESC_TELEMETRY group, ...) passes the fraction ``ratio`` of
its messages, spread evenly (a Bresenham-style credit per stream), so a 2 Hz value at ratio 0.25
goes out every 2 s and never in bursts. Heartbeats, acknowledgements, STATUSTEXT and answers to
requests are never held back; :data:`EVENT_RESERVE` of the budget is left for them.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.mavlink.esc_status import ESC_INFO_HZ
from mavservo.mavlink.wip_messages import EscInfo, EscStatus

#: MAVLink 2 framing around a payload: 10-byte header and 2-byte checksum.
FRAME_OVERHEAD = 12
#: A signature adds link id, timestamp and signature.
SIGNATURE_BYTES = 13
#: Share of the budget kept free for event traffic (STATUSTEXT, COMMAND_ACK, answers).
EVENT_RESERVE = 0.1
#: ArduPilot's mount driver wants the gimbal's attitude status at least this often.
GIMBAL_STATUS_FLOOR_HZ = 5.0
#: NAMED_VALUE_FLOAT names per servo each period: flt, hlt, pos, vel, cur, tmp, sp.
NAMES_PER_SERVO = 7


def frame_bytes(message_class: Any, signed: bool) -> int:
    """Largest frame of a message type (MAVLink 2 trims trailing zeros; budget the worst)."""
    return FRAME_OVERHEAD + message_class.unpacker.size + (SIGNATURE_BYTES if signed else 0)


@dataclass(frozen=True)
class StreamCost:
    """One kind of periodic telemetry: messages per second at its configured rate, frame size."""

    name: str
    hz: float
    messages_per_s: float
    frame_bytes: int
    floor_ratio: float = 0.0

    @property
    def bytes_per_s(self) -> float:
        return self.messages_per_s * self.frame_bytes


@dataclass(frozen=True)
class BudgetPlan:
    """What the budget does to each stream: the ratio of its messages sent on the link."""

    budget_bytes_s: float | None
    fixed_bytes_s: float
    streams: tuple[StreamCost, ...]
    ratios: Mapping[str, float]

    @property
    def full_bytes_s(self) -> float:
        """The link's periodic load at the configured rates (what the monitor outputs get)."""
        return self.fixed_bytes_s + sum(s.bytes_per_s for s in self.streams)

    @property
    def link_bytes_s(self) -> float:
        """The link's periodic load with the budget applied."""
        return self.fixed_bytes_s + sum(s.bytes_per_s * self.ratios[s.name] for s in self.streams)

    def lines(self) -> list[str]:
        """``check``'s estimate: load per link, and the rate of each scaled stream."""
        full = f"{self.full_bytes_s:,.0f} B/s"
        if self.budget_bytes_s is None:
            return [
                f"autopilot link: {full} of periodic telemetry (no budget)",
                f"monitor outputs: {full} each",
            ]
        lines = [
            f"autopilot link: {self.link_bytes_s:,.0f} B/s of periodic telemetry within a budget "
            f"of {self.budget_bytes_s:,.0f} B/s ({full} at the configured rates)"
        ]
        for stream in self.streams:
            ratio = self.ratios[stream.name]
            if stream.messages_per_s and ratio < 1:
                lines.append(
                    f"  {stream.name}: {stream.hz * ratio:.2g} Hz on the link "
                    f"({stream.hz:g} Hz configured)"
                )
        lines.append(f"monitor outputs: {full} each (configured rates)")
        return lines


def plan_budget(
    budget_bytes_s: float | None,
    *,
    servos: int,
    gimbals: int,
    health_names: int,
    components: int,
    rates: Any,
    signed: bool,
) -> BudgetPlan:
    """Scale the periodic streams so they fit ``budget_bytes_s`` (None: no scaling).

    ``rates`` is the telemetry rates section (``..._hz`` attributes); ``components`` counts the
    heartbeats (one per component per second), which are never scaled.
    """
    heartbeat = frame_bytes(mavlink2.MAVLink_heartbeat_message, signed)
    fixed = components * heartbeat
    esc_groups = -(-servos // 4) if servos else 0
    gimbal_hz = rates.gimbal_attitude_status_hz
    streams = (
        StreamCost(
            "NAMED_VALUE_FLOAT",
            rates.named_value_float_hz,
            rates.named_value_float_hz * (servos * NAMES_PER_SERVO + health_names),
            frame_bytes(mavlink2.MAVLink_named_value_float_message, signed),
        ),
        StreamCost(
            "ESC_TELEMETRY",
            rates.esc_telemetry_hz,
            rates.esc_telemetry_hz * esc_groups,
            frame_bytes(mavlink2.MAVLink_esc_telemetry_1_to_4_message, signed),
        ),
        # gcs (issue 30): QGroundControl's ESC view, the same groups as ESC_TELEMETRY
        StreamCost(
            "ESC_STATUS",
            rates.esc_telemetry_hz,
            rates.esc_telemetry_hz * esc_groups,
            frame_bytes(EscStatus, signed),
        ),
        StreamCost(
            "ESC_INFO",
            min(ESC_INFO_HZ, rates.esc_telemetry_hz),
            min(ESC_INFO_HZ, rates.esc_telemetry_hz) * esc_groups,
            frame_bytes(EscInfo, signed),
        ),
        StreamCost(
            "ACTUATOR_OUTPUT_STATUS",
            rates.actuator_output_status_hz,
            rates.actuator_output_status_hz,
            frame_bytes(mavlink2.MAVLink_actuator_output_status_message, signed),
        ),
        StreamCost(
            "GIMBAL_DEVICE_ATTITUDE_STATUS",
            gimbal_hz,
            gimbal_hz * gimbals,
            frame_bytes(mavlink2.MAVLink_gimbal_device_attitude_status_message, signed),
            floor_ratio=min(1.0, GIMBAL_STATUS_FLOOR_HZ / gimbal_hz) if gimbal_hz > 0 else 0.0,
        ),
    )
    ratios = {s.name: 1.0 for s in streams}
    if budget_bytes_s is not None:
        ratios = _fit(budget_bytes_s * (1 - EVENT_RESERVE) - fixed, streams)
    return BudgetPlan(budget_bytes_s, fixed, streams, ratios)


def _fit(room: float, streams: tuple[StreamCost, ...]) -> dict[str, float]:
    """One common ratio for every stream, streams held at their floor taken out first."""
    ratios = {s.name: 1.0 for s in streams}
    free = [s for s in streams if s.bytes_per_s > 0]
    for _ in range(len(streams) + 1):  # each pass pins at least one stream or ends
        total = sum(s.bytes_per_s for s in free)
        if total <= room or total == 0:
            return ratios
        ratio = max(0.0, room) / total
        pinned = [s for s in free if s.floor_ratio > ratio]
        for stream in free:
            ratios[stream.name] = max(ratio, stream.floor_ratio)
        if not pinned:
            return ratios
        room -= sum(s.bytes_per_s * s.floor_ratio for s in pinned)
        free = [s for s in free if s not in pinned]
    return ratios


_STREAM_OF_TYPE = {
    "NAMED_VALUE_FLOAT": "NAMED_VALUE_FLOAT",
    "ACTUATOR_OUTPUT_STATUS": "ACTUATOR_OUTPUT_STATUS",
    "GIMBAL_DEVICE_ATTITUDE_STATUS": "GIMBAL_DEVICE_ATTITUDE_STATUS",
    "ESC_STATUS": "ESC_STATUS",  # gcs (issue 30)
    "ESC_INFO": "ESC_INFO",  # gcs (issue 30)
}


class LinkBudget:
    """Decides, message by message, what of the periodic telemetry also goes on the link."""

    def __init__(self, plan: BudgetPlan) -> None:
        self.plan = plan
        self._credit: dict[tuple[Any, ...], float] = {}
        self.counters: Counter[str] = Counter()

    def allow(self, component_id: int, msg: Any) -> bool:
        """True when ``msg`` goes on the autopilot link (it always goes to the monitors)."""
        kind = msg.get_type()
        stream = _STREAM_OF_TYPE.get(kind)
        if stream is None and kind.startswith("ESC_TELEMETRY_"):
            stream = "ESC_TELEMETRY"
        if stream is None:
            return True
        ratio = self.plan.ratios.get(stream, 1.0)
        if ratio >= 1.0:
            return True
        key = (component_id, kind, msg.name if kind == "NAMED_VALUE_FLOAT" else None)
        if kind in ("ESC_STATUS", "ESC_INFO"):  # gcs (issue 30): one stream per ESC group
            key = (component_id, kind, msg.index)
        credit = self._credit.get(key, 1.0) + ratio
        if credit >= 1.0:
            self._credit[key] = credit - 1.0
            return True
        self._credit[key] = credit
        self.counters["held_back"] += 1
        return False
