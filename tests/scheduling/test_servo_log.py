"""What the scheduler logs about its servos: flapping rate-limited, slow servos named once.

The pure rules (:mod:`mavservo.scheduling.outage_log`) under a fake clock, then the threaded
scheduler on python-can ``virtual`` with simulated servos that lose or delay their replies (the
trial: 8-29 ``offline (no reply)`` lines in 6-8 s and no recovery line; a servo answering 80 ms
late read as losing most replies with nothing in the log saying the timeout was too short).
"""

from __future__ import annotations

import logging
import uuid

import can
import pytest

from mavservo.scheduling.outage_log import LateReplies, OnlineLog
from mavservo.scheduling.runner import Scheduler, ServoSpec, TimingConfig
from mavservo.servos import Fault, RmdX, ServoState
from mavservo.sim.servo import Faults, SimServo
from mavservo.sim.virtual import VirtualServoBus
from tests.support.waiting import wait_until

FAST = TimingConfig(command_period_s=0.02, telemetry_period_s=0.03, reply_timeout_s=0.05)
WAIT_LIMIT_S = 10.0


def texts(lines: list[tuple[int, str]], level: int | None = None) -> list[str]:
    return [text for lvl, text in lines if level is None or lvl == level]


def test_the_first_offline_and_its_recovery_are_logged_and_repeats_summed_up_per_interval() -> None:
    log = OnlineLog(interval_s=10.0)
    assert texts(log.offline("a", "no reply", 0.0), logging.WARNING) == [
        "servo a offline (no reply)"
    ]
    assert texts(log.online("a", 0.5), logging.INFO) == ["servo a back online after 0.5 s"]
    for k in range(1, 8):  # flapping: counted, not logged
        assert log.offline("a", "no reply", k) == []
        assert log.online("a", k + 0.2) == []
    assert log.offline("a", "no reply", 8.0) == []
    assert log.flush(9.9) == []
    (summary,) = log.flush(10.0)
    assert summary[0] == logging.WARNING
    # the ground station's words and count (mavservo.records.repeats): still offline now
    assert summary[1] == "servo a offline (x9 in 10 s)"
    assert log.flush(25.0) == []  # nothing new to sum up
    # it was offline at the summary, so its recovery is logged
    assert texts(log.online("a", 30.0), logging.INFO) == ["servo a back online after 22.0 s"]


def test_servos_are_rate_limited_independently_and_a_quiet_servo_logs_every_outage() -> None:
    log = OnlineLog(interval_s=10.0)
    assert log.offline("a", "no reply", 0.0)
    assert log.offline("b", "sends failing", 0.1)  # another servo: its own first line
    log.online("a", 1.0)
    assert log.offline("a", "no reply", 2.0) == []
    log.online("a", 3.0)
    (summary,) = log.flush(10.0)
    # back online now: said first, at INFO, with the count of the outages
    assert summary == (logging.INFO, "servo a back online after 1.0 s (offline x2 in 10 s)")
    assert texts(log.offline("a", "no reply", 21.0)) == ["servo a offline (no reply)"]


def test_a_slow_servo_is_named_once_with_its_lateness_and_the_setting() -> None:
    late = LateReplies(reply_timeout_s=0.05, warn_after=3, ceiling_s=0.15)
    assert late.late("a", 0.081) == []
    assert late.late("a", None) == []  # not matched: counted, no latency
    assert late.late("b", 0.2) == []
    (line,) = late.late("a", 0.079)
    assert line[0] == logging.WARNING
    assert "servo a: 3 replies came after reply_timeout_s (50 ms)" in line[1]
    assert "typically 80 ms after the request (30 ms late)" in line[1]
    assert "scheduler.reply_timeout_s to 120 ms" in line[1]
    assert [late.late("a", 0.08) for _ in range(5)] == [[]] * 5  # once per servo


def test_late_replies_never_advise_an_unsafe_timeout_but_name_the_cause() -> None:
    """Issue 37: a loaded host made replies ~270 ms late and the warning advised a flight
    surface's bus to wait 401 ms; past the ceiling (100 ms) the advice is the cause instead."""
    late = LateReplies(reply_timeout_s=0.05, warn_after=3)
    for _ in range(2):
        assert late.late("aileron", 0.267) == []
    ((level, text),) = late.late("aileron", 0.268)
    assert level == logging.WARNING
    assert "typically 267 ms after the request" in text
    assert "raise scheduler.reply_timeout_s to" not in text
    assert "401" not in text
    assert "busy host or a congested bus" in text and "never above 100 ms" in text


def scheduler_records(caplog: pytest.LogCaptureFixture, level: int, *words: str) -> list[str]:
    return [
        r.getMessage()
        for r in caplog.records
        if r.name == "mavservo.scheduling.runner"
        and r.levelno == level
        and all(w in r.getMessage() for w in words)
    ]


def test_a_flapping_servo_logs_its_first_outage_and_recovery_once_not_every_flap(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO)
    channel = f"flap-{uuid.uuid4().hex}"
    sims = [SimServo("rmd-x", 1, faults=Faults(drop_reply_prob=0.7), seed=7)]
    went_offline: list[float] = []
    last: dict[str, ServoState] = {}

    def on_state(servo: str, state: ServoState) -> None:
        before = last.get(servo)
        if Fault.NO_REPLY in state.faults and (
            before is None or Fault.NO_REPLY not in before.faults
        ):
            went_offline.append(state.timestamp)
        last[servo] = state

    with VirtualServoBus(sims, channel=channel):
        bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        scheduler = Scheduler(bus, [ServoSpec("s1", RmdX(1))], FAST, name="bus0")
        scheduler.subscribe(on_state)
        try:
            with scheduler:
                assert scheduler.set_setpoint("s1", 5.0, "test").accepted
                assert wait_until(lambda: len(went_offline) >= 3, WAIT_LIMIT_S, interval=0.01)
                assert wait_until(lambda: scheduler.is_online("s1"), WAIT_LIMIT_S, interval=0.01)
        finally:
            bus.shutdown()

    assert len(scheduler_records(caplog, logging.WARNING, "servo s1 offline (no reply)")) == 1
    assert len(scheduler_records(caplog, logging.INFO, "servo s1 back online")) == 1


def test_a_servo_answering_after_its_timeout_gets_one_warning_naming_the_setting(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO)
    channel = f"slow-{uuid.uuid4().hex}"
    sims = [
        SimServo("rmd-x", 1, faults=Faults(reply_delay_s=0.08)),
        SimServo("rmd-x", 2),
    ]
    specs = [ServoSpec("slow", RmdX(1)), ServoSpec("quick", RmdX(2))]
    with VirtualServoBus(sims, channel=channel):
        bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        scheduler = Scheduler(bus, specs, FAST, name="bus0")
        try:
            with scheduler:
                assert wait_until(
                    lambda: scheduler.metrics()["servos"]["slow"]["frames"]["late"] >= 10,
                    WAIT_LIMIT_S,
                    interval=0.01,
                )
        finally:
            bus.shutdown()

    frames = scheduler.metrics()["servos"]["slow"]["frames"]
    # every late reply had timed out first; it is late, not also lost (the summary said both)
    assert frames["timed_out"] == frames["late"] + frames["lost"]
    assert frames["lost"] < frames["late"]
    (warning,) = scheduler_records(caplog, logging.WARNING, "reply_timeout_s")
    assert warning.startswith("scheduler bus0: servo slow: ")
    assert "(counted late, not lost)" in warning
    assert "(50 ms)" in warning and "ms late" in warning
    # the setting, advised up to its ceiling, or named with the cause past it (a loaded host
    # makes the 80 ms replies come hundreds of ms late)
    assert "scheduler.reply_timeout_s" in warning
