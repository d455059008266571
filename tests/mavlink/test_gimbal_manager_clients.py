"""A gimbal manager a client can use (issue 38, item 4), below the MAVSDK end-to-end test.

MAVSDK's Gimbal plugin reads who is in control from GIMBAL_MANAGER_STATUS: it must reach the
budgeted link at least once a second (behind ~90 other streams it came every ~8 s) and at the
next tick after a DO_GIMBAL_MANAGER_CONFIGURE changed the control. A gimbal that is its own
manager is not looked for by the autopilot, so no "not found" warning is due for it.
"""

from __future__ import annotations

from typing import Any

from mavservo.mavlink.connection import mavlink2
from mavservo.mavlink.gimbal import GimbalDevice
from mavservo.mavlink.gimbal_settings import GimbalSettings
from tests.mavlink.test_gimbal_discovery import ardupilot, attitude
from tests.mavlink.test_link_budget_window import _default_plan
from tests.support.mavlink_doubles import RecordingBackend, make_mavlink_core, wire

CONFIGURE = mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE
GCS = (245, 190)


def _gimbal(manager: bool) -> GimbalDevice:
    settings = GimbalSettings(
        name="g",
        axis_servos={"pitch": "aileron"},
        limits_deg={"pitch": (-90, 30)},
        act_as_manager=manager,
    )
    return GimbalDevice(settings, RecordingBackend(), boot_time=0.0)


def _statuses(messages: list[Any]) -> list[Any]:
    return [m for m in messages if m.get_type() == "GIMBAL_MANAGER_STATUS"]


def test_a_control_change_is_said_at_the_next_tick_not_the_next_period() -> None:
    gimbal = _gimbal(manager=True)
    assert _statuses(gimbal.periodic(0.0))  # the first one, then the next is 0.5 s away
    assert _statuses(gimbal.periodic(0.01)) == []
    params = (-2.0, -2.0, -1.0, -1.0, 0.0, 0.0, 0.0)  # primary: me
    assert gimbal.handle_command(CONFIGURE, params, 0.02, sender=GCS) == 0
    (status,) = _statuses(gimbal.periodic(0.03))
    assert (status.primary_control_sysid, status.primary_control_compid) == GCS


def test_the_manager_status_reaches_a_busy_link_every_period() -> None:
    """The default budget and the simulation's nine servos: ~90 streams wait in the line; the
    manager status (2 Hz) goes at the head, every one of them within the period."""
    gimbal = _gimbal(manager=True)
    core, _ = make_mavlink_core(gimbals=(gimbal,), link_budget_bytes_s=1000.0)
    core.budget.replan(_default_plan(servos=9, gimbals=1), 0.0)
    budget, sent = core.budget, []
    names = [
        mavlink2.MAVLink_named_value_float_message(0, f"s{n}_x{k}".encode(), 1.0)
        for n in range(9)
        for k in range(7)
    ]
    for step in range(1000):  # 10 s of 10 ms ticks
        now = step * 0.01
        batch = [(140, m) for m in names] if step % 50 == 0 else []
        batch += [(154, m) for m in gimbal.periodic(now)]
        for _cid, msg in budget.due(now):
            sent.append((now, msg))
        for cid, msg in batch:
            if budget.offer(cid, msg, now).value == "now":
                sent.append((now, msg))
    times = [t for t, m in sent if m.get_type() == "GIMBAL_MANAGER_STATUS"]
    assert len(times) >= 18, len(times)  # 2 Hz for 10 s
    assert max(b - a for a, b in zip(times, times[1:], strict=False)) <= 1.0


def test_no_discovery_warning_for_a_gimbal_that_is_its_own_manager() -> None:
    for manager, warned in ((False, 1), (True, 0)):
        core, _ = make_mavlink_core(gimbals=(_gimbal(manager),), link_budget_bytes_s=None)
        autopilot = (1, 1)
        core.on_message(wire(ardupilot(), autopilot), 0.0)
        core.on_message(wire(attitude(75.0), autopilot), 0.0)  # booted 75 s ago
        for step in range(1, 101):  # 10 s: past the grace time; nobody asks for the gimbal
            now = step * 0.1
            core.on_message(wire(ardupilot(), autopilot), now)
            core.tick(now)
        assert core.counters["gimbal_not_found"] == warned, manager


# ------------------------------------------------------------------------------ COMMAND_ACK first


def test_a_ground_stations_acks_never_wait_behind_the_messages_it_asked_for() -> None:
    """Issue 38, item 2: a ground station (not an allowed source) asks for
    ACTUATOR_OUTPUT_STATUS five times a second at the default budget, on a simulated clock:
    every ACK leaves at the first tick the budget allows, before any requested message still
    waiting; a request repeated before its answer went is answered once."""
    from tests.support.mavlink_doubles import command_long

    core, _ = make_mavlink_core(link_budget_bytes_s=1000.0)
    core.budget.replan(_default_plan(servos=9, gimbals=1), 0.0)
    request = wire(command_long((1, 140), 512, 375), GCS)
    asked_at: list[float] = []
    acks: list[float] = []
    for step in range(1000):  # 10 s of 10 ms ticks
        now = step * 0.01
        if step % 20 == 0:  # 5 a second
            asked_at.append(now)
            core.queue_responses(GCS, core.on_message(request, now), now)
        core.tick(now)
        for answer in core.answers_due(now):
            if answer.msg.get_type() == "COMMAND_ACK":
                acks.append(now)
    assert len(acks) >= len(asked_at) - 1
    late = [a - q for q, a in zip(asked_at, acks, strict=False) if a - q > 0.3]
    assert late == []
    # three requests before the first answer could go: one ACK, one message queued
    core2, _ = make_mavlink_core(link_budget_bytes_s=1000.0)
    for at in (0.0, 0.01, 0.02):
        core2.queue_responses(GCS, core2.on_message(request, at), at)
    assert len(core2.acks) == 1 and len(core2.responses) == 1
