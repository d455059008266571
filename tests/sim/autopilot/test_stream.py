"""The autopilot stream simulator over real pymavlink UDP on 127.0.0.1 (bounded windows)."""

from __future__ import annotations

import math
from collections import Counter

import pytest

from mavservo.config.autopilot_script import Event, RepeatServo, SetActuator, SetServo
from mavservo.mavlink.connection import mavlink2 as mav
from mavservo.mavlink.connection import open_connection
from mavservo.mavlink.quaternion import quaternion_to_euler
from mavservo.sim.autopilot.factory import simulator_from_config
from mavservo.sim.autopilot.motion_scripts import HoldProfile, StaircaseProfile, SweepProfile
from mavservo.sim.autopilot.replay import ReplayRunner
from mavservo.sim.autopilot.stream import AutopilotStream, normalized_outputs
from tests.support.autopilot import collect, of_type, peer
from tests.support.waiting import free_udp_port


@pytest.fixture
def link():
    port = free_udp_port()
    conn = peer(port)
    yield port, conn
    conn.close()


def test_stream_rates_and_content(link) -> None:
    port, conn = link
    with AutopilotStream(f"udpout:127.0.0.1:{port}", SweepProfile()).start() as stream:
        messages = collect(conn, 2.5)
    assert stream.error is None
    window = messages[-1][0] - messages[0][0]
    counts = Counter(m.get_type() for _, m in messages)
    # generous bounds around the nominal rates: 20 Hz, 10 Hz, 2 Hz, 1 Hz
    assert 0.4 * 20 * window <= counts["SERVO_OUTPUT_RAW"] <= 1.6 * 20 * window + 2
    assert 0.4 * 10 * window <= counts["ATTITUDE"] <= 1.6 * 10 * window + 2
    assert 1 <= counts["SYS_STATUS"] <= 2 * 2 * window + 2
    assert 1 <= counts["HEARTBEAT"] <= 2 * window + 2

    for _, msg in messages:
        assert msg.get_msgbuf()[0] == 0xFD  # MAVLink 2 on the wire
        assert (msg.get_srcSystem(), msg.get_srcComponent()) == (1, 1)
    hb = of_type(messages, "HEARTBEAT")[0]
    assert (hb.type, hb.autopilot) == (mav.MAV_TYPE_FIXED_WING, mav.MAV_AUTOPILOT_ARDUPILOTMEGA)

    outputs = of_type(messages, "SERVO_OUTPUT_RAW")
    stamps = [m.time_usec for m in outputs]
    assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps)
    profile = SweepProfile()
    for m in outputs:
        assert m.port == 0
        values = tuple(getattr(m, f"servo{i}_raw") for i in range(1, 17))
        assert len(values) == 16
        t = m.time_usec / 1e6 - 1.0  # the simulator reports boot time = stream time + 1 s
        expected = profile.pwm(t)
        assert values == expected


def test_commanded_log_is_what_the_peer_received(link) -> None:
    port, conn = link
    with AutopilotStream(f"udpout:127.0.0.1:{port}", SweepProfile()).start() as stream:
        messages = collect(conn, 1.5)
    received = [m.servo1_raw for m in of_type(messages, "SERVO_OUTPUT_RAW")]
    deduped = [v for i, v in enumerate(received) if i == 0 or v != received[i - 1]]
    logged = [c for c in stream.commanded_log() if c.key == 1 and c.source == "servo_output_raw"]
    assert len(deduped) >= 5
    assert [c.value for c in logged[: len(deduped)]] == deduped
    for entry in logged:
        assert stream.commanded_pwm(1, entry.t) == entry.value
    assert stream.commanded_pwm(1, logged[0].t - 1.0) is None


def test_set_message_interval_is_acked_and_honoured(link) -> None:
    port, conn = link
    with AutopilotStream(f"udpout:127.0.0.1:{port}", HoldProfile()).start():
        collect(conn, 2.0, until=lambda m: m.get_type() == "HEARTBEAT")
        conn.mav.command_long_send(
            1,
            1,
            mav.MAV_CMD_SET_MESSAGE_INTERVAL,
            0,
            mav.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW,
            -1,
            0,
            0,
            0,
            0,
            0,
        )
        before = collect(conn, 2.0, until=lambda m: m.get_type() == "COMMAND_ACK")
        after = collect(conn, 1.2)
        conn.mav.command_long_send(
            1,
            1,
            mav.MAV_CMD_SET_MESSAGE_INTERVAL,
            0,
            mav.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW,
            0,
            0,
            0,
            0,
            0,
            0,
        )
        restored = collect(conn, 1.2)
    ack = before[-1][1]
    assert ack.get_type() == "COMMAND_ACK"
    assert (ack.command, ack.result) == (mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAV_RESULT_ACCEPTED)
    assert (ack.target_system, ack.target_component) == (1, 191)
    assert of_type(after, "SERVO_OUTPUT_RAW") == []  # disabled: nothing after the ACK
    assert of_type(after, "ATTITUDE")  # the rest of the stream goes on
    assert len(of_type(restored, "SERVO_OUTPUT_RAW")) >= 5  # back to the default rate


def test_command_retried_with_same_content_until_the_third_try_is_acked(link) -> None:
    port, conn = link
    tries: list = []

    def ack_third(msg) -> None:
        if msg.get_type() == "COMMAND_LONG" and msg.command == mav.MAV_CMD_DO_SET_SERVO:
            tries.append(msg)
            if len(tries) == 3:
                conn.mav.command_ack_send(msg.command, mav.MAV_RESULT_ACCEPTED, 0, 0, 1, 1)

    script = [Event(0.2, SetServo(9, 1100))]
    stream = AutopilotStream(
        f"udpout:127.0.0.1:{port}", HoldProfile(), script, command_target=(1, 191)
    )
    with stream.start():
        record = None
        for _ in range(60):  # bounded: at most ~6 s
            collect(conn, 0.1, on_message=ack_third)
            if stream.commands.commands and stream.commands.commands[0].done:
                record = stream.commands.commands[0]
                break
        collect(conn, 0.8, on_message=ack_third)  # anything after the ACK would be a bug
    assert record is not None
    assert len(tries) == 3 and record.attempts == 3
    assert {
        (m.target_system, m.target_component, m.param1, m.param2, m.confirmation) for m in tries
    } == {(1, 191, 9.0, 1100.0, 0)}
    assert record.result == mav.MAV_RESULT_ACCEPTED and record.ack_from == (1, 191)
    assert [a.source for a in stream.commands.acks] == [(1, 191)]


def test_mission_commands_content_and_output_mirroring(link) -> None:
    port, conn = link
    seen: list = []

    def ack_all(msg) -> None:
        if msg.get_type() == "COMMAND_LONG":
            seen.append(msg)
            conn.mav.command_ack_send(msg.command, mav.MAV_RESULT_ACCEPTED, 0, 0, 1, 1)

    script = [
        Event(0.1, SetServo(9, 1100)),
        Event(0.1, SetActuator((0.25, math.nan, -1.0), set_index=1)),
        Event(0.3, RepeatServo(10, 1900, count=1, cycle_s=0.4)),
    ]
    stream = AutopilotStream(
        f"udpout:127.0.0.1:{port}", HoldProfile(), script, repeat_servo_cycle="milliseconds"
    )
    with stream.start():
        messages = collect(conn, 1.5, on_message=ack_all)
    by_cmd = {m.command: m for m in seen}
    assert set(by_cmd) == {
        mav.MAV_CMD_DO_SET_SERVO,
        mav.MAV_CMD_DO_SET_ACTUATOR,
        mav.MAV_CMD_DO_REPEAT_SERVO,
    }
    assert all((m.target_system, m.target_component) == (1, 0) for m in seen)  # broadcast
    act = by_cmd[mav.MAV_CMD_DO_SET_ACTUATOR]
    assert act.param1 == 0.25 and act.param3 == -1.0 and act.param7 == 1.0  # set 1: 7..12
    assert all(math.isnan(v) for v in (act.param2, act.param4, act.param5, act.param6))
    rep = by_cmd[mav.MAV_CMD_DO_REPEAT_SERVO]
    assert (rep.param1, rep.param2, rep.param3, rep.param4) == (10, 1900, 1, 400.0)  # ms
    assert all(r.result == 0 and r.attempts == 1 for r in stream.commands.commands)
    # like ArduPilot, the commanded channels show up in SERVO_OUTPUT_RAW
    ch9 = [m.servo9_raw for m in of_type(messages, "SERVO_OUTPUT_RAW")]
    ch10 = [m.servo10_raw for m in of_type(messages, "SERVO_OUTPUT_RAW")]
    assert ch9[0] == 0 and ch9[-1] == 1100
    assert 1900 in ch10 and ch10[-1] == 1500  # repeat ends on trim
    assert stream.commanded_actuator(7, stream.commanded_log("actuator")[0].t) == 0.25
    assert stream.commanded_actuator(8, 1e12) is None


def test_gimbal_manager_discovers_device_then_streams_targets() -> None:
    port = free_udp_port()
    device = peer(port, component=154)
    try:
        stream = AutopilotStream(f"udpout:127.0.0.1:{port}", HoldProfile(), gimbal=True)
        with stream.start():
            waiting = collect(device, 1.5)
            device.mav.gimbal_device_information_send(
                0, b"Test", b"Gimbal", b"", 0, 0, 0, 0, 0, -0.5, 0.5, -1.5, 0.5, -2.7, 2.7
            )
            streaming = collect(device, 1.0)
            stream.set_gimbal(0.0, -30.0, 45.0, 16)
            retargeted = collect(device, 1.0)
    finally:
        device.close()
    requests = [
        m for m in of_type(waiting, "COMMAND_LONG") if m.command == mav.MAV_CMD_REQUEST_MESSAGE
    ]
    assert requests and all(m.param1 == 283 and m.target_component == 154 for m in requests)
    assert of_type(waiting, "GIMBAL_DEVICE_SET_ATTITUDE") == []
    sets = of_type(streaming, "GIMBAL_DEVICE_SET_ATTITUDE")
    states = of_type(streaming, "AUTOPILOT_STATE_FOR_GIMBAL_DEVICE")
    assert len(sets) >= 10 and len(states) >= 10  # ~50 Hz nominal
    assert all((m.target_system, m.target_component) == (1, 154) for m in sets)
    assert all((m.target_system, m.target_component) == (1, 0) for m in states)
    after_first_set = streaming[[m for _, m in streaming].index(sets[0]) :]
    assert not [
        m
        for m in of_type(after_first_set, "COMMAND_LONG")
        if m.command == mav.MAV_CMD_REQUEST_MESSAGE
    ]
    assert quaternion_to_euler(tuple(sets[0].q)) == pytest.approx((0, 0, 0), abs=1e-4)
    last = of_type(retargeted, "GIMBAL_DEVICE_SET_ATTITUDE")[-1]
    assert last.flags == 16
    assert quaternion_to_euler(tuple(last.q)) == pytest.approx((0, -30, 45), abs=1e-3)
    assert math.isnan(last.angular_velocity_x)
    log = stream.commanded_log("gimbal")
    assert [c.value for c in log] == [(0.0, 0.0, 0.0, 0), (0.0, -30.0, 45.0, 16)]
    assert stream.commanded_gimbal(log[1].t) == (0.0, -30.0, 45.0, 16)


def test_dropout_silences_everything_then_resumes(link) -> None:
    port, conn = link
    with AutopilotStream(f"udpout:127.0.0.1:{port}", HoldProfile()).start() as stream:
        messages = collect(conn, 0.5)
        stream.dropout(1.2)
        messages += collect(conn, 2.5)
    assert len(stream.dropouts) == 1
    start, end = stream.dropouts[0]
    sent_inside = [name for t, name in stream.sent_log if start <= t < end]
    assert sent_inside == []  # heartbeats included
    # the peer's view: the autopilot's own clocks show a hole at least as long as the dropout
    outputs = [m.time_usec for m in of_type(messages, "SERVO_OUTPUT_RAW")]
    attitude = [m.time_boot_ms for m in of_type(messages, "ATTITUDE")]
    assert max(b - a for a, b in zip(outputs, outputs[1:], strict=False)) >= 1.2e6
    assert max(b - a for a, b in zip(attitude, attitude[1:], strict=False)) >= 1200
    assert outputs[-1] > (end - stream.t0 + 1.0) * 1e6  # it came back
    assert of_type(messages, "HEARTBEAT")


def test_udpin_mode_waits_for_the_bridge_then_streams() -> None:
    port = free_udp_port()
    stream = AutopilotStream(f"udpin:127.0.0.1:{port}", HoldProfile())
    with stream.start():
        bridge = open_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=191)
        try:
            bridge.mav.heartbeat_send(
                mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0
            )
            messages = collect(bridge, 1.0)
        finally:
            bridge.close()
    assert of_type(messages, "SERVO_OUTPUT_RAW")
    assert stream.received.count("HEARTBEAT") == 1
    assert stream.received.last("HEARTBEAT").type == mav.MAV_TYPE_ONBOARD_CONTROLLER


def test_factory_builds_what_the_config_asks_for(tmp_path) -> None:
    stream = simulator_from_config(
        {
            "profile": "steps",
            "servo_output_rate_hz": 10,
            "script": [{"at": 1, "do_set_servo": {"channel": 9, "pwm": 1100}}],
        },
        "udpout:127.0.0.1:9",
    )
    assert isinstance(stream, AutopilotStream) and isinstance(stream.profile, StaircaseProfile)
    assert stream.interval_s("SERVO_OUTPUT_RAW") == pytest.approx(0.1)
    assert [e.action for e in stream.script.events] == [SetServo(9, 1100)]
    runner = simulator_from_config(
        {"profile": "replay", "replay_file": str(tmp_path / "x.tlog")}, "udpout:127.0.0.1:9"
    )
    assert isinstance(runner, ReplayRunner)
    with pytest.raises(ValueError):
        simulator_from_config({"profile": "replay"}, "udpout:127.0.0.1:9")


def test_normalized_outputs_map_ardupilot_ranges_to_unit_interval() -> None:
    frame = (1100, 1500, 2000, 1900) + (0,) * 12
    values, active = normalized_outputs(frame)
    assert values[:4] == [-1.0, 0.0, 1.0, 1.0] and active == 0b1111
    assert all(math.isnan(v) for v in values[4:])


def test_px4_style_actuator_output_status_when_asked_for(link) -> None:
    port, conn = link
    stream = AutopilotStream(
        f"udpout:127.0.0.1:{port}", StaircaseProfile(), actuator_output_status_hz=10.0
    )
    with stream.start():
        messages = collect(conn, 1.0)
    statuses = of_type(messages, "ACTUATOR_OUTPUT_STATUS")
    assert statuses
    for status in statuses:
        assert status.active == 0b1111
        assert status.actuator[0] == pytest.approx(-1.0)  # first stair: 1100 us
        assert status.actuator[2] == pytest.approx(-1.0)  # throttle at 1000 us
