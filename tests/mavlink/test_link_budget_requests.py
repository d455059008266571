"""The link budget's waiting line against requests: a message a peer asked for
(REQUEST_MESSAGE) is an answer to that peer, not a turn of the periodic stream of its type.

Found by review (rvlb): the bridge's own gimbal status and a stranger's requested copy of it
shared one decimation credit, so a stranger asking for GIMBAL_DEVICE_ATTITUDE_STATUS ten times
a second took the turns of the status the autopilot needs every second (ArduPilot's mount
calls the gimbal unhealthy after 1 s without it, docs/engineering/sitl.md)."""

from __future__ import annotations

from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.mavlink.bandwidth import GIMBAL_STATUS_FLOOR_HZ, MAX_WAITING, Admission, LinkBudget
from mavservo.mavlink.gimbal import GimbalDevice, GimbalSettings
from mavservo.mavlink.settings import MavlinkSettings
from mavservo.mavlink.side import MavlinkSide
from mavservo.records.metrics import peak_window_bytes
from tests.mavlink.test_link_budget_window import _default_plan
from tests.support.mavlink_doubles import RecordingBackend, command_long, make_mavlink_core, wire

NOW = Admission.NOW
STRANGER = (77, 190)
GIMBAL = (1, 154)
SERVO = (1, 140)
MSG_GIMBAL_DEVICE_ATTITUDE_STATUS = 285
MAV_CMD_REQUEST_MESSAGE = 512
DO_SET_SERVO = 183


def _sim_plan() -> Any:
    """The plan of `config/sim.yaml` (nine servos and a gimbal at the default budget)."""
    return _default_plan(servos=9, gimbals=1)


def _gimbal_core() -> Any:
    gimbal = GimbalDevice(
        GimbalSettings(name="g", axis_servos={"pitch": "aileron"}, limits_deg={"pitch": (-90, 30)}),
        RecordingBackend(),
    )
    core, _ = make_mavlink_core(gimbals=(gimbal,), link_budget_bytes_s=1000.0)
    # the gimbal's status at its floor with margin: 6.5 of its 10 Hz on the link
    core.budget.replan(_sim_plan(), 0.0)
    assert core.budget.plan.ratios["GIMBAL_DEVICE_ATTITUDE_STATUS"] == 0.65
    return core


class _SideOnAClock:
    """A MAVLink side on a simulated clock whose link records what it is told to send, and
    where (the side's decision, not the socket's work)."""

    def __init__(self, budget: float, **settings: Any) -> None:
        self.now = 0.0
        self.side = MavlinkSide(
            MavlinkSettings(system_id=1, link_budget_bytes_s=budget, **settings),
            RecordingBackend(),
            clock=lambda: self.now,
        )
        #: (time, message, on the link, to the monitors)
        self.sent: list[tuple[float, Any, bool, bool]] = []
        self.side.link.send = self._record  # type: ignore[method-assign]

    def _record(self, component_id: int, msg: Any, system_id: int, **where: Any) -> None:
        self.sent.append(
            (self.now, msg, where.get("to_link", True), where.get("to_monitors", True))
        )

    def on_link(self, msg: Any) -> list[float]:
        return [t for t, m, link, _ in self.sent if m is msg and link]

    def on_monitors(self, msg: Any) -> list[float]:
        return [t for t, m, _, monitors in self.sent if m is msg and monitors]

    def link_types(self) -> list[str]:
        return [m.get_type() for _, m, link, _ in self.sent if link]

    def link_bytes(self) -> list[tuple[float, int]]:
        scratch = mavlink2.MAVLink(None)
        return [(t, len(m.pack(scratch))) for t, m, link, _ in self.sent if link]


def _texts(count: int) -> list[Any]:
    """A burst of WARNING texts, 66 B each: seconds of a 400 B/s budget."""
    return [
        mavlink2.MAVLink_statustext_message(4, f"line {i} ".encode() * 6, 0, 0)
        for i in range(count)
    ]


def test_a_strangers_requests_do_not_take_the_autopilots_gimbal_status_turns() -> None:
    """20 s in the MAVLink side's 10 ms ticks (the side's order: the waiting line, the tick's
    output through the budget, then the queued answers); a stranger asks for the gimbal's
    attitude status every 100 ms. Before: the status the bridge broadcasts reached the link
    27 times in 25 s (gaps of 24.8 s) in the same mix in simulated time; the autopilot's
    mount check wants one a second. Here (no servos, the line short): 63 of the 100 planned
    (3.2 Hz, under the 5 Hz floor), 101 without the stranger."""
    core = _gimbal_core()
    budget = core.budget
    broadcast: list[float] = []
    answered = 0
    now = 0.0
    for tick in range(2000):
        now = tick * 0.01
        went = [msg for _, msg in budget.due(now)]
        went += [msg for cid, msg in core.tick(now) if budget.offer(cid, msg, now) is NOW]
        broadcast += [now for msg in went if msg.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS"]
        if tick % 10 == 2:
            request = command_long(
                GIMBAL, MAV_CMD_REQUEST_MESSAGE, MSG_GIMBAL_DEVICE_ATTITUDE_STATUS
            )
            out = core.on_message(wire(request, STRANGER), now)
            # what the side does with an unverified sender's responses: to it, in its turn
            core.queue_responses(STRANGER, out, now)
        for answer in core.answers_due(now):
            answered += answer.msg.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS"
    gaps = [b - a for a, b in zip([0.0, *broadcast], [*broadcast, now], strict=True)]
    planned = 20 * 10 * budget.plan.ratios["GIMBAL_DEVICE_ATTITUDE_STATUS"]
    assert len(broadcast) >= 0.95 * planned, f"{len(broadcast)} of {planned:.0f} broadcast"
    assert max(gaps) < 1.0, f"{len(broadcast)} broadcast, longest gap {max(gaps):.2f} s"
    assert answered > 0  # the stranger is answered too


GCS = (255, 190)
MSG_ACTUATOR_OUTPUT_STATUS = 375


def test_a_ground_stations_requested_message_reaches_the_link_every_time() -> None:
    """A ground station in ``allowed_sources`` asks for ACTUATOR_OUTPUT_STATUS once a second
    (REQUEST_MESSAGE: "send it once, now"). Its answers go out at once through the side's
    budget (:meth:`MavlinkSide._send`); before, they went through the stream's decimation
    like the periodic copies, so at the `config/sim.yaml` plan (the stream at 4 % of its
    messages) the station got 1 of 10 on the link, the others to the monitors only."""
    bridge = _SideOnAClock(1000.0, allowed_sources=frozenset({GCS}))
    bridge.side.core.budget.replan(_sim_plan(), 0.0)
    for second in range(10):
        bridge.now = float(second)
        request = command_long(SERVO, MAV_CMD_REQUEST_MESSAGE, MSG_ACTUATOR_OUTPUT_STATUS)
        bridge.side._on_message(wire(request, GCS), bridge.now)
    on_link = bridge.link_types()
    assert on_link.count("ACTUATOR_OUTPUT_STATUS") == 10, on_link
    assert on_link.count("COMMAND_ACK") == 10


def test_re_plans_with_a_late_receipt_time_mint_no_tokens() -> None:
    """A SET_MESSAGE_INTERVAL re-plans the budget at its receipt time, which may be earlier
    than the tick that last took tokens (the receive thread waited for the side's lock). The
    new bucket started its clock there, and the next take refilled the time already counted:
    each re-plan minted ``rate * lag`` bytes, so a stranger's stream of accepted intervals
    (no rate limit of its own) widened the link's window past the budget."""
    budget = LinkBudget(_sim_plan())
    plan = budget.plan
    text = mavlink2.MAVLink_statustext_message(4, b"x" * 50, 0, 0)
    now = 10.0
    sent = 0
    while budget.offer(140, text, now) is NOW and sent < 100:  # down to the events' debt
        sent += 1
    minted = 0
    for _ in range(100):
        budget.replan(plan, now - 0.01)  # received 10 ms before the tick that took tokens
        minted += budget.offer(140, text, now) is NOW  # the next tick, the same instant
    assert 0 < sent < 100
    assert minted == 0, f"{minted} texts of 66 B more in the same instant"


def test_monitors_get_every_held_event_at_once_and_the_link_each_once() -> None:
    """An event the budget cannot take yet (a burst of STATUSTEXT) waits for the link, in
    order; the monitor outputs are local and keep everything at once, as they do for the
    telemetry waiting in the line. Before, a held event reached the monitors only when the
    link took it (late in the recording), and one dropped from the full held list never."""
    bridge = _SideOnAClock(400.0)
    texts = _texts(30)
    bridge.side._send([(140, text) for text in texts])
    for step in range(1, 200):  # 20 s of ticks, more than the 30 texts need at 400 B/s
        bridge.now = step * 0.1
        bridge.side._send([])
    assert all(bridge.on_monitors(text) == [0.0] for text in texts)
    assert all(len(bridge.on_link(text)) == 1 for text in texts)
    went = [bridge.on_link(text)[0] for text in texts]
    assert went == sorted(went) and went[-1] > 0.0  # in order, and some had to wait


def _run_flooded(flood: Any, seconds: float) -> tuple[list[float], list[tuple[float, int]], int]:
    """The side's order in 10 ms ticks of simulated time with ``flood(core, now)`` each tick:
    the gimbal statuses broadcast, every message on the link (time, bytes), answers sent."""
    core = _gimbal_core()
    budget = core.budget
    scratch = mavlink2.MAVLink(None)
    broadcast: list[float] = []
    sent: list[tuple[float, int]] = []
    answered = 0
    for tick in range(int(seconds / 0.01)):
        now = tick * 0.01
        went = [msg for _, msg in budget.due(now)]
        went += [msg for cid, msg in core.tick(now) if budget.offer(cid, msg, now) is NOW]
        broadcast += [now for msg in went if msg.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS"]
        flood(core, now)
        answers = [answer.msg for answer in core.answers_due(now)]
        answered += len(answers)
        sent += [(now, len(msg.pack(scratch))) for msg in went + answers]
    return broadcast, sent, answered


def _stranger_sends(core: Any, source: tuple[int, int], msg: Any, now: float) -> None:
    out = core.on_message(wire(msg, source), now)
    core.queue_responses(source, out, now)  # what the side does for an unverified sender


def test_a_strangers_command_flood_does_not_starve_the_gimbal_status() -> None:
    """One stranger, 100 DO_SET_SERVO a second on a channel nobody maps (each DENIED). Its
    ACKs went as events, which may take the bucket into debt: 0 of the 100 planned gimbal
    statuses reached the link in 20 s (the autopilot's mount check wants one a second)."""

    def flood(core: Any, now: float) -> None:
        _stranger_sends(core, STRANGER, command_long(SERVO, DO_SET_SERVO, 99, 1500), now)

    broadcast, _, answered = _run_flooded(flood, 20.0)
    gaps = [b - a for a, b in zip(broadcast, broadcast[1:], strict=False)]
    assert len(broadcast) >= 95, f"{len(broadcast)} of 100 planned"
    assert max(gaps) < 1.0
    assert answered > 0  # the stranger is answered, within the answers' share


def test_requested_heartbeats_from_spoofed_senders_stay_within_the_budget() -> None:
    """16 spoofed senders ask for a HEARTBEAT (REQUEST_MESSAGE 0) every 10 ms. The answer
    went as an essential message (the bridge's own heartbeat always goes, over the budget if
    it must): 60 over the budget in 10 s and a 1-s window of 1,110 B on a 1,000 B/s budget."""

    def flood(core: Any, now: float) -> None:
        for component in range(100, 116):
            _stranger_sends(
                core, (66, component), command_long(SERVO, MAV_CMD_REQUEST_MESSAGE, 0), now
            )

    _, sent, answered = _run_flooded(flood, 10.0)
    assert peak_window_bytes(sent) <= 1000.0
    assert answered > 0


def test_the_gimbal_managers_periodic_status_never_goes_out_stale() -> None:
    """GIMBAL_MANAGER_STATUS is periodic (2 Hz when a gimbal acts as its own manager) but was
    not a stream of the budget: it went as an event, so behind a burst of held texts each one
    was held in turn and all went later, in order, seconds old, taking places in the held
    list that the texts need. A periodic message waits in the line like the others: the
    newest of its stream, never older than its period."""
    bridge = _SideOnAClock(400.0)
    bridge.side._send([(140, text) for text in _texts(30)])
    for step in range(1, 200):  # 20 s of 100 ms ticks, a manager status every 500 ms
        bridge.now = step * 0.1
        out = []
        if step % 5 == 0 and step <= 100:  # made now: its time_boot_ms says when
            out.append(
                (
                    154,
                    mavlink2.MAVLink_gimbal_manager_status_message(step * 100, 0, 154, 0, 0, 0, 0),
                )
            )
        bridge.side._send(out)
    ages = [
        t - m.time_boot_ms / 1000
        for t, m, link, _ in bridge.sent
        if link and m.get_type() == "GIMBAL_MANAGER_STATUS"
    ]
    assert ages, "some manager statuses reach the link"
    assert max(ages) <= 0.5, f"a manager status {max(ages):.1f} s old on the link"


def test_the_bridges_heartbeat_is_not_held_behind_waiting_texts() -> None:
    """Heartbeats always go (over the budget if they must, counted): the autopilot and the
    ground station call a component lost after a few seconds without one. Behind a burst of
    held texts (30 at 400 B/s: seconds of them) the heartbeat was held too, "in order" with
    events it has no order with."""
    bridge = _SideOnAClock(400.0)
    bridge.side._send([(140, text) for text in _texts(30)])
    beats: list[tuple[Any, float]] = []
    for step in range(1, 100):  # 10 s of 100 ms ticks, a heartbeat a second
        bridge.now = step * 0.1
        out = []
        if step % 10 == 0:
            beats.append((mavlink2.MAVLink_heartbeat_message(26, 8, 0, 0, 4, 3), bridge.now))
            out.append((140, beats[-1][0]))
        bridge.side._send(out)
    late = [t - made for beat, made in beats for t in bridge.on_link(beat)]
    assert len(late) == 9
    assert max(late) == 0.0, f"a heartbeat {max(late):.1f} s late"


def test_a_full_waiting_line_never_drops_the_gimbal_status_first() -> None:
    """The line holds one message per stream up to MAX_WAITING (1,024: seven names per servo,
    about 146 servos, a config with no bound on servos reaches it); beyond it the oldest went
    first, and the oldest is the head, where the gimbal's status (the autopilot's health
    check) is put. The status survives the line's bound; a name is dropped instead."""
    budget = LinkBudget(_default_plan(servos=160, gimbals=1))
    now = 10.0
    gimbal = mavlink2.MAVLink_gimbal_device_attitude_status_message(
        0, 0, 0, 0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0
    )
    text = mavlink2.MAVLink_statustext_message(4, b"x" * 50, 0, 0)
    for _ in range(100):  # events take the window down to their debt
        if budget.offer(140, text, now) is not NOW:
            break
    assert budget.offer(154, gimbal, now) is Admission.WAITS
    for name in [f"s{i}_pos".encode() for i in range(MAX_WAITING + 50)]:
        budget.offer(140, mavlink2.MAVLink_named_value_float_message(0, name, 1.0), now)
    assert budget.counters["waiting_dropped"] > 0
    assert budget.due(now + 1.0)[0] == (154, gimbal)


def test_heartbeats_asked_for_by_a_spoofed_autopilot_stay_within_the_budget() -> None:
    """On an unsigned link anyone can send as the autopilot (1/1), whose requests are answered
    at once. A HEARTBEAT it asks for (REQUEST_MESSAGE 0) is an answer, not the bridge's own
    heartbeat: it went as an essential message, over the budget whatever the rate (100 a
    second: 1-s windows of 3 kB on a 1,000 B/s budget), and it was never dropped from the
    held events, so real texts were dropped in its place."""
    bridge = _SideOnAClock(1000.0)
    for tick in range(500):  # 5 s, a request every 10 ms
        bridge.now = tick * 0.01
        request = command_long(SERVO, MAV_CMD_REQUEST_MESSAGE, 0, tick)  # not a retry
        bridge.side._on_message(wire(request, (1, 1)), bridge.now)
        bridge.side._send([])
    assert peak_window_bytes(bridge.link_bytes()) <= 1000.0
    assert bridge.side.core.budget.counters["essential_over_budget"] == 0


def test_two_threads_sends_leave_in_the_order_they_were_decided() -> None:
    """The receive thread and the tick thread each decide where their messages go under the
    side's lock; they used to send outside it, so a batch decided second could reach the link
    before the end of a batch decided first (review rvlb). Here the first batch's first write
    is slow (it waits up to 0.5 s for the second thread to decide): the second batch must
    still leave after the whole first one."""
    import threading

    rig = _SideOnAClock(budget=None)  # type: ignore[arg-type]
    first = [mavlink2.MAVLink_statustext_message(6, f"first {i}".encode(), 0, 0) for i in range(3)]
    second = [
        mavlink2.MAVLink_statustext_message(6, f"second {i}".encode(), 0, 0) for i in range(3)
    ]
    second_decided, first_writing = threading.Event(), threading.Event()
    record = rig._record
    decide = rig.side._decide

    def slow_record(component_id: int, msg: Any, system_id: int, **where: Any) -> None:
        if msg is first[0]:
            first_writing.set()
            second_decided.wait(0.5)  # bounded: with the order kept, the second waits for us
        record(component_id, msg, system_id, **where)

    def watched_decide(out: Any, requested: bool, reply_to: Any = None) -> Any:
        decided = decide(out, requested, reply_to)
        if any(m is second[0] for _, m, _, _ in decided):
            second_decided.set()
        return decided

    rig.side.link.send = slow_record  # type: ignore[method-assign]
    rig.side._decide = watched_decide  # type: ignore[method-assign]
    one = threading.Thread(target=rig.side._send, args=([(140, m) for m in first],))
    one.start()
    assert first_writing.wait(5.0)  # the first batch is being sent (its first write waits)
    two = threading.Thread(target=rig.side._send, args=([(140, m) for m in second],))
    two.start()
    one.join(5.0)
    two.join(5.0)
    texts = [m.text for _, m, link, _ in rig.sent if link]
    assert texts == [m.text for m in first + second], texts


def test_the_gimbal_status_keeps_its_floor_in_every_second_when_ticks_come_late() -> None:
    """Issue 40's flood on a loaded machine: the gimbal status reached the autopilot at 0-4 Hz
    in its worst seconds. Not the flood's bytes (answers leave the urgent status its tokens):
    the plan put the stream at exactly 5 Hz, every other status of the 10 Hz gimbal, counted
    per message, and a tick that comes late makes the gimbal skip a status (it does not catch
    up), so each late tick cost a turn on the link. Here, in simulated time with the flood's
    mix (REQUEST_MESSAGE and SET_MESSAGE_INTERVAL from 250 spoofed ids, 1,000 a second), the
    10 ms ticks stall twice a second (150 and 250 ms late): before, 3-4 statuses in most
    seconds; ArduPilot wants 5."""
    core = _gimbal_core()
    budget = core.budget
    statuses: list[float] = []
    now, sent = 0.0, 0
    while now < 12.0:
        went = [msg for _, msg in budget.due(now)]
        went += [msg for cid, msg in core.tick(now) if budget.offer(cid, msg, now) is NOW]
        statuses += [now for msg in went if msg.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS"]
        for _ in range(10):  # 10 ms of the flood
            sent += 1
            target = SERVO if sent % 2 else GIMBAL
            if sent % 4 < 2:
                asked = (MSG_GIMBAL_DEVICE_ATTITUDE_STATUS, MSG_ACTUATOR_OUTPUT_STATUS, 0)[sent % 3]
                flood = command_long(target, MAV_CMD_REQUEST_MESSAGE, asked)
            else:
                flood = command_long(target, 511, MSG_GIMBAL_DEVICE_ATTITUDE_STATUS, 100_000)
            _stranger_sends(core, (1 + sent % 250, 190), flood, now)
        core.answers_due(now)
        within = now % 1.0
        stalled = 0.15 if 0.3 <= within < 0.31 else 0.25 if 0.7 <= within < 0.71 else 0.0
        now = round(now + 0.01 + stalled, 6)
    per_second = [sum(int(t) == s for t in statuses) for s in range(1, 11)]
    assert min(per_second) >= GIMBAL_STATUS_FLOOR_HZ, per_second
