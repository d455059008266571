"""The bridge node's parts alone (servos/dronecan: notices, safety, info_service, bus_sharing,
actuator_watch), each on a few frames or plain objects, with no node around it. The node's own
tests (test_profile_and_node.py, tests/redteam/test_dronecan_*.py) cover them through it."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

from mavservo.servos.dronecan import wire
from mavservo.servos.dronecan.actuator_watch import SILENT_ACTUATOR_S, ActuatorWatch
from mavservo.servos.dronecan.bus_sharing import SENDERS_REPORTED, BusSharingWatch
from mavservo.servos.dronecan.info_service import GET_NODE_INFO_PER_S, NodeInfoService
from mavservo.servos.dronecan.notices import Notices
from mavservo.servos.dronecan.safety import SAFETY_PERIOD_S, SafetyBroadcast


def _decoded(frames: list) -> wire.Received:  # type: ignore[type-arg]
    reassembler = wire.Reassembler()
    results = [reassembler.push(msg, 0.0) for msg in frames]
    assert results[-1] is not None, reassembler.errors
    return results[-1]


def test_notices_keep_their_order_and_say_a_kind_once() -> None:
    notices = Notices()
    notices.add("a")
    notices.once("flood", "b")
    notices.once("flood", "c")
    notices.add("d")
    assert notices.take() == ["a", "b", "d"]
    assert notices.take() == []
    notices.once("flood", "e")
    assert notices.take() == []


def _safety(safety_on: str = "stop", off: bool = True, ardupilot: tuple[int, ...] = ()):  # type: ignore[no-untyped-def]
    counters: Counter[str] = Counter()
    notices = Notices()
    plan = SafetyBroadcast(100, off, safety_on, ardupilot, 0.0, counters, notices)  # type: ignore[arg-type]
    return plan, counters, notices


def test_safety_off_goes_out_every_period_and_safety_on_at_once_in_failsafe() -> None:
    plan, counters, _ = _safety("failsafe_and_stop")
    [first] = plan.due(0.0)
    assert int(_decoded([first]).payload.status) == wire.SAFETY_OFF
    assert plan.due(SAFETY_PERIOD_S / 2) == []
    assert plan.next_due() == SAFETY_PERIOD_S
    plan.failsafe(True)
    [on] = plan.due(SAFETY_PERIOD_S / 2)  # a change goes out at once
    assert int(_decoded([on]).payload.status) != wire.SAFETY_OFF
    assert counters == Counter(safety_off=1, safety_on=1)
    assert _decoded([first]).transfer_id + 1 == _decoded([on]).transfer_id


def test_safety_plan_stop_ignores_failsafe_and_none_sends_nothing() -> None:
    plan, counters, _ = _safety("stop")
    plan.due(0.0)
    plan.failsafe(True)
    assert plan.due(0.1) == []
    assert plan.turns_on_at_stop and len(plan.at_stop()) == 1
    silent, silent_counts, _ = _safety(off=False)
    assert silent.due(0.0) == [] and silent.next_due() is None and not silent_counts


def test_safety_warning_for_ardupilot_nodes_at_start_and_with_the_first_command() -> None:
    plan, _, notices = _safety(off=False, ardupilot=(20, 21))
    [at_start] = notices.take()
    assert "20, 21" in at_start and "SAFETY_OFF" in at_start
    plan.ardupilot_commanded()
    plan.ardupilot_commanded()
    assert notices.take() == [at_start]


def _asking(source: int, tid: int) -> wire.Received:
    return wire.Received(None, wire.DTID_GET_NODE_INFO, source, tid, True, True, 100, "", 16)


def test_get_node_info_is_answered_to_the_asker_at_a_bounded_rate() -> None:
    counters: Counter[str] = Counter()
    notices = Notices()
    status = wire.node_status(0.0, wire.HEALTH_OK, wire.MODE_OPERATIONAL)
    service = NodeInfoService(
        100, "org.example.x", (1, 2), bytes(range(16)), lambda now: status, counters, notices
    )
    answers = [service.answer(_asking(42, tid), 0.01 * tid) for tid in range(10)]
    given = [a for a in answers if a is not None]
    assert len(given) == GET_NODE_INFO_PER_S
    assert counters == Counter(get_node_info=4, get_node_info_limited=6)
    assert len(notices.take()) == 1
    ids = wire.service_fields(given[0][0])
    assert ids is not None and ids.destination == 42 and not ids.request
    assert all(len(a) == service.frames() for a in given)
    assert service.answer(_asking(42, 11), 1.5) is not None  # a second later: answered again


def _sharing() -> tuple[BusSharingWatch, Counter[str], Notices]:
    counters: Counter[str] = Counter()
    notices = Notices()
    watch = BusSharingWatch(100, {1, 2}, True, wire.Reassembler(), counters, notices)
    return watch, counters, notices


def _array_command(source: int, actuators: list[int], tid: int = 0) -> list:  # type: ignore[type-arg]
    payload = wire.array_command([(a, 1, 0.5) for a in actuators])
    return wire.encode_message(payload, source, tid, wire.PRIORITY_HIGH)


def test_another_master_of_the_bridges_actuators_is_reported_once() -> None:
    watch, counters, notices = _sharing()
    for tid in range(3):
        for msg in _array_command(7, [2, 5], tid):
            watch.command(msg, 7, 0.1 * tid)
    [notice] = notices.take()
    assert "node 7" in notice and "two masters" in notice
    frames = len(_array_command(7, [2, 5]))  # two commands: a two-frame transfer
    assert frames == 2 and counters["foreign_commands"] == 3 * frames  # every frame counted
    assert watch.foreign_masters == {7}


def test_a_controller_of_other_actuators_is_named_then_again_when_it_turns_to_ours() -> None:
    watch, _, notices = _sharing()
    for msg in _array_command(8, [9]):
        watch.command(msg, 8, 0.0)
    [other] = notices.take()
    assert "not the bridge's" in other
    for msg in _array_command(8, [1], 1):
        watch.command(msg, 8, 0.1)
    [ours] = notices.take()
    assert "two masters" in ours


def test_senders_beyond_the_bound_are_counted_not_named() -> None:
    watch, counters, notices = _sharing()
    for source in range(1, SENDERS_REPORTED + 4):
        for msg in _array_command(source, [9]):
            watch.command(msg, source, 0.0)
    assert len(notices.take()) == SENDERS_REPORTED + 1  # one summary for the rest
    assert counters["senders_not_reported"] == 3


def test_a_node_status_with_the_bridges_id_is_a_conflict_said_once() -> None:
    watch, counters, notices = _sharing()
    for _ in range(3):
        watch.node_status(100)
    watch.node_status(20)
    assert counters["node_id_conflict"] == 3 and len(notices.take()) == 1


@dataclass
class _Options:
    actuator_id: int = 1
    firmware: str = "generic"
    command: str = "unitless"


@dataclass
class _Servo:
    can_id: int = 20
    node_heard_at: float | None = None
    node_last_heard: float | None = None
    actuator_reported_at: float | None = None
    options: _Options = field(default_factory=_Options)


def test_a_commanded_actuator_that_never_reports_while_its_node_lives_is_said_once() -> None:
    servo = _Servo(node_heard_at=0.0, node_last_heard=0.0)
    counters: Counter[str] = Counter()
    notices = Notices()
    watch = ActuatorWatch([servo], counters, notices)
    watch.commanded(0, release=False)
    t = 0.0
    while t < 2 * SILENT_ACTUATOR_S:
        watch.check(t)
        t += 0.5
    [notice] = notices.take()
    assert "never reports Status for actuator 1" in notice and "commands ignored" in notice
    assert counters["silent_actuators"] == 1


def test_a_reporting_actuator_that_stops_is_said_once_per_episode_and_a_released_one_never() -> (
    None
):
    servo = _Servo(node_heard_at=0.0, actuator_reported_at=0.0)
    counters: Counter[str] = Counter()
    notices = Notices()
    watch = ActuatorWatch([servo], counters, notices)
    for step in range(20):  # commanded every 0.5 s, the node heard, no Status after t=0
        t = 0.5 * step
        servo.node_last_heard = t
        watch.commanded(0, release=False)
        watch.check(t)
    assert counters["stopped_actuators"] == 1 and len(notices.take()) == 1
    servo.actuator_reported_at = 10.0  # a report ends the episode
    watch.check(10.0)
    released = _Servo(node_heard_at=0.0, actuator_reported_at=0.0)
    quiet = ActuatorWatch([released], Counter(), notices)
    for step in range(20):
        released.node_last_heard = 0.5 * step
        quiet.commanded(0, release=True)
        quiet.check(0.5 * step)
    assert notices.take() == []
