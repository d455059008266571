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
goes out every 2 s and never in bursts. :data:`EVENT_RESERVE` of the rate is left for events.

The plan is an average; a telemetry radio's buffer is small, so every message on the link also
passes a token bucket (:class:`~mavservo.mavlink.pacing.TokenBucket`): rate ``r``, depth ``C``,
and events (heartbeats, acknowledgements, STATUSTEXT) may run ``D`` into debt. In any interval of
length T the link carries at most C + r*T + D bytes, so with C + r + D = budget no 1-second
window exceeds the budget (issue 30, item 5: the average was under it, 25 of 60 seconds were
not). Periodic telemetry and answers to requests take tokens only while half the depth stays
for events (telemetry is then held back and counted, answers wait in their queue), events
(STATUSTEXT, COMMAND_ACK) may take the rest and the debt; heartbeats and CRITICAL texts always go
(counted in ``essential_over_budget`` when they exceed it).
Sizes are the worst case of each message type (MAVLink 2 trims trailing zeros: real frames are
shorter), so the bound holds for the bytes really sent.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.mavlink.esc_status import ESC_INFO_HZ
from mavservo.mavlink.pacing import TokenBucket
from mavservo.mavlink.wip_messages import EscInfo, EscStatus

#: MAVLink 2 framing around a payload: 10-byte header and 2-byte checksum.
FRAME_OVERHEAD = 12
#: A signature adds link id, timestamp and signature.
SIGNATURE_BYTES = 13
#: Share of the bucket's rate kept free for event traffic (STATUSTEXT, COMMAND_ACK, answers).
EVENT_RESERVE = 0.1
#: Share of the bucket's rate answers to requests (parameter lists and reads, FTP) may use at
#: most: a read flood from a stranger starved the autopilot's telemetry when answers and
#: telemetry competed for the same tokens without a cap. While answers flow, telemetry gets
#: the rest (held back and counted in ``held_back_window``); without requests, all of it.
RESERVATION_S = 1.0
"""How long a periodic stream held back by the window keeps other streams waiting for it (its
messages come again within its period; a stream that stopped frees the window after this)."""
ANSWER_SHARE = 0.3
#: Depth of the answers' own bucket: the largest MAVLink 2 frame (an FTP data packet, signed).
ANSWER_DEPTH_BYTES = 280
#: The token bucket's depth (at least the largest frame) and the events' debt, as shares of
#: the budget; the rest is its rate.
BUCKET_DEPTH_SHARE = 0.2
EVENT_DEBT_SHARE = 0.05

#: Periodic streams the autopilot's own health check needs: they take the window's turn from
#: any other stream. ArduPilot's MAVLink mount (``AP_Mount_Gremsy::healthy``, master
#: 90700977c5) calls the gimbal unhealthy, and refuses to arm, after 1 s without a
#: GIMBAL_DEVICE_ATTITUDE_STATUS; against ArduPlane SITL, behind ~70 other streams at the
#: default budget, gaps of up to 6.3 s came out (docs/sitl.md).
_URGENT_STREAMS = frozenset({"GIMBAL_DEVICE_ATTITUDE_STATUS"})
#: MAV_SEVERITY_CRITICAL: STATUSTEXT this grave always goes.
_CRITICAL = 2
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
    signed: bool = False

    @property
    def bucket(self) -> tuple[float, float, float]:
        """(rate, depth, debt) of the link's token bucket, in bytes; rate + depth + debt is the
        budget (the depth at least one frame of the largest periodic message)."""
        budget = self.budget_bytes_s or 0.0
        largest = max((s.frame_bytes for s in self.streams), default=0)
        depth = max(budget * BUCKET_DEPTH_SHARE, float(largest))
        debt = budget * EVENT_DEBT_SHARE
        return max(budget - depth - debt, budget * 0.1), depth, debt

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
        rate, depth, debt = self.bucket
        lines.append(
            f"  every message within a token bucket of {rate:,.0f} B/s, {depth:,.0f} B deep "
            f"(+{debt:,.0f} B for events): no second above {self.budget_bytes_s:,.0f} B/s"
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
    plan = BudgetPlan(budget_bytes_s, fixed, streams, ratios, signed)
    if budget_bytes_s is not None:
        rate = plan.bucket[0]
        ratios = _fit(rate * (1 - EVENT_RESERVE) - fixed, streams)
    return BudgetPlan(budget_bytes_s, fixed, streams, ratios, signed)


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
    """Decides, message by message, what goes on the autopilot link (monitors get everything):
    periodic telemetry decimated by the plan, and everything within the token bucket."""

    def __init__(self, plan: BudgetPlan) -> None:
        self._credit: dict[tuple[Any, ...], float] = {}
        self.counters: Counter[str] = Counter()
        self.plan = plan
        self._scratch = mavlink2.MAVLink(None)
        self._bucket: TokenBucket | None = None
        self._answers: TokenBucket | None = None
        #: the periodic stream (its key) waiting for the window, and since when
        self._reserved: tuple[tuple[Any, ...], float] | None = None
        self.replan(plan)

    def replan(self, plan: BudgetPlan, now: float | None = None) -> None:
        """A new plan (rates changed by parameter or SET_MESSAGE_INTERVAL); the bucket keeps
        its tokens, so the change cannot open a burst."""
        self.plan = plan
        if plan.budget_bytes_s is None:
            self._bucket = self._answers = None
            return
        rate, depth, _ = plan.bucket
        before = self._bucket, self._answers
        self._bucket = TokenBucket(rate, depth, now)
        self._answers = TokenBucket(rate * ANSWER_SHARE, ANSWER_DEPTH_BYTES, now)
        for old, new in zip(before, (self._bucket, self._answers), strict=True):
            if old is not None:  # a re-plan (a stranger's SET_MESSAGE_INTERVAL) refills nothing
                new.tokens = min(old.tokens, new.capacity)
        if before[0] is not None:
            self.counters["replans"] += 1

    def _cost(self, msg: Any) -> int:
        """The bytes ``msg`` takes on the link: packed by a scratch encoder (MAVLink 2 trims
        trailing zeros), plus the signature when the link signs."""
        try:
            size = len(msg.pack(self._scratch))
        except Exception:  # noqa: BLE001 - a field it cannot carry: the link drops it anyway
            return frame_bytes(type(msg), self.plan.signed)
        return size + (SIGNATURE_BYTES if self.plan.signed else 0)

    @staticmethod
    def _stream(kind: str) -> str | None:
        stream = _STREAM_OF_TYPE.get(kind)
        if stream is None and kind.startswith("ESC_TELEMETRY_"):
            stream = "ESC_TELEMETRY"
        return stream

    def is_event(self, msg: Any) -> bool:
        """Not periodic telemetry: a message that must go, late rather than never."""
        return self._stream(msg.get_type()) is None

    @staticmethod
    def essential(msg: Any) -> bool:
        """A heartbeat or a CRITICAL (or graver) text: always goes."""
        kind = msg.get_type()
        return kind == "HEARTBEAT" or (kind == "STATUSTEXT" and msg.severity <= _CRITICAL)

    def allow(self, component_id: int, msg: Any, now: float = 0.0) -> bool:
        """True when ``msg`` goes on the autopilot link now (it always goes to the monitors);
        False for an event means "not yet" (the caller keeps it for the next tick)."""
        kind = msg.get_type()
        stream = self._stream(kind)
        bucket = self._bucket
        if stream is None:
            return self._event(kind, msg, now, bucket)
        ratio = self.plan.ratios.get(stream, 1.0)
        key = (component_id, kind, msg.name if kind == "NAMED_VALUE_FLOAT" else None)
        if kind in ("ESC_STATUS", "ESC_INFO"):  # one stream per ESC group (issue 30)
            key = (component_id, kind, msg.index)
        credit = self._credit.get(key, 1.0) + ratio if ratio < 1.0 else 1.0
        if credit < 1.0:
            self._credit[key] = credit
            self.counters["held_back"] += 1
            return False
        if bucket is not None and not self._periodic_fits(bucket, key, msg, now):
            # its turn is kept (the credit stays): it goes with the next message the window allows
            self._credit[key] = min(credit, 1.0 + ratio) if ratio < 1.0 else 1.0
            self.counters["held_back_window"] += 1
            return False
        if ratio < 1.0:
            self._credit[key] = credit - 1.0
        return True

    def _periodic_fits(
        self, bucket: TokenBucket, key: tuple[Any, ...], msg: Any, now: float
    ) -> bool:
        """Tokens for a periodic message, first come first served except that a stream held
        back by the window reserves its turn: until it has gone (or :data:`RESERVATION_S` has
        passed) no other stream takes tokens. Without it a frame near the bucket's depth (an
        ACTUATOR_OUTPUT_STATUS of 152 B in a 200 B bucket) needs a full bucket, which the many
        small NAMED_VALUE_FLOATs never leave: it, ESC_STATUS and ESC_INFO starved although the
        plan had room for them (0 of 17 ESC_STATUS in 4 s on a one-servo config). A stream in
        :data:`_URGENT_STREAMS` goes before a reservation and takes it over when it is held back
        itself: with one turn at a time for ~70 streams, the gimbal's status waited seconds for
        its turn."""
        held = self._reserved
        urgent = key[1] in _URGENT_STREAMS
        others_turn = held is not None and held[0] != key and now - held[1] < RESERVATION_S
        if others_turn and not urgent:
            return False
        if bucket.take(self._cost(msg), now):
            if held is not None and not others_turn:
                self._reserved = None
            return True
        if held is None or held[0] != key and (urgent or not others_turn):
            self._reserved = (key, now)
        return False

    def _take_keeping_half(self, bucket: TokenBucket, msg: Any, now: float) -> bool:
        """Tokens for ``msg`` if half the depth stays for events (or, for a frame larger than
        half the depth, if the rest of the bucket is enough)."""
        cost = self._cost(msg)
        return bucket.take(
            cost, now, keep=max(0.0, min(bucket.capacity / 2, bucket.capacity - cost))
        )

    def _event(self, kind: str, msg: Any, now: float, bucket: TokenBucket | None) -> bool:
        if bucket is None:
            return True
        cost = self._cost(msg)
        _, _, debt = self.plan.bucket
        if bucket.take(cost, now, debt=debt):
            return True
        if self.essential(msg):
            bucket.tokens -= cost
            self.counters["essential_over_budget"] += 1
            return True
        self.counters["events_delayed"] += 1
        return False

    def admit_answer(self, component_id: int, msg: Any, now: float) -> bool:
        """An answer to a request may go now: within the answers' share of the rate
        (:data:`ANSWER_SHARE`, their own bucket) and with tokens for it while half the depth
        stays for events (otherwise it waits in its queue). A frame deeper than the bucket (an
        FTP data packet on a budget under ~1.3 kB/s) waits for a full bucket and leaves it in
        debt: that one window may exceed the budget by the frame's excess over the depth."""
        bucket, share = self._bucket, self._answers
        if bucket is None or share is None:
            return True
        cost = self._cost(msg)
        if share.level(now) < min(cost, share.capacity):
            return False
        if cost > bucket.capacity:
            if bucket.level(now) < bucket.capacity:
                return False
            bucket.tokens -= cost
            self.counters["answers_deeper_than_bucket"] += 1
        elif not self._take_keeping_half(bucket, msg, now):
            return False
        share.tokens -= cost
        return True
