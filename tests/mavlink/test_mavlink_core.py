"""Behaviour of the sans-I/O MAVLink core: addressing, ACKs, retries, bad input, repeat servo,
arbitration with mirroring, failsafe, system-id following and telemetry content."""

from __future__ import annotations

import logging
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mavservo.mavlink.commands import INT32_MAX
from mavservo.mavlink.gimbal import GimbalDevice, GimbalSettings
from mavservo.mavlink.mavlink_core import MavlinkCore
from mavservo.mavlink.settings import MavlinkSettings
from mavservo.servos.base import Fault
from tests.support.mavlink_doubles import (
    NAN,
    RecordingBackend,
    command_int,
    command_long,
    heartbeat,
    make_mavlink_core,
    servo_output_raw,
    state,
    wire,
)

GCS = (255, 190)
AUTOPILOT = (1, 1)
SERVO = (1, 140)
ACCEPTED, TEMP_REJECTED, DENIED, UNSUPPORTED = 0, 1, 2, 3


def make_core(**overrides) -> tuple[MavlinkCore, RecordingBackend]:
    return make_mavlink_core(**{"channel_trims_us": {9: 1500.0}, **overrides})


def acks(out) -> list[tuple[int, int, int]]:
    """(sending component, command, result) of every COMMAND_ACK in ``out``."""
    return [(cid, m.command, m.result) for cid, m in out if m.get_type() == "COMMAND_ACK"]


def send(core, msg, src=GCS, now=0.0):
    return core.on_message(wire(msg, src), now)


def test_direct_do_set_servo_is_applied_and_acked_from_servo_component():
    core, backend = make_core()
    out = send(core, command_long(SERVO, 183, 1, 1700))
    assert acks(out) == [(140, 183, ACCEPTED)]
    assert backend.servo_calls() == [("servo", 1, 1700.0, "do_set_servo")]
    ack = out[0][1]
    assert (ack.target_system, ack.target_component) == GCS


def test_command_int_do_set_servo_works_like_command_long():
    core, backend = make_core()
    out = send(core, command_int(SERVO, 183, 9, 1100))
    assert acks(out) == [(140, 183, ACCEPTED)]
    assert backend.servo_calls() == [("servo", 9, 1100.0, "do_set_servo")]


@pytest.mark.parametrize(
    "params, reason",
    [
        ((1, 3000), "bad_param"),
        ((1, NAN), "bad_param"),
        ((1.5, 1500), "bad_param"),
        ((5, 1500), "unmapped"),
        ((0, 1500), "bad_param"),
    ],
)
def test_bad_direct_do_set_servo_is_denied_counted_and_never_applied(params, reason):
    core, backend = make_core()
    out = send(core, command_long(SERVO, 183, *params))
    assert acks(out) == [(140, 183, DENIED)]
    assert backend.calls == []
    assert core.commands.counters[f"reason_{reason}"] == 1


def test_broadcast_for_mapped_channel_is_acted_on_and_acked_from_our_component():
    core, backend = make_core()
    out = send(core, command_long((1, 0), 183, 9, 1900))
    assert acks(out) == [(140, 183, ACCEPTED)]
    assert backend.servo_calls() == [("servo", 9, 1900.0, "do_set_servo")]


def test_broadcast_for_unmapped_channel_or_unknown_command_is_ignored_silently():
    core, backend = make_core()
    assert send(core, command_long((0, 0), 183, 3, 1900)) == []
    assert send(core, command_long((1, 0), 400, 1, 21196)) == []
    assert backend.calls == []


def test_commands_for_other_components_or_systems_are_ignored():
    core, backend = make_core()
    assert send(core, command_long((1, 1), 183, 1, 1900)) == []
    assert send(core, command_long((2, 140), 183, 1, 1900)) == []
    assert backend.calls == []


def test_ignored_commands_are_counted_and_logged_at_debug_level(caplog):
    core, _ = make_core()
    with caplog.at_level(logging.DEBUG, logger="mavservo.mavlink.commands"):
        send(core, command_long((2, 140), 183, 1, 1900))  # another system
        send(core, command_long((1, 1), 183, 1, 1900))  # the autopilot
        send(core, command_long((1, 0), 187, 0.5, 0, 0, 0, 0, 0, 1))  # broadcast, unmapped set
    assert core.stats()["commands"] == {
        "ignored_other_system": 1,
        "ignored_other_component": 1,
        "ignored_not_ours": 1,
    }
    lines = [r.getMessage() for r in caplog.records if r.levelno == logging.DEBUG]
    assert len(lines) == 3 and all("ignored" in line for line in lines), lines
    assert "system 2" in lines[0] and "component 1" in lines[1] and "187" in lines[2]


def test_autopilot_addressed_do_set_servo_acted_on_without_ack_when_configured():
    core, backend = make_core(act_on_autopilot_commands=True)
    assert send(core, command_long((1, 1), 183, 9, 1100)) == []
    assert send(core, command_long((1, 1), 183, 4, 1100)) == []  # unmapped: not ours
    assert backend.servo_calls() == [("servo", 9, 1100.0, "do_set_servo")]


def test_unknown_command_addressed_to_us_is_unsupported():
    core, _ = make_core()
    assert acks(send(core, command_long(SERVO, 400, 1))) == [(140, 400, UNSUPPORTED)]


def test_retry_is_acked_again_with_same_result_but_applied_once():
    core, backend = make_core()
    first = send(core, command_long(SERVO, 184, 9, 1900, 3, 2), now=10.0)
    again = send(core, command_long(SERVO, 184, 9, 1900, 3, 2, confirmation=1), now=10.5)
    same = send(core, command_long(SERVO, 184, 9, 1900, 3, 2), now=11.0)
    assert acks(first) == acks(again) == acks(same) == [(140, 184, ACCEPTED)]
    assert len(backend.servo_calls()) == 1
    assert core.commands.counters["retry_not_reapplied"] == 2


def test_same_command_after_retry_window_is_applied_again():
    core, backend = make_core()
    send(core, command_long(SERVO, 183, 1, 1200), now=0.0)
    send(core, command_long(SERVO, 183, 1, 1200), now=5.0)
    assert len(backend.servo_calls()) == 2


def test_retry_of_denied_command_is_denied_again():
    core, _ = make_core()
    assert acks(send(core, command_long(SERVO, 183, 1, 9999))) == [(140, 183, DENIED)]
    assert acks(send(core, command_long(SERVO, 183, 1, 9999), now=0.5)) == [(140, 183, DENIED)]


def test_offline_servo_gives_temporarily_rejected():
    core, backend = make_core()
    backend.offline.add("aileron")
    assert acks(send(core, command_long(SERVO, 183, 1, 1600))) == [(140, 183, TEMP_REJECTED)]


@pytest.mark.parametrize("unit, cycle", [("seconds", 2.0), ("milliseconds", 2000.0)])
def test_repeat_servo_alternates_and_ends_on_trim(unit, cycle):
    core, backend = make_core(repeat_servo_cycle=unit)
    send(core, command_long(SERVO, 184, 9, 1900, 3, cycle), now=100.0)
    for step in range(1, 80):
        core.tick(100.0 + step * 0.1)
    pwms = [c[2] for c in backend.servo_calls()]
    assert pwms == [1900.0, 1500.0, 1900.0, 1500.0, 1900.0, 1500.0]
    assert core.commands.repeating_channels() == set()


def test_do_set_servo_cancels_a_running_repeat():
    core, backend = make_core()
    send(core, command_long(SERVO, 184, 9, 1900, 5, 2), now=0.0)
    core.tick(1.0)
    send(core, command_long(SERVO, 183, 9, 1100), now=1.2)
    for step in range(2, 40):
        core.tick(step * 0.5)
    assert [c[2] for c in backend.servo_calls()] == [1900.0, 1500.0, 1100.0]


def test_repeat_servo_bad_count_or_cycle_denied():
    core, backend = make_core()
    assert acks(send(core, command_long(SERVO, 184, 9, 1900, 0, 2))) == [(140, 184, DENIED)]
    assert acks(send(core, command_long(SERVO, 184, 9, 1900, 2, -1))) == [(140, 184, DENIED)]
    assert backend.calls == []


def test_set_actuator_nan_leaves_and_param7_is_the_actuator_set_index():
    core, backend = make_core()
    out = send(core, command_long((1, 0), 187, 0.5, NAN, NAN, NAN, NAN, NAN, 0))
    assert acks(out) == [(140, 187, ACCEPTED)]
    assert backend.servo_calls("actuator") == [("actuator", 1, 0.5, "do_set_actuator")]
    # the spec: "if set to 1, Actuator 1 becomes Actuator 7"; 7..12 are not mapped here, so a
    # broadcast is left to whoever owns them and a command addressed to us is denied
    assert send(core, command_long((1, 0), 187, 0.5, 0, 0, 0, 0, 0, 1), now=3) == []
    assert acks(send(core, command_long(SERVO, 187, 0.5, 0, 0, 0, 0, 0, 1), now=3)) == [
        (140, 187, DENIED)
    ]


def test_set_actuator_out_of_range_denied_before_anything_moves():
    core, backend = make_core()
    out = send(core, command_long(SERVO, 187, 1.5, NAN, NAN, NAN, NAN, NAN, 0))
    assert acks(out) == [(140, 187, DENIED)]
    assert backend.calls == []


def test_set_actuator_command_int_int32_max_means_leave():
    core, backend = make_core()
    out = send(core, command_int(SERVO, 187, -0.25, NAN, NAN, NAN, INT32_MAX, INT32_MAX, 0))
    assert acks(out) == [(140, 187, ACCEPTED)]
    assert backend.servo_calls("actuator") == [("actuator", 1, -0.25, "do_set_actuator")]


def test_set_actuator_command_int_carries_actuators_5_and_6_scaled_by_1e7():
    # the spec: "If sent in COMMAND_INT or MISSION_ITEM_INT: value is scaled by 1e7"
    core, backend = make_core()
    out = send(core, command_int(SERVO, 187, NAN, NAN, NAN, NAN, 5_000_000, INT32_MAX, 0))
    assert acks(out) == [(140, 187, ACCEPTED)]
    assert backend.servo_calls("actuator") == [("actuator", 5, 0.5, "do_set_actuator")]
    out = send(core, command_int(SERVO, 187, NAN, NAN, NAN, NAN, 20_000_000, INT32_MAX, 0), now=5)
    assert acks(out) == [(140, 187, DENIED)]  # 2.0: outside [-1, 1]


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.one_of(
            st.floats(width=32, allow_nan=True, allow_infinity=True),
            st.integers(-3000, 3000).map(float),
        ),
        min_size=7,
        max_size=7,
    ),
    st.sampled_from([183, 184, 187]),
)
def test_any_params_yield_exactly_one_ack_and_only_valid_values_reach_backend(params, command):
    core, backend = make_core()
    out = send(core, command_long(SERVO, command, *params))
    assert len(acks(out)) == 1
    for call in backend.calls:
        value = call[2]
        assert math.isfinite(value)
        assert (-1 <= value <= 1) if call[0] == "actuator" else (500 <= value <= 2500)
    if acks(out)[0][2] != ACCEPTED:
        assert backend.calls == []


def test_mirror_applies_changes_on_mapped_channels_ignores_zero_and_other_sources():
    core, backend = make_core()
    send(core, servo_output_raw(servo1=1500, servo2=1700, servo9=0), src=AUTOPILOT)
    send(core, servo_output_raw(servo1=1500, servo9=0), src=AUTOPILOT, now=0.05)
    send(core, servo_output_raw(servo1=1600, servo9=1200), src=AUTOPILOT, now=0.1)
    send(core, servo_output_raw(servo1=1900), src=GCS, now=0.15)
    assert backend.servo_calls() == [
        ("servo", 1, 1500.0, "servo_output_raw"),
        ("servo", 1, 1600.0, "servo_output_raw"),
        ("servo", 9, 1200.0, "servo_output_raw"),
    ]


def test_mirror_port_offset():
    core, backend = make_core(servo_output_port_width=8)
    send(core, servo_output_raw(port=1, servo1=1300), src=AUTOPILOT)
    assert backend.servo_calls() == [("servo", 9, 1300.0, "servo_output_raw")]


def test_explicit_command_holds_off_mirroring_then_mirroring_resumes():
    core, backend = make_core(command_hold_s=2.0)
    send(core, command_long(SERVO, 183, 1, 1900), now=0.0)
    send(core, servo_output_raw(servo1=1500), src=AUTOPILOT, now=1.0)
    assert backend.servo_calls()[-1][2] == 1900.0
    send(core, servo_output_raw(servo1=1500), src=AUTOPILOT, now=2.5)
    assert backend.servo_calls()[-1] == ("servo", 1, 1500.0, "servo_output_raw")
    assert core.hold.mirror_suppressed == 1


def test_actuator_output_status_mirror_pwm_units():
    core, backend = make_core(mirror_actuator_output_status=True)
    from pymavlink.dialects.v20 import ardupilotmega as m

    values = [1750.0] + [0.0] * 31
    send(core, m.MAVLink_actuator_output_status_message(0, 0b1, values), src=AUTOPILOT)
    assert backend.servo_calls("actuator") == [("actuator", 1, 0.5, "actuator_output_status")]


def test_heartbeat_loss_enters_failsafe_once_and_recovery_announced():
    core, backend = make_core(heartbeat_timeout_s=2.0)
    core.tick(5.0)
    assert backend.failsafe_events == []  # never saw the autopilot: nothing to lose
    send(core, heartbeat(), src=AUTOPILOT, now=10.0)
    core.tick(11.0)
    assert backend.failsafe_events == []
    out = core.tick(12.5) + core.tick(13.0)
    assert backend.failsafe_events == ["enter"]
    texts = [m.text for _, m in out if m.get_type() == "STATUSTEXT"]
    assert any("failsafe" in t for t in texts)
    send(core, servo_output_raw(servo1=1800), src=AUTOPILOT, now=13.5)
    assert backend.servo_calls() == []
    send(core, heartbeat(), src=AUTOPILOT, now=14.0)
    assert backend.failsafe_events == ["enter", "leave"]
    texts = [m.text for _, m in core.tick(14.1) if m.get_type() == "STATUSTEXT"]
    assert any("autopilot back" in t for t in texts)


def test_system_id_follows_first_autopilot_heartbeat_not_gcs():
    core, backend = make_core(system_id="follow")
    send(core, heartbeat(mav_type=6, autopilot=8), src=(255, 190))
    assert core.system_id == 1
    send(core, heartbeat(), src=(7, 1))
    assert core.system_id == 7
    assert acks(send(core, command_long((7, 140), 183, 1, 1600))) == [(140, 183, ACCEPTED)]
    assert send(core, command_long((1, 140), 183, 1, 1600)) == []


def test_allowed_sources_filter_commands():
    core, backend = make_core(allowed_sources=frozenset({(255, 190)}))
    assert send(core, command_long(SERVO, 183, 1, 1600), src=(255, 1)) == []
    assert acks(send(core, command_long(SERVO, 183, 1, 1600))) == [(140, 183, ACCEPTED)]
    assert core.counters["rejected_source"] == 1


def test_heartbeats_once_per_second_per_component_with_servo_type():
    core, _ = make_core()
    beats = []
    for step in range(0, 301):
        beats += [(c, m.type) for c, m in core.tick(step * 0.01) if m.get_type() == "HEARTBEAT"]
    assert beats == [(140, 33)] * 4


def test_telemetry_content_matches_servo_state():
    core, backend = make_core()
    backend.states["aileron"] = state(
        15.0, velocity=-120.0, current=1.25, temperature=41, voltage=24.2
    )
    backend.states["flap"] = state(-6.0)
    out = [m for _, m in core.tick(0.0)]
    aos = next(m for m in out if m.get_type() == "ACTUATOR_OUTPUT_STATUS")
    assert aos.active == 0b101
    assert aos.actuator[0] == pytest.approx(0.5) and aos.actuator[2] == pytest.approx(-0.2)
    # the default ESC numbers start at 17 (ESC_TELEMETRY_17_TO_20), above the motors
    esc = next(m for m in out if m.get_type() == "ESC_TELEMETRY_17_TO_20")
    assert esc.temperature[0] == 41 and esc.current[0] == 125 and esc.rpm[0] == 20
    assert esc.voltage[0] == 2420
    named = {m.name: m.value for m in out if m.get_type() == "NAMED_VALUE_FLOAT"}
    assert named["s1_pos"] == pytest.approx(15.0) and named["s3_pos"] == pytest.approx(-6.0)
    assert all(len(name) <= 10 for name in named)


def test_set_message_interval_and_request_message():
    core, backend = make_core()
    backend.states["aileron"] = state(3.0)
    out = send(core, command_long(SERVO, 511, 375, -1))
    assert acks(out) == [(140, 511, ACCEPTED)]
    emitted = [m for step in range(100) for _, m in core.tick(step * 0.01)]
    assert not any(m.get_type() == "ACTUATOR_OUTPUT_STATUS" for m in emitted)
    out = send(core, command_long(SERVO, 512, 375), now=1.0)
    assert acks(out) == [(140, 512, ACCEPTED)]
    assert [m.get_type() for _, m in out][1:] == ["ACTUATOR_OUTPUT_STATUS"]
    assert acks(send(core, command_long(SERVO, 512, 283), now=1.0)) == [(140, 512, UNSUPPORTED)]
    assert acks(send(core, command_long(SERVO, 511, 283, 1000), now=1.0)) == [
        (140, 511, UNSUPPORTED)
    ]


def test_request_message_heartbeat_answers_at_once_from_the_component_asked():
    gimbal = GimbalDevice(
        GimbalSettings(name="g", axis_servos={"pitch": "aileron"}, limits_deg={"pitch": (-90, 30)}),
        RecordingBackend(),
    )
    core = MavlinkCore(MavlinkSettings(system_id=1), RecordingBackend(), gimbals=[gimbal])
    for target, now, expected in (((1, 140), 1.0, 33), ((1, 154), 2.0, 26), ((1, 0), 3.0, 33)):
        out = send(core, command_long(target, 512, 0), now=now)
        component = 154 if target[1] == 154 else 140
        assert acks(out) == [(component, 512, ACCEPTED)], target
        beats = [(cid, m.type) for cid, m in out if m.get_type() == "HEARTBEAT"]
        assert beats == [(component, expected)], target


def test_statustext_on_fault_onset_clearance_and_offline():
    core, backend = make_core()
    backend.states["aileron"] = state(0.0)
    core.tick(0.0)
    backend.states["aileron"] = state(0.0, faults=Fault(list(Fault)[0].value))
    texts = [m.text for _, m in core.tick(1.0) if m.get_type() == "STATUSTEXT"]
    backend.states["aileron"] = state(0.0)
    backend.offline.add("aileron")
    texts += [m.text for _, m in core.tick(2.0) if m.get_type() == "STATUSTEXT"]
    assert any("fault" in t for t in texts)
    assert any("cleared" in t for t in texts)
    assert any("offline" in t for t in texts)
