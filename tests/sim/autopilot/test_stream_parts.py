"""The simulated autopilot's parts, each alone: message rates and the companion's rate
commands, the servo outputs, the gimbal device search, the record of what was commanded,
and the MAVLink link (a real pymavlink pair on 127.0.0.1).

The whole stream is tested against the bridge in test_stream.py and the e2e tests; here each
part is driven through its own interface with explicit times (no clock, no sleeps).
"""

from __future__ import annotations

import math
import time

import pytest

from mavservo.config import GimbalTarget, RepeatServo
from mavservo.mavlink import mavlink2 as mav
from mavservo.mavlink import open_connection
from mavservo.sim.autopilot.autopilot_link import AutopilotLink
from mavservo.sim.autopilot.commanded import Commanded, CommandedLog
from mavservo.sim.autopilot.message_rates import MessageRates, interval_of
from mavservo.sim.autopilot.motion_scripts import HoldProfile
from mavservo.sim.autopilot.mount_driver import REQUEST_INTERVAL_S, MountDriver
from mavservo.sim.autopilot.servo_outputs import ServoOutputs

HEARTBEAT_ID = mav.MAVLINK_MSG_ID_HEARTBEAT
SERVO_OUTPUT_RAW_ID = mav.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW
GIMBAL_SET_ID = mav.MAVLINK_MSG_ID_GIMBAL_DEVICE_SET_ATTITUDE


def _rates() -> MessageRates:
    return MessageRates(
        {"HEARTBEAT": 1.0, "SERVO_OUTPUT_RAW": 0.05, "GIMBAL_DEVICE_SET_ATTITUDE": None},
        unrequestable=("GIMBAL_DEVICE_SET_ATTITUDE",),
    )


def test_rates_are_due_on_absolute_deadlines_and_skip_ahead_after_a_stall() -> None:
    rates = _rates()
    rates.start(10.0)
    assert rates.due(10.0) == ["HEARTBEAT", "SERVO_OUTPUT_RAW"]
    assert rates.due(10.03) == []
    assert rates.due(10.06) == ["SERVO_OUTPUT_RAW"]  # due at 10.05: next at 10.10, not 10.11
    assert rates.next_deadline(default=99.0) == pytest.approx(10.10)
    assert rates.due(12.0) == ["HEARTBEAT", "SERVO_OUTPUT_RAW"]  # a 2 s stall: once each
    assert rates.due(12.01) == []
    assert rates.next_deadline(default=99.0) == pytest.approx(12.05)


def test_set_message_interval_turns_off_restores_and_sets_and_a_reboot_forgets() -> None:
    rates = _rates()
    set_interval = mav.MAV_CMD_SET_MESSAGE_INTERVAL
    ok = (mav.MAV_RESULT_ACCEPTED, None)
    assert rates.on_command(set_interval, SERVO_OUTPUT_RAW_ID, 100_000) == ok
    assert rates.interval_s("SERVO_OUTPUT_RAW") == pytest.approx(0.1)
    assert rates.on_command(set_interval, HEARTBEAT_ID, -1) == ok
    assert rates.interval_s("HEARTBEAT") is None
    rates.start(0.0)
    assert rates.due(0.0) == ["SERVO_OUTPUT_RAW"]  # an off message is never due
    assert rates.on_command(set_interval, SERVO_OUTPUT_RAW_ID, 0) == ok
    assert rates.interval_s("SERVO_OUTPUT_RAW") == 0.05  # 0: back to the default
    rates.reset()
    assert rates.interval_s("HEARTBEAT") == 1.0


def test_rate_commands_for_messages_it_does_not_send_are_denied() -> None:
    rates = _rates()
    denied = (mav.MAV_RESULT_DENIED, None)
    attitude_id = mav.MAVLINK_MSG_ID_ATTITUDE
    assert rates.on_command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, attitude_id, 1000) == denied
    assert rates.on_command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, 65_000, 1000) == denied
    assert rates.on_command(mav.MAV_CMD_REQUEST_MESSAGE, GIMBAL_SET_ID, 0) == denied
    assert rates.on_command(mav.MAV_CMD_REQUEST_MESSAGE, HEARTBEAT_ID, 0) == (
        mav.MAV_RESULT_ACCEPTED,
        "HEARTBEAT",
    )
    assert rates.on_command(mav.MAV_CMD_DO_SET_SERVO, 1, 1500) == (
        mav.MAV_RESULT_UNSUPPORTED,
        None,
    )
    assert interval_of(0) is None and interval_of(-5) is None and interval_of(4) == 0.25


def test_outputs_hold_a_set_servo_and_report_only_changes() -> None:
    outputs = ServoOutputs(HoldProfile())
    first = outputs.frame(0.0, now=0.0)
    assert first[:4] == (1500, 1500, 1000, 1500)
    assert len(outputs.changes(first)) == 16  # the first frame: every channel
    outputs.set_servo(2, 1800)
    frame = outputs.frame(5.0, now=5.0)
    assert frame[1] == 1800
    assert outputs.changes(frame) == [(2, 1800)]
    assert outputs.changes(frame) == []


def test_outputs_cycle_a_repeat_servo_then_hold_trim_and_a_set_servo_ends_it() -> None:
    outputs = ServoOutputs(HoldProfile(), servo_trim=1500)
    outputs.repeat_servo(RepeatServo(channel=5, pwm=1900, count=2, cycle_s=1.0), now=100.0)
    assert [outputs.frame(0.0, now=100.0 + dt)[4] for dt in (0.1, 0.6, 1.1, 1.6, 2.5)] == [
        1900,
        1500,
        1900,
        1500,
        1500,
    ]
    outputs.repeat_servo(RepeatServo(channel=6, pwm=1900, count=5, cycle_s=1.0), now=100.0)
    outputs.set_servo(6, 1200)
    assert outputs.frame(0.0, now=100.1)[5] == 1200


def test_outputs_not_mirrored_follow_the_profile_only() -> None:
    outputs = ServoOutputs(HoldProfile(), mirror=False)
    outputs.set_servo(1, 1900)
    outputs.repeat_servo(RepeatServo(channel=2, pwm=1900, count=1, cycle_s=1.0), now=0.0)
    assert outputs.frame(0.0, now=0.1)[:2] == (1500, 1500)


def test_mount_asks_for_the_device_once_a_second_within_the_search_window() -> None:
    mount = MountDriver(154, search_s=(10.0, 60.0))
    assert not mount.request_due(now=100.0, boot_s=5.0, armed=False)  # too early after boot
    assert mount.request_due(now=100.0, boot_s=10.5, armed=False)
    assert not mount.request_due(now=100.0 + REQUEST_INTERVAL_S / 2, boot_s=11.0, armed=False)
    assert mount.request_due(now=101.0, boot_s=11.5, armed=False)
    assert not mount.request_due(now=200.0, boot_s=70.0, armed=True)  # armed past the window
    assert mount.request_due(now=200.0, boot_s=70.0, armed=False)


def test_mount_is_ready_only_once_its_own_device_answered() -> None:
    class Info:
        def __init__(self, component: int) -> None:
            self.component = component

        def get_srcComponent(self) -> int:  # noqa: N802 - pymavlink's name
            return self.component

    mount = MountDriver(154)
    assert not mount.ready()
    mount.heard(Info(155))  # another component's answer does not count
    assert not mount.ready() and mount.request_due(now=0.0, boot_s=0.0, armed=False)
    mount.heard(Info(154))
    assert mount.ready() and not mount.request_due(now=5.0, boot_s=5.0, armed=False)
    assert MountDriver(154, wait_for_device=False).ready()
    assert not MountDriver(154, enabled=False).request_due(now=0.0, boot_s=20.0, armed=False)


def test_mount_attitude_and_a_target_recorded_once_per_change() -> None:
    mount = MountDriver(154, target=GimbalTarget(0.0, -30.0, 0.0, 0))
    flags, q, rates = mount.attitude()
    assert flags == 0 and all(math.isnan(r) for r in rates)
    assert q[0] == pytest.approx(math.cos(math.radians(-15.0)))
    assert mount.new_target() == GimbalTarget(0.0, -30.0, 0.0, 0)
    assert mount.new_target() is None
    mount.target = GimbalTarget(0.0, 0.0, 0.0, mav.GIMBAL_DEVICE_FLAGS_RETRACT)
    flags, q, rates = mount.attitude()
    assert all(math.isnan(v) for v in q) and rates == (0.0, 0.0, 0.0)
    assert mount.new_target() is not None


def test_commanded_log_answers_what_was_asked_at_a_time_per_kind() -> None:
    log = CommandedLog(keep=10)
    log.record("servo", Commanded(1.0, 1, 1100, "servo_output_raw"))
    log.record("servo", Commanded(2.0, 1, 1200, "do_set_servo"))
    log.record("servo", Commanded(1.5, 2, 1300, "servo_output_raw"))
    log.record("gimbal", Commanded(1.2, 0, (0.0, -30.0, 0.0, 0), "gimbal"))
    assert log.at("servo", 1, 0.5) is None
    assert log.at("servo", 1, 1.9).value == 1100  # type: ignore[union-attr]
    assert log.at("servo", 1, 2.0).value == 1200  # type: ignore[union-attr]
    assert [c.t for c in log.changes("servo")] == [1.0, 1.5, 2.0]
    assert [c.key for c in log.changes("gimbal")] == [0]
    with pytest.raises(ValueError):
        CommandedLog(keep=1)


def test_link_sends_arduplane_messages_and_counts_them() -> None:
    listener = open_connection("udpin:127.0.0.1:0", source_system=255, source_component=190)
    port = listener.port.getsockname()[1]
    link = AutopilotLink(system_id=1, component_id=1, keep=2)
    link.open(f"udpout:127.0.0.1:{port}")
    try:
        link.heartbeat(1.0, armed=True)
        link.servo_output_raw(2.0, 3_000_000, [1500] * 16)
        link.command_ack(3.0, mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAV_RESULT_DENIED, (255, 190))
        got = {}
        deadline = time.monotonic() + 5.0
        while len(got) < 3 and time.monotonic() < deadline:  # bounded in time and count
            msg = listener.recv_match(blocking=True, timeout=0.1)
            if msg is not None and msg.get_type() != "BAD_DATA":
                got[msg.get_type()] = msg
    finally:
        link.close()
        listener.close()
    heartbeat = got["HEARTBEAT"]
    assert heartbeat.get_srcSystem() == 1 and heartbeat.type == mav.MAV_TYPE_FIXED_WING
    assert heartbeat.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED
    assert got["SERVO_OUTPUT_RAW"].time_usec == 3_000_000
    ack = got["COMMAND_ACK"]
    assert (ack.result, ack.target_system, ack.target_component) == (
        mav.MAV_RESULT_DENIED,
        255,
        190,
    )
    assert link.sent == {"HEARTBEAT": 1, "SERVO_OUTPUT_RAW": 1, "COMMAND_ACK": 1}
    assert list(link.sent_log) == [(2.0, "SERVO_OUTPUT_RAW"), (3.0, "COMMAND_ACK")]  # keep=2
