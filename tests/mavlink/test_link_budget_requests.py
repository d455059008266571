"""The link budget's waiting line against requests: a message a peer asked for
(REQUEST_MESSAGE) is an answer to that peer, not a turn of the periodic stream of its type.

Found by review (rvlb): the bridge's own gimbal status and a stranger's requested copy of it
shared one decimation credit, so a stranger asking for GIMBAL_DEVICE_ATTITUDE_STATUS ten times
a second took the turns of the status the autopilot needs every second (ArduPilot's mount
calls the gimbal unhealthy after 1 s without it, docs/sitl.md)."""

from __future__ import annotations

from typing import Any

from mavservo.mavlink.bandwidth import Admission, plan_budget
from mavservo.mavlink.gimbal import GimbalDevice, GimbalSettings
from mavservo.mavlink.settings import TelemetryRates
from tests.support.mavlink_doubles import RecordingBackend, command_long, make_mavlink_core, wire

NOW = Admission.NOW
STRANGER = (77, 190)
GIMBAL = (1, 154)
MSG_GIMBAL_DEVICE_ATTITUDE_STATUS = 285
MAV_CMD_REQUEST_MESSAGE = 512


def _gimbal_core() -> Any:
    gimbal = GimbalDevice(
        GimbalSettings(name="g", axis_servos={"pitch": "aileron"}, limits_deg={"pitch": (-90, 30)}),
        RecordingBackend(),
    )
    core, _ = make_mavlink_core(gimbals=(gimbal,), link_budget_bytes_s=1000.0)
    # the plan of `config/sim.yaml` (nine servos and a gimbal at the default budget): the
    # gimbal's status at its floor, half of its 10 Hz on the link
    core.budget.replan(
        plan_budget(
            1000.0,
            servos=9,
            gimbals=1,
            health_names=7,
            components=2,
            rates=TelemetryRates(),
            signed=False,
        ),
        0.0,
    )
    assert core.budget.plan.ratios["GIMBAL_DEVICE_ATTITUDE_STATUS"] == 0.5
    return core


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
