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
not). Periodic telemetry that does not fit waits in a line, one message per stream, and goes
in turn (:meth:`LinkBudget.offer`, :meth:`LinkBudget.due`); answers to requests (and every
response to an unverified sender's command, its ACK included) take tokens only within their
share and while half the depth stays for events (they wait in their own queue), the bridge's
own events (STATUSTEXT, COMMAND_ACK to a verified sender) may take the rest and the debt;
heartbeats and CRITICAL texts always go (counted in ``essential_over_budget`` when they exceed
it).
Sizes are the worst case of each message type (MAVLink 2 trims trailing zeros: real frames are
shorter), so the bound holds for the bytes really sent.
"""

from __future__ import annotations

import enum
from collections import Counter, OrderedDict
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
MAX_WAITING = 1024
"""Most periodic messages waiting for the window (one per stream: 9 servos and a gimbal make
~90 streams; a bound all the same, the oldest but the urgent ones goes first and is counted)."""
#: Share of the bucket's rate answers to requests (parameter lists and reads, FTP) may use at
#: most: a read flood from a stranger starved the autopilot's telemetry when answers and
#: telemetry competed for the same tokens without a cap. While answers flow, telemetry gets
#: the rest (waiting in the line, see :meth:`LinkBudget.offer`); without requests, all of it.
#: 0.6: at the default 1,000 B/s a full FTP data frame (266 B) can leave every 0.66 s, inside
#: QGroundControl's 1,000 ms FTP time-out (``FTPManager.h``: ``_ackOrNakTimeoutMsecs = 1000``,
#: ``_maxRetry = 3``) with the urgent gimbal status and the heartbeats taking their ~350 B/s;
#: at 0.3 (before) it took 1.3 s at best, and the client's retries doubled the queue (issue 38).
ANSWER_SHARE = 0.6
#: Depth of the answers' own bucket: the largest MAVLink 2 frame (an FTP data packet, signed).
ANSWER_DEPTH_BYTES = 280
#: The link bucket is at least an FTP data frame deep (less the events' debt, which answers that
#: large may use), when that is at most this share of the budget: a frame deeper than the bucket
#: and its debt had to leave it deeper in debt, over the budget in that window.
ANSWER_FRAME_DEPTH_SHARE = 0.4
#: The token bucket's depth (at least the largest frame) and the events' debt, as shares of
#: the budget; the rest is its rate.
BUCKET_DEPTH_SHARE = 0.2
EVENT_DEBT_SHARE = 0.05

#: Periodic streams the autopilot's own health check needs: they take the window's turn from
#: any other stream. ArduPilot's MAVLink mount (``AP_Mount_Gremsy::healthy``, master
#: 90700977c5) calls the gimbal unhealthy, and refuses to arm, after 1 s without a
#: GIMBAL_DEVICE_ATTITUDE_STATUS; against ArduPlane SITL, behind ~70 other streams at the
#: default budget, gaps of up to 6.3 s came out (docs/engineering/sitl.md).
#: GIMBAL_MANAGER_STATUS of a gimbal that is its own manager too: behind the other streams it
#: went about once every 8 s at the default budget, and MAVSDK's Gimbal plugin showed a control
#: granted 2 s late (issue 38); a client needs it at >= 1 Hz (it is planned as fixed bytes).
_URGENT_STREAMS = frozenset({"GIMBAL_DEVICE_ATTITUDE_STATUS", "GIMBAL_MANAGER_STATUS"})
#: MAV_SEVERITY_CRITICAL: STATUSTEXT this grave always goes.
_CRITICAL = 2
#: ArduPilot's mount driver wants the gimbal's attitude status at least this often.
GIMBAL_STATUS_FLOOR_HZ = 5.0
#: The gimbal status is planned this much above its floor: planned at exactly 5 Hz (every
#: other status of a 10 Hz gimbal), any status the gimbal did not make on time (a tick the
#: loaded machine delayed past its period: the gimbal then skips it) or that crossed a second's
#: edge late left that second at 4 or fewer: the issue-40 flood bench's worst seconds were
#: 0-4 Hz at a mean of 4.7-5.0; on a simulated clock with 0.3-1 % of ticks 50-300 ms late
#: (with the flood's mix or without it) the worst second of 60 was 3 at 5 Hz, 4 at 5.5 and
#: 6 Hz, 4-6 at 6.5 Hz (with the stream's turns by the clock, :meth:`LinkBudget._takes_turn`).
#: The cost: the other streams get 30 % fewer turns at the default budget.
#: Test: tests/mavlink/test_link_budget_requests.py (late ticks).
GIMBAL_STATUS_MARGIN = 1.3
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
        debt = budget * EVENT_DEBT_SHARE
        # an FTP data frame fits the depth and the debt together (answers that large may take
        # the bucket into the debt, :meth:`LinkBudget.admit_answer`): no deeper than needed,
        # every byte of depth is a byte less of rate
        frame = min(float(ANSWER_DEPTH_BYTES) - debt, budget * ANSWER_FRAME_DEPTH_SHARE)
        depth = max(budget * BUCKET_DEPTH_SHARE, float(largest), frame)
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
    manager_status_hz: float = 0.0,
    left_out: frozenset[str] = frozenset(),
) -> BudgetPlan:
    """Scale the periodic streams so they fit ``budget_bytes_s`` (None: no scaling).

    ``rates`` is the telemetry rates section (``..._hz`` attributes); ``components`` counts the
    heartbeats (one per component per second), which are never scaled, like the
    GIMBAL_MANAGER_STATUS of gimbals that are their own manager (``manager_status_hz``, all
    together). ``left_out``: streams not sent on the link at all (:mod:`.link_carriage`: the
    autopilot drops them), ratio 0.
    """
    heartbeat = frame_bytes(mavlink2.MAVLink_heartbeat_message, signed)
    manager = frame_bytes(mavlink2.MAVLink_gimbal_manager_status_message, signed)
    fixed = components * heartbeat + manager_status_hz * manager
    esc_groups = -(-servos // 4) if servos else 0
    gimbal_hz = rates.gimbal_attitude_status_hz
    streams: tuple[StreamCost, ...] = (
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
            floor_ratio=(
                min(1.0, GIMBAL_STATUS_FLOOR_HZ * GIMBAL_STATUS_MARGIN / gimbal_hz)
                if gimbal_hz > 0
                else 0.0
            ),
        ),
    )
    # px4 (issue 38 item 5): a stream left out is not sent on the link (ratio 0, no share of
    # the budget); the monitor outputs still get it at its configured rate
    ratios = {s.name: 0.0 if s.name in left_out else 1.0 for s in streams}
    plan = BudgetPlan(budget_bytes_s, fixed, streams, ratios, signed)
    if budget_bytes_s is not None:
        rate = plan.bucket[0]
        sent = tuple(s for s in streams if s.name not in left_out)
        ratios.update(_fit(rate * (1 - EVENT_RESERVE) - fixed, sent))
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


_MAX_TURNS_KEPT = 1.0
"""Turns a waiting stream may keep for later (a stream that waited long catches up by one
message, not by a burst)."""
_GOLDEN = (5**0.5 - 1) / 2
"""The golden ratio's fraction: successive multiples of it spread over [0, 1) as evenly as any
sequence can, whatever the number of streams."""


class Admission(enum.Enum):
    """What :meth:`LinkBudget.offer` did with a message."""

    NOW = "now"
    WAITS = "waits"
    SKIPPED = "skipped"


_STREAM_OF_TYPE = {
    "NAMED_VALUE_FLOAT": "NAMED_VALUE_FLOAT",
    "ACTUATOR_OUTPUT_STATUS": "ACTUATOR_OUTPUT_STATUS",
    "GIMBAL_DEVICE_ATTITUDE_STATUS": "GIMBAL_DEVICE_ATTITUDE_STATUS",
    "ESC_STATUS": "ESC_STATUS",  # gcs (issue 30)
    "ESC_INFO": "ESC_INFO",  # gcs (issue 30)
    # a gimbal that is its own manager says this at 2 Hz: periodic, so it waits in the line
    # (the newest one) instead of being held as an event and sent seconds old (review rvlb);
    # never decimated (no ratio), urgent (the head of the line), planned as fixed bytes
    "GIMBAL_MANAGER_STATUS": "GIMBAL_MANAGER_STATUS",
}


def _not_before(now: float | None, old: TokenBucket | None) -> float | None:
    """The clock of a re-planned bucket: never before the old one's (a SET_MESSAGE_INTERVAL
    re-plans at its receipt time, which may precede the tick that last took tokens: a clock
    set back refilled that time twice, ``rate * lag`` bytes minted at each re-plan)."""
    if old is None or old.at is None or now is None:
        return now
    return max(now, old.at)


class LinkBudget:
    """Decides, message by message, what goes on the autopilot link (monitors get everything):
    periodic telemetry decimated by the plan, and everything within the token bucket."""

    def __init__(self, plan: BudgetPlan) -> None:
        self._credit: dict[tuple[Any, ...], float] = {}
        #: when each stream's last message came (a stream held at its floor earns its turns
        #: by the clock: :meth:`_takes_turn`)
        self._last_seen: dict[tuple[Any, ...], float] = {}
        self.counters: Counter[str] = Counter()
        self.plan = plan
        self._scratch = mavlink2.MAVLink(None)
        self._bucket: TokenBucket | None = None
        self._answers: TokenBucket | None = None
        #: periodic messages waiting for the window, one per stream, oldest turn first
        self._waiting: OrderedDict[tuple[Any, ...], tuple[int, Any]] = OrderedDict()
        #: the link bucket's level the first answer a client waits for needs, this round
        #: (:meth:`answers_round`); 0: none waits
        self._answer_waiting = 0.0
        #: when the waiting answer's share has its tokens
        self._answer_ready_at = 0.0
        self.replan(plan)

    def replan(self, plan: BudgetPlan, now: float | None = None) -> None:
        """A new plan (rates changed by parameter or SET_MESSAGE_INTERVAL); the bucket keeps
        its tokens, so the change cannot open a burst."""
        self.plan = plan
        #: the planned rate of each stream held at its floor (its turns by the clock)
        self._floor_hz = {
            s.name: s.hz * plan.ratios[s.name]
            for s in plan.streams
            if s.floor_ratio > 0 and plan.ratios[s.name] <= s.floor_ratio
        }
        if plan.budget_bytes_s is None:
            self._bucket = self._answers = None
            return
        rate, depth, _ = plan.bucket
        before = self._bucket, self._answers
        self._bucket = TokenBucket(rate, depth, _not_before(now, before[0]))
        self._answers = TokenBucket(
            rate * ANSWER_SHARE, ANSWER_DEPTH_BYTES, _not_before(now, before[1])
        )
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

    def offer(
        self, component_id: int, msg: Any, now: float, *, requested: bool = False
    ) -> Admission:
        """Where ``msg`` goes: on the link now (:attr:`Admission.NOW`), into the waiting line
        for the link (:attr:`Admission.WAITS`: :meth:`due` hands it out when the window has
        room, oldest first), or to the monitors only (:attr:`Admission.SKIPPED`: the plan's
        decimation, or an event the bucket cannot take yet: the caller keeps those).

        Why a waiting line: the plan gives each stream a rate that fits the budget on average,
        but the bridge's telemetry comes in bursts (every stream of a tick at once) and the
        window is first come first served: the many small NAMED_VALUE_FLOATs took the tokens
        each time they came back, and a frame near the bucket's depth (ACTUATOR_OUTPUT_STATUS,
        ESC_STATUS) needed a full bucket that was never left. The reservation tried before (one
        held-back stream kept the window for up to a second) left the link idle while it
        waited: with `config/ardupilot-sitl.yaml` the link carried 407 B/s of its 1,000 and
        ACTUATOR_OUTPUT_STATUS got 39 % of its planned turns. In the line, a stream's message
        waits for its turn instead of being lost; every newer message of the same stream,
        decimated or not, takes its place (fresher data, the same turn), so the line holds at
        most one message per stream and no value on the link is older than the stream's own
        period. Periodic messages take tokens only while half the bucket's depth stays for
        events and answers (a parameter read must not wait behind the line). The gimbal's
        attitude status (:data:`_URGENT_STREAMS`) goes to the head: the autopilot calls the
        gimbal unhealthy after 1 s without it.

        A message a peer asked for (``requested``: REQUEST_MESSAGE, "send it once, now") is an
        event whatever its type: never decimated, never a turn of its stream's (before, a
        ground station asking for ACTUATOR_OUTPUT_STATUS once a second got 1 of 10 on the
        link at the stream's 4 %)."""
        kind = msg.get_type()
        stream = self._stream(kind)
        bucket = self._bucket
        if stream is None or requested:
            admitted = self._event(msg, now, bucket, requested)
            return Admission.NOW if admitted else Admission.SKIPPED
        key = self._key(component_id, kind, msg)
        if key in self._waiting:
            # a fresher value takes the waiting one's place (the link never gets a value older
            # than the stream's own period); a turn it would have taken is the stream's later
            if self._takes_turn(key, stream, now):
                self._give_turn_back(key, stream)
            self._waiting[key] = (component_id, msg)
            self.counters["waiting_refreshed"] += 1
            return Admission.WAITS
        if not self._takes_turn(key, stream, now):
            return Admission.SKIPPED
        if bucket is None:
            return Admission.NOW
        urgent = kind in _URGENT_STREAMS
        if (not self._waiting or urgent) and self._take_periodic(bucket, msg, now, urgent):
            return Admission.NOW
        self._waiting[key] = (component_id, msg)
        if urgent:
            self._waiting.move_to_end(key, last=False)
        self.counters["waited"] += 1
        while len(self._waiting) > MAX_WAITING:  # ~146 servos' names: no bound on servos
            # the oldest that is not urgent (the urgent stream is at the head: dropping the
            # head dropped the gimbal status the autopilot's health check needs)
            first = next(iter(self._waiting))
            oldest = next((k for k in self._waiting if k[1] not in _URGENT_STREAMS), first)
            del self._waiting[oldest]
            self.counters["waiting_dropped"] += 1
        return Admission.WAITS

    def due(self, now: float) -> list[tuple[int, Any]]:
        """The waiting periodic messages the window takes now, oldest first; the line stops at
        the first one that does not fit (a large frame is not overtaken by small ones, or it
        would wait for ever)."""
        bucket = self._bucket
        if bucket is None:  # the budget was switched off: all of them
            out = list(self._waiting.values())
            self._waiting.clear()
            return out
        out = []
        while self._waiting:
            key, (component_id, msg) = next(iter(self._waiting.items()))
            if not self._take_periodic(bucket, msg, now, key[1] in _URGENT_STREAMS):
                break
            del self._waiting[key]
            out.append((component_id, msg))
        return out

    @staticmethod
    def _key(component_id: int, kind: str, msg: Any) -> tuple[Any, ...]:
        """The stream a periodic message belongs to: a NAMED_VALUE_FLOAT name, an ESC group."""
        if kind == "NAMED_VALUE_FLOAT":
            return (component_id, kind, msg.name)
        if kind in ("ESC_STATUS", "ESC_INFO"):  # one stream per ESC group (issue 30)
            return (component_id, kind, msg.index)
        return (component_id, kind, None)

    def _takes_turn(self, key: tuple[Any, ...], stream: str, now: float) -> bool:
        """The plan's decimation: a stream at ratio r passes r of its messages, evenly spread
        (a Bresenham credit per stream); the others are counted in ``held_back``.

        A stream's first message always passes (a ground station sees every name soon after
        it connects); after it, each stream starts from its own phase (the golden-ratio
        sequence over the streams in the order they appear), so streams of one rate take
        their turns spread over the period instead of all in the same tick: 63 names at
        ratio 0.08 came as one burst every 12.8 s, and the burst held the line for seconds.

        A stream held at its floor (the gimbal status) earns its credit by the clock instead,
        at its planned rate: counted per message, the credit followed the messages the gimbal
        made, and a gimbal whose ticks the loaded machine delayed makes fewer (it skips a
        status it is late for), so its turns fell under the floor in exactly the seconds the
        machine lost ticks. By the clock, the messages after a delay take the turns it cost
        (at most :data:`_MAX_TURNS_KEPT` more)."""
        ratio = self.plan.ratios.get(stream, 1.0)
        if ratio >= 1.0:
            return True
        floor_hz = self._floor_hz.get(stream)
        credit = self._credit.get(key)
        if credit is None:
            self._credit[key] = (len(self._credit) * _GOLDEN) % 1.0
            if floor_hz is not None:
                self._last_seen[key] = now
            return True
        if floor_hz is None:
            credit += ratio
        else:
            elapsed = max(0.0, now - self._last_seen.get(key, now))
            self._last_seen[key] = now
            credit = min(credit + elapsed * floor_hz, 1.0 + _MAX_TURNS_KEPT)
        if credit < 1.0:
            self._credit[key] = credit
            self.counters["held_back"] += 1
            return False
        self._credit[key] = credit - 1.0
        return True

    def _give_turn_back(self, key: tuple[Any, ...], stream: str) -> None:
        """A turn that came while the stream's message was still waiting: kept for after it
        went (the plan's count of messages per second holds), at most one turn ahead."""
        if self.plan.ratios.get(stream, 1.0) < 1.0 and key in self._credit:
            self._credit[key] = min(self._credit[key] + 1.0, 1.0 + _MAX_TURNS_KEPT)

    def _take_periodic(self, bucket: TokenBucket, msg: Any, now: float, urgent: bool) -> bool:
        """Tokens for a periodic message: as :meth:`_take_keeping_half`, and, unless it is
        urgent, leaving the tokens an answer a client waits for needs when its share is ready
        (:meth:`admit_answer`): the answer goes before periodic telemetry, which waits in the
        line meanwhile (decimated: a newer value replaces the waiting one). Just in time: the
        tokens the link bucket earns (at half its rate, the urgent streams and heartbeats take
        the rest) before the answer's share is ready are not reserved, so small answers (a
        parameter read flood, limited by the share) hold little back."""
        waiting = self._answer_waiting
        if urgent:  # a quarter of the depth left for events: answers leave it its own cost
            cost = self._cost(msg)
            keep = max(0.0, min(bucket.capacity / 4, bucket.capacity - cost))
            return bucket.take(cost, now, keep=keep)
        if not waiting:
            return self._take_keeping_half(bucket, msg, now)
        cost = self._cost(msg)
        lead = max(0.0, self._answer_ready_at - now) * bucket.rate * 0.25
        needed = min(bucket.capacity, max(0.0, waiting - lead))
        keep = max(min(bucket.capacity / 2, bucket.capacity - cost), needed)
        if bucket.take(cost, now, keep=keep):
            return True
        self.counters["periodic_yielded_to_answers"] += 1
        return False

    def _take_keeping_half(self, bucket: TokenBucket, msg: Any, now: float) -> bool:
        """Tokens for ``msg`` if half the depth stays for events (or, for a frame larger than
        half the depth, if the rest of the bucket is enough)."""
        cost = self._cost(msg)
        return bucket.take(
            cost, now, keep=max(0.0, min(bucket.capacity / 2, bucket.capacity - cost))
        )

    def _event(
        self, msg: Any, now: float, bucket: TokenBucket | None, requested: bool = False
    ) -> bool:
        """An event within the bucket and its debt; the bridge's own essential ones beyond
        (a HEARTBEAT a peer asked for is an answer, not the bridge's heartbeat: a spoofed
        autopilot asking for one every 10 ms took 1-s windows to 2,254 B of 1,000)."""
        if bucket is None:
            return True
        cost = self._cost(msg)
        _, _, debt = self.plan.bucket
        if bucket.take(cost, now, debt=debt):
            return True
        if self.essential(msg) and not requested:
            bucket.tokens -= cost
            self.counters["essential_over_budget"] += 1
            return True
        self.counters["events_delayed"] += 1
        return False

    def admit_response(self, component_id: int, msg: Any, now: float) -> bool:
        """A queued response to an unverified sender's command (its ACK, a message it asked
        for with REQUEST_MESSAGE) may go now: as an answer (:meth:`admit_answer`: within the
        answers' share, half the depth kept for the bridge's own events), never as an event
        nor as a turn of the periodic stream of its type.

        Why (review rvlb): as events, a single stranger's 100 DO_SET_SERVO a second took
        every token with their DENIED ACKs (events may run the bucket into debt), and the
        gimbal status the autopilot needs every second got 0 of its 100 planned turns in 20 s;
        a requested HEARTBEAT went as an essential message, over the budget. As a turn of its
        stream (through ``allow``, since removed), a stranger asking for the gimbal's attitude
        status ten times a second took the broadcast copy's turns (63 of 100). The responses
        still go before the service answers (they are admitted first at each tick)."""
        return self.admit_answer(component_id, msg, now)

    def _urgent_waiting(self) -> Any | None:
        """The urgent periodic message at the head of the waiting line, if one waits."""
        for key, (_component_id, msg) in self._waiting.items():
            return msg if key[1] in _URGENT_STREAMS else None
        return None

    def answers_round(self) -> None:
        """A new round of answers starts (each tick, before they are admitted): what waited
        in the last round is asked for again, or nothing waits any more."""
        self._answer_waiting = 0.0

    def admit_answer(
        self,
        component_id: int,
        msg: Any,
        now: float,
        *,
        awaited: bool = True,
        keep_share: float = 0.5,
    ) -> bool:
        """An answer to a request may go now: within the answers' share of the rate
        (:data:`ANSWER_SHARE`, their own bucket) and with tokens for it in the link bucket:
        a small one while half the depth stays for events, one larger than half the depth
        (an FTP data frame) from a full bucket, a frame deeper than the bucket down into the
        events' debt at most (the bound on every window, depth + rate + debt, holds).

        An ``awaited`` answer that cannot go yet (one a client waits for: not an FTP refusal)
        is noted: periodic telemetry then leaves the tokens to it (:meth:`_take_periodic`)
        until it went, so a reply a client waits for leaves within about ``cost / rate`` of the
        tokens left by the urgent streams and heartbeats (an FTP frame every ~0.8 s at the
        default budget with the simulation's gimbal), not behind telemetry that kept the
        bucket low (issue 38: 1.2-7 s, the client's retries doubling the queue). Refusals to
        strangers do not hold the telemetry back. A frame deeper than the bucket (an FTP data
        packet on a budget under ~700 B/s) waits for a full bucket and leaves it in debt: that
        one window may exceed the budget by the frame's excess."""
        bucket, share = self._bucket, self._answers
        if bucket is None or share is None:
            return True
        cost = self._cost(msg)
        _, _, debt = self.plan.bucket
        # the level of the link bucket the answer needs: half the depth left for events, or the
        # full bucket for a large one (a frame deeper than the bucket goes into the debt);
        # never less for a larger answer (an ACK needed more than the message it acknowledges
        # and waited behind it: 1 ACK of 25 in 5 s)
        level = min(cost + bucket.capacity * keep_share, bucket.capacity)
        urgent = self._urgent_waiting()
        if urgent is not None:  # the autopilot's gimbal check first: leave it its tokens
            urgent_cost = self._cost(urgent)
            level = max(
                level, cost + urgent_cost + min(bucket.capacity / 4, bucket.capacity - urgent_cost)
            )
        admitted = share.level(now) >= min(cost, share.capacity) and bucket.level(now) >= level
        if admitted:
            bucket.tokens -= cost
            if cost - debt > bucket.capacity:
                self.counters["answers_deeper_than_bucket"] += 1
        else:
            if awaited and not self._answer_waiting:
                self._answer_waiting = level
                short = max(0.0, min(cost, share.capacity) - share.level(now))
                self._answer_ready_at = now + short / share.rate if share.rate > 0 else now
            return False
        share.tokens -= cost
        return True
