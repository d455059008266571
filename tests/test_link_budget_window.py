"""The link budget's promise, as a property: whatever mix and timing of periodic telemetry,
events and answers, the bytes it lets on the link in any 1-second window stay within the budget
(issue 30 item 5), as long as nothing essential (heartbeats, CRITICAL texts) had to go over it."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.mavlink.bandwidth import LinkBudget, plan_budget
from mavservo.mavlink.settings import TelemetryRates
from mavservo.records.metrics import peak_window_bytes

MESSAGES = {
    "nvf": lambda: mavlink2.MAVLink_named_value_float_message(0, b"s1_pos", 1.5),
    "aos": lambda: mavlink2.MAVLink_actuator_output_status_message(0, 1, [0.5] * 32),
    "text": lambda: mavlink2.MAVLink_statustext_message(4, b"x" * 50, 0, 0),
    "ack": lambda: mavlink2.MAVLink_command_ack_message(183, 0, 0, 0, 255, 190),
    "answer": lambda: mavlink2.MAVLink_param_value_message(b"SRV1_TRIM", 1.0, 9, 90, 0),
}


@settings(max_examples=80, deadline=None)
@given(
    budget=st.sampled_from([400.0, 1000.0, 5000.0]),
    signed=st.booleans(),
    traffic=st.lists(
        st.tuples(st.sampled_from([0.0, 0.001, 0.01, 0.05]), st.sampled_from(sorted(MESSAGES))),
        min_size=100,
        max_size=800,
    ),
)
def test_no_window_exceeds_the_budget(
    budget: float, signed: bool, traffic: list[tuple[float, str]]
) -> None:
    plan = plan_budget(
        budget,
        servos=10,
        gimbals=1,
        health_names=7,
        components=2,
        rates=TelemetryRates(),
        signed=signed,
    )
    link = LinkBudget(plan)
    now, sent = 100.0, []
    for gap, kind in traffic:
        now += gap
        msg = MESSAGES[kind]()
        admitted = (
            link.admit_answer(140, msg, now) if kind == "answer" else link.allow(140, msg, now)
        )
        if admitted:
            size = len(msg.pack(mavlink2.MAVLink(None))) + (13 if signed else 0)
            sent.append((now, size))
    assert link.counters["essential_over_budget"] == 0
    assert peak_window_bytes(sent) <= budget
