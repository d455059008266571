"""ArduPilot or PX4 (issue 39): the flavour from the HEARTBEAT or the config, and each difference
where it lives: ACTUATOR_OUTPUT_STATUS.active (a count from PX4, the spec's bitmask otherwise),
what the link carries (issue 38 item 5), the gimbal setpoints asked of PX4 only, and the advice
a low-rate warning gives. Sans-I/O, on the MAVLink core."""

from __future__ import annotations

import logging
import math

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from mavservo.mavlink.autopilot_flavour import (
    ARDUPILOT,
    ESC_TELEMETRY_IDS,
    PX4,
    AutopilotFlavour,
    flavour_of_heartbeat,
)
from mavservo.mavlink.bandwidth import plan_budget
from mavservo.mavlink.link_carriage import blocked_ids, carriage_lines
from mavservo.mavlink.mavlink_core import MavlinkCore
from mavservo.mavlink.settings import MavlinkSettings, StreamRequestSettings, TelemetryRates
from mavservo.mavlink.stream_request import GIMBAL_SETPOINT, StreamRequester
from mavservo.mavlink.wip_messages import EscInfo
from tests.support.mavlink_doubles import (
    RecordingBackend,
    command_long,
    heartbeat,
    make_mavlink_core,
    wire,
)

AUTOPILOT = (1, 1)
GCS = (255, 190)
PX4_ID, ARDUPILOT_ID = 12, 3


def _aos(active: int, values: dict[int, float]):
    actuator = [0.0] * 32
    for index, value in values.items():
        actuator[index - 1] = value
    return mav.MAVLink_actuator_output_status_message(1_000_000, active, actuator)


def _mirrored(autopilot: int, active: int, **settings) -> dict[int, float]:
    core, backend = make_mavlink_core(mirror_actuator_output_status=True, **settings)
    core.on_message(wire(heartbeat(autopilot=autopilot), AUTOPILOT), 0.0)
    core.on_message(wire(_aos(active, {1: 1750.0, 5: 1250.0}), AUTOPILOT), 0.1)
    return {c[1]: c[2] for c in backend.servo_calls("actuator")}


def test_the_esc_telemetry_ids_are_pymavlinks() -> None:
    assert {
        getattr(mav, f"MAVLINK_MSG_ID_ESC_TELEMETRY_{n}_TO_{n + 3}") for n in range(1, 33, 4)
    } == ESC_TELEMETRY_IDS


def test_the_heartbeat_names_the_flavour() -> None:
    assert flavour_of_heartbeat(ARDUPILOT_ID) == "ardupilot"
    assert flavour_of_heartbeat(PX4_ID) == "px4"
    assert flavour_of_heartbeat(mav.MAV_AUTOPILOT_GENERIC) == "other"
    assert flavour_of_heartbeat(mav.MAV_AUTOPILOT_INVALID) is None  # a GCS, not an autopilot


def test_a_configured_flavour_wins_and_a_heartbeat_saying_otherwise_is_logged_once(
    caplog: pytest.LogCaptureFixture,
) -> None:
    flavour = AutopilotFlavour("px4")
    with caplog.at_level(logging.WARNING):
        for _ in range(3):
            assert not flavour.on_heartbeat(ARDUPILOT_ID)
    assert flavour.flavour == "px4" and flavour.facts is PX4
    assert sum("HEARTBEAT says ArduPilot" in r.message for r in caplog.records) == 1
    learned = AutopilotFlavour("auto")
    assert learned.flavour is None and not learned.known
    assert learned.on_heartbeat(PX4_ID) and learned.facts is PX4
    assert not learned.on_heartbeat(PX4_ID)


def test_px4s_active_is_the_number_of_outputs() -> None:
    """PX4: ``msg.active = act.noutputs`` (16): outputs 1 and 5 are both valid. Read as the
    spec's bitmask (the code before), 16 is output 5 alone and output 1 was never mirrored."""
    applied = _mirrored(PX4_ID, 16)
    assert applied == {1: pytest.approx(0.5), 5: pytest.approx(-0.5)}
    assert _mirrored(PX4_ID, 4) == {1: pytest.approx(0.5)}  # outputs 1..4 only


def test_other_senders_active_is_the_specs_bitmask() -> None:
    assert _mirrored(ARDUPILOT_ID, 16) == {5: pytest.approx(-0.5)}
    assert _mirrored(ARDUPILOT_ID, 0b10001) == {1: pytest.approx(0.5), 5: pytest.approx(-0.5)}
    # a configured flavour needs no heartbeat of that kind
    assert _mirrored(ARDUPILOT_ID, 16, autopilot_flavour="px4") == {
        1: pytest.approx(0.5),
        5: pytest.approx(-0.5),
    }


def test_a_count_beyond_the_32_slots_is_counted_and_mirrors_nothing() -> None:
    core, backend = make_mavlink_core(mirror_actuator_output_status=True)
    core.on_message(wire(heartbeat(autopilot=PX4_ID), AUTOPILOT), 0.0)
    core.on_message(wire(_aos(0xFFFFFFFF, {1: 1750.0}), AUTOPILOT), 0.1)
    assert backend.servo_calls("actuator") == []
    assert core.mirror.counters["active_count_out_of_range"] == 1


@pytest.mark.parametrize(
    ("link", "flavour", "blocked"),
    [
        ("port", "ardupilot", {290, 291, 397}),
        ("port", "px4", set(ESC_TELEMETRY_IDS)),
        ("port", "other", set(ESC_TELEMETRY_IDS)),
        ("port", None, set()),
        ("router", "ardupilot", set()),
        ("router", "px4", set(ESC_TELEMETRY_IDS)),
        ("router", None, set()),
    ],
)
def test_the_link_carries_what_can_arrive(link, flavour, blocked) -> None:
    assert blocked_ids(link, flavour) == blocked


def test_the_core_sends_the_esc_view_only_where_it_can_arrive(
    caplog: pytest.LogCaptureFixture,
) -> None:
    esc_info = EscInfo(
        index=16,
        time_usec=0,
        counter=0,
        count=0,
        connection_type=2,
        info=0,
        failure_flags=[0] * 4,
        error_count=[0] * 4,
        temperature=[0] * 4,
    )
    esc_telemetry = mav.MAVLink_esc_telemetry_17_to_20_message(*([[0] * 4] * 6))
    core, _ = make_mavlink_core()
    assert core.link_carries(esc_info) and core.link_carries(esc_telemetry)  # nothing heard
    core.on_message(wire(heartbeat(autopilot=ARDUPILOT_ID), AUTOPILOT), 0.0)
    assert not core.link_carries(esc_info) and core.link_carries(esc_telemetry)
    px4, _ = make_mavlink_core()
    with caplog.at_level(logging.INFO, logger="mavservo.mavlink.mavlink_core"):
        px4.on_message(wire(heartbeat(autopilot=PX4_ID), AUTOPILOT), 0.0)
        px4.on_message(wire(heartbeat(autopilot=PX4_ID), AUTOPILOT), 1.0)
    said = [r.getMessage() for r in caplog.records if "not sending" in r.getMessage()]
    assert said == [
        "not sending ESC_TELEMETRY_x_TO_y on the autopilot link: PX4 drops them "
        "(mavlink.autopilot.link: router if a router or the ground station is at the other "
        "end; docs/px4.md)"
    ]
    assert px4.link_carries(esc_info) and not px4.link_carries(esc_telemetry)
    # the budget plans nothing for what is not sent
    ratios = px4.budget.plan.ratios
    assert ratios["ESC_TELEMETRY"] == 0 and ratios["ESC_STATUS"] > 0


def test_component_metadata_through_ardupilots_port_is_unsupported_at_once() -> None:
    """ArduPilot drops message 397: a ground station asking through it gets UNSUPPORTED (and
    falls back to the parameter list) instead of waiting for a reply that never comes."""
    request = command_long((1, 140), mav.MAV_CMD_REQUEST_MESSAGE, 397)

    def answer(autopilot: int, link: str) -> list[str]:
        core = MavlinkCore(
            MavlinkSettings(system_id=1, link_budget_bytes_s=None, autopilot_link=link),  # type: ignore[arg-type]
            RecordingBackend(),
            boot_time=0.0,
            metadata_files={140: {"general.json": b"{}"}},
        )
        core.on_message(wire(heartbeat(autopilot=autopilot), AUTOPILOT), 0.0)
        out = core.on_message(wire(request, GCS), 0.1)
        return [
            m.get_type() if m.get_type() != "COMMAND_ACK" else f"ACK {m.result}" for _, m in out
        ]

    unsupported = f"ACK {mav.MAV_RESULT_UNSUPPORTED}"
    accepted = f"ACK {mav.MAV_RESULT_ACCEPTED}"
    assert answer(ARDUPILOT_ID, "port") == [unsupported]
    assert answer(PX4_ID, "port") == [accepted, "COMPONENT_METADATA"]
    assert answer(ARDUPILOT_ID, "router") == [accepted, "COMPONENT_METADATA"]


def test_px4_is_asked_for_the_gimbal_setpoints_and_ardupilot_is_not() -> None:
    settings = StreamRequestSettings.for_mirror(("SERVO_OUTPUT_RAW",), 0.05, gimbals=True)
    sent = {}
    for facts in (ARDUPILOT, PX4):
        requester = StreamRequester(settings, heartbeat_timeout_s=2.0)
        requester.set_flavour(facts, 0.0)
        requester.on_heartbeat(AUTOPILOT, 0.0)
        ids = []
        for step in range(4):  # one request in flight at a time: ACK each
            for request in requester.tick(0.1 * step):
                ids.append(request[2])
                requester.on_ack(mav.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 0.1 * step)
        sent[facts.name] = ids
        if facts is PX4:
            assert requester.streams[GIMBAL_SETPOINT].rate_hz == 20.0
    assert sent["ArduPilot"] == [mav.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW]
    assert sent["PX4"] == [
        mav.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW,
        mav.MAVLINK_MSG_ID_GIMBAL_DEVICE_SET_ATTITUDE,
    ]
    no_gimbal = StreamRequester(StreamRequestSettings.for_mirror((), 0.05), 2.0)
    no_gimbal.set_flavour(PX4, 0.0)
    assert GIMBAL_SETPOINT not in no_gimbal.streams


def test_a_low_px4_gimbal_stream_is_warned_about_with_px4s_advice(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """PX4's onboard default is 5 Hz: a bridge that asked 20 and gets 5 says so, with how to
    raise it on PX4 (not ArduPilot's MAVn_* parameters)."""
    settings = StreamRequestSettings.for_mirror((), 0.05, gimbals=True)
    requester = StreamRequester(settings, heartbeat_timeout_s=2.0)
    requester.set_flavour(PX4, 0.0)
    requester.on_heartbeat(AUTOPILOT, 0.0)
    requester.tick(0.0)
    requester.on_ack(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAV_RESULT_DENIED, 0.05)
    setpoint = mav.MAVLink_gimbal_device_set_attitude_message(
        1, 154, 0, [1, 0, 0, 0], math.nan, math.nan, math.nan
    )
    t = 0.0
    with caplog.at_level(logging.WARNING):
        while t < 13.0:
            t = round(t + 0.2, 3)  # 5 Hz
            requester.on_message(setpoint, t)
            if t % 1 < 0.2:
                requester.on_heartbeat(AUTOPILOT, t)
            requester.tick(t)
    warnings = [r.message for r in caplog.records if "arrives at" in r.message]
    assert warnings and "gimbal servos" in warnings[0]
    assert "mavlink stream -u 14580" in warnings[0] and "MAVn_RC_CHAN" not in warnings[0]
    assert any("PX4 refused" in r.message for r in caplog.records)


def test_check_says_what_each_link_gets() -> None:
    lines = carriage_lines("port", "auto")
    text = "\n".join(lines)
    assert "to ArduPilot: sends ESC_TELEMETRY_x_TO_y; not ESC_INFO, ESC_STATUS" in text
    assert "to PX4: sends ESC_INFO, ESC_STATUS, COMPONENT_METADATA; not ESC_TELEMETRY" in text
    assert lines[-1] == "monitor outputs: every message"
    assert len(carriage_lines("router", "px4")) == 3


def test_plan_budget_leaves_out_what_is_not_sent() -> None:
    kwargs = dict(servos=4, gimbals=0, health_names=0, components=1, signed=False)
    full = plan_budget(1000.0, rates=TelemetryRates(), **kwargs)
    lean = plan_budget(1000.0, rates=TelemetryRates(), left_out=frozenset({"ESC_INFO"}), **kwargs)
    assert lean.ratios["ESC_INFO"] == 0 and full.ratios["ESC_INFO"] > 0
    assert lean.full_bytes_s == full.full_bytes_s  # the monitors still get it
    # the room it leaves goes to the others
    assert lean.ratios["NAMED_VALUE_FLOAT"] > full.ratios["NAMED_VALUE_FLOAT"]
    assert lean.link_bytes_s <= 1000.0
