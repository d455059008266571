"""The bridge asks the autopilot for the streams it mirrors (issue 17, item 1).

Pure tests of :class:`StreamRequester` (no timing: time is an argument), the config keys, and an
end-to-end run over real UDP on 127.0.0.1 against the simulated autopilot set to ArduPlane's
SERIAL1 default of 1 Hz SERVO_OUTPUT_RAW: the bridge's request moves it to the configured rate,
and again after the autopilot reboots.
"""

from __future__ import annotations

import logging
from pathlib import Path
from types import SimpleNamespace

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from mavservo.app.console import format_summary
from mavservo.config.loader import ConfigError, load_config
from mavservo.config.views import mavlink_settings
from mavservo.mavlink.settings import MavlinkSettings, StreamRequestSettings
from mavservo.mavlink.side import MavlinkSide
from mavservo.mavlink.stream_request import (
    MAX_ATTEMPTS,
    REASK_INTERVAL_S,
    RESTART_HOLDOFF_S,
    RETRY_S,
    WINDOW_S,
    StreamRequester,
)
from mavservo.sim.autopilot.stream import ARDUPILOT_SERIAL1_SERVO_OUTPUT_HZ, AutopilotStream
from tests.support.mavlink_doubles import RecordingBackend
from tests.support.paths import TEST_DATA
from tests.support.waiting import free_udp_port, wait_until

SERVO_OUTPUT_RAW = mav.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW


def requester(enabled: bool = True, timeout_s: float = 2.0) -> StreamRequester:
    settings = StreamRequestSettings(
        enabled=enabled, rates_hz={"SERVO_OUTPUT_RAW": 20.0}, min_hz={"SERVO_OUTPUT_RAW": 15.0}
    )
    return StreamRequester(settings, heartbeat_timeout_s=timeout_s)


def servo_output(time_usec: int) -> SimpleNamespace:
    return SimpleNamespace(get_type=lambda: "SERVO_OUTPUT_RAW", time_usec=time_usec)


def feed(streams: StreamRequester, start: float, seconds: float, hz: float) -> float:
    """``hz`` SERVO_OUTPUT_RAW a second for ``seconds`` from ``start`` (boot time = t), with the
    autopilot's heartbeat every second; the requester ticks after every message. Returns the
    end time."""
    n = int(seconds * hz)
    for i in range(n):
        t = start + i / hz
        if i % max(1, round(hz)) == 0:  # the autopilot's 1 Hz heartbeat: it is heard
            streams.on_heartbeat((1, 1), t)
        streams.on_message(servo_output(int(t * 1e6)), t)
        if streams.tick(t):  # an autopilot that ACKs every request (and may still ignore it)
            streams.on_ack(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAV_RESULT_ACCEPTED, t)
    return start + n / hz


# ------------------------------------------------------------------ the request


def test_first_heartbeat_asks_that_autopilot_for_the_configured_rate() -> None:
    streams = requester()
    assert streams.tick(0.0) == []  # nobody heard yet: nobody to ask
    streams.on_heartbeat((7, 1), 0.0)
    assert streams.tick(0.0) == [(7, 1, SERVO_OUTPUT_RAW, 50_000, 0)]
    assert streams.tick(0.5) == []  # waiting for the answer
    assert streams.tick(RETRY_S) == [(7, 1, SERVO_OUTPUT_RAW, 50_000, 1)]  # retried, confirmation 1
    streams.on_ack(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAV_RESULT_ACCEPTED, 1.1)
    assert [streams.tick(t) for t in (2.0, 5.0, 30.0)] == [[], [], []]
    figures = streams.stats()["streams"]["SERVO_OUTPUT_RAW"]
    assert figures["answer"] == "accepted" and figures["requests_sent"] == 2


def test_an_autopilot_that_never_answers_is_asked_a_bounded_number_of_times(caplog) -> None:
    streams = requester()
    streams.on_heartbeat((1, 1), 0.0)
    sent = [r for i in range(50) for r in streams.tick(i * RETRY_S)]
    assert len(sent) == MAX_ATTEMPTS
    assert streams.stats()["streams"]["SERVO_OUTPUT_RAW"]["answer"] == "no answer"
    assert sum("did not answer" in r.message for r in caplog.records) == 1


def test_a_refusal_is_logged_once_and_not_retried(caplog) -> None:
    streams = requester()
    streams.on_heartbeat((1, 1), 0.0)
    streams.tick(0.0)
    with caplog.at_level(logging.WARNING):
        streams.on_ack(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAV_RESULT_DENIED, 0.1)
        streams.on_ack(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAV_RESULT_DENIED, 0.2)  # stray
    assert [r for i in range(10) for r in streams.tick(i * RETRY_S)] == []
    assert streams.stats()["streams"]["SERVO_OUTPUT_RAW"]["answer"] == "denied"
    assert sum("refused SET_MESSAGE_INTERVAL" in r.message for r in caplog.records) == 1


def test_acks_of_other_commands_do_not_answer_the_request() -> None:
    streams = requester()
    streams.on_heartbeat((1, 1), 0.0)
    streams.tick(0.0)
    streams.on_ack(mav.MAV_CMD_DO_SET_SERVO, mav.MAV_RESULT_ACCEPTED, 0.1)
    assert streams.stats()["streams"]["SERVO_OUTPUT_RAW"]["answer"] == "sent"


def test_asked_again_after_a_heartbeat_gap() -> None:
    streams = requester(timeout_s=2.0)
    streams.on_heartbeat((1, 1), 0.0)
    streams.tick(0.0)
    streams.on_ack(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAV_RESULT_ACCEPTED, 0.1)
    streams.on_heartbeat((1, 1), 1.0)  # in time: nothing to do
    assert streams.tick(1.0) == []
    streams.on_heartbeat((1, 1), 5.0)  # 4 s of silence: link back or autopilot restarted
    assert streams.tick(5.0) == [(1, 1, SERVO_OUTPUT_RAW, 50_000, 0)]
    assert streams.stats()["autopilot_restarts"] == 1


def test_asked_again_when_the_boot_time_goes_back_but_not_on_a_uint32_wrap() -> None:
    streams = requester()
    streams.on_heartbeat((1, 1), 0.0)
    streams.tick(0.0)
    streams.on_ack(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAV_RESULT_ACCEPTED, 0.1)
    streams.on_message(servo_output(2**32 - 1_000), 1.0)  # time_usec about to wrap
    streams.on_message(servo_output(40_000), 1.05)  # wrapped: still the same boot
    assert streams.tick(1.05) == []
    streams.on_message(servo_output(900_000_000), 2.0)
    streams.on_message(servo_output(1_000_000), 2.05)  # 900 s -> 1 s: rebooted
    assert streams.tick(2.05) == [(1, 1, SERVO_OUTPUT_RAW, 50_000, 0)]
    assert streams.stats()["autopilot_restarts"] == 1


def test_spoofed_boot_times_cannot_make_the_bridge_flood_the_autopilot_with_requests() -> None:
    # an unsigned link: someone sends SERVO_OUTPUT_RAW as 1/1 with boot times jumping back and
    # forth, 1,000 a second for 10 s
    streams = requester()
    streams.on_heartbeat((1, 1), 0.0)
    sent = streams.tick(0.0)
    for i in range(10_000):
        t = 0.001 * i
        streams.on_message(servo_output(900_000_000 if i % 2 else 1_000_000), t)
        sent += streams.tick(t)
    assert len(sent) <= 10 * MAX_ATTEMPTS  # at most one restart per RESTART_HOLDOFF_S
    assert streams.stats()["autopilot_restarts"] <= 10 / RESTART_HOLDOFF_S + 1
    assert streams.stats()["restarts_ignored"] > 4_000


# ------------------------------------------------------------------ the measurement


def test_received_rate_is_measured_and_a_low_rate_warned_once_a_minute(caplog) -> None:
    streams = requester()
    streams.on_heartbeat((1, 1), 0.0)
    streams.tick(0.0)
    streams.on_ack(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAV_RESULT_ACCEPTED, 0.0)
    with caplog.at_level(logging.INFO):
        end = feed(streams, 0.0, 4 * WINDOW_S, 1.0)  # autopilot ignores the request: 1 Hz
    figures = streams.stats()["streams"]["SERVO_OUTPUT_RAW"]
    assert figures["received_hz"] == pytest.approx(1.0, abs=0.21)
    assert figures["low_rate_windows"] >= 3
    warnings = [r.message for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "below the 15 Hz the servos need" in warnings[0]
    assert "MAVn_RC_CHAN" in warnings[0]
    feed(streams, end, 3 * WINDOW_S, 20.0)  # now as asked
    figures = streams.stats()["streams"]["SERVO_OUTPUT_RAW"]
    assert figures["received_hz"] == pytest.approx(20.0, rel=0.05)


def test_a_rate_that_falls_after_it_was_accepted_is_asked_again_at_a_bounded_pace(
    caplog,
) -> None:
    """Behind a router a second bridge asks the same port for 10 Hz and wins: the first one
    sees its accepted 20 Hz stay at 10 and asks again, at most every REASK_INTERVAL_S."""
    streams = requester()
    streams.on_heartbeat((1, 1), 0.0)
    streams.tick(0.0)
    streams.on_ack(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAV_RESULT_ACCEPTED, 0.0)
    end = feed(streams, 0.0, 2 * WINDOW_S, 20.0)
    assert streams.stats()["streams"]["SERVO_OUTPUT_RAW"]["asked_again"] == 0
    with caplog.at_level(logging.INFO):
        end = feed(streams, end, 6 * WINDOW_S, 10.0)  # 30 s at the other bridge's rate
    figures = streams.stats()["streams"]["SERVO_OUTPUT_RAW"]
    assert 1 <= figures["asked_again"] <= 30 / REASK_INTERVAL_S + 1
    assert figures["requests_sent"] == 1 + figures["asked_again"]
    assert any("ask the same rate on every bridge" in r.message for r in caplog.records)
    feed(streams, end, 4 * WINDOW_S, 20.0)  # the re-ask took: no more
    assert streams.stats()["streams"]["SERVO_OUTPUT_RAW"]["asked_again"] == figures["asked_again"]


def test_no_stream_rate_advice_once_the_autopilot_is_silent(caplog) -> None:
    """The autopilot died: nothing arrives, and that is not a stream-rate problem to advise
    about (the failsafe says what happened)."""
    streams = requester()
    streams.on_heartbeat((1, 1), 0.0)
    streams.tick(0.0)
    streams.on_ack(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAV_RESULT_ACCEPTED, 0.0)
    # it dies 3.5 s into a window, its last heartbeat 2 s before the window closes (still
    # "heard" then): that window reads low (14 Hz), and only the silence after explains it
    end = feed(streams, 0.0, 2 * WINDOW_S + 3.5, 20.0)
    with caplog.at_level(logging.INFO):
        for i in range(int(6 * WINDOW_S / 0.1)):  # 30 s of silence, the tick goes on
            streams.tick(end + i * 0.1)
    assert not any("arrives at" in r.message for r in caplog.records)
    assert streams.stats()["streams"]["SERVO_OUTPUT_RAW"]["asked_again"] == 0


def test_disabled_sends_nothing_but_still_measures_and_warns(caplog) -> None:
    streams = requester(enabled=False)
    streams.on_heartbeat((1, 1), 0.0)
    with caplog.at_level(logging.WARNING):
        feed(streams, 0.0, 3 * WINDOW_S, 1.0)
    assert streams.stats()["streams"]["SERVO_OUTPUT_RAW"]["requests_sent"] == 0
    assert streams.stats()["streams"]["SERVO_OUTPUT_RAW"]["answer"] == "disabled"
    assert any("below the 15 Hz" in r.message for r in caplog.records)


def test_summary_shows_requested_against_received() -> None:
    streams = requester()
    streams.on_heartbeat((1, 1), 0.0)
    streams.tick(0.0)
    streams.on_ack(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAV_RESULT_ACCEPTED, 0.0)
    feed(streams, 0.0, 2 * WINDOW_S, 20.0)
    text = format_summary({"mavlink": {"stream": streams.stats()}})
    assert "autopilot stream SERVO_OUTPUT_RAW: asked 20 Hz (accepted), received 20.0 Hz" in text
    off = requester(enabled=False)
    off.on_heartbeat((1, 1), 0.0)
    feed(off, 0.0, 3 * WINDOW_S, 1.0)
    text = format_summary({"mavlink": {"stream": off.stats()}})
    assert "SERVO_OUTPUT_RAW: asked nothing (disabled), received 1.0 Hz" in text
    assert "below the 15 Hz needed in 2 windows" in text


# ------------------------------------------------------------------ the config


def _config(tmp_path: Path, mavlink_extra: str, scheduler: str = "") -> Path:
    path = tmp_path / "c.yaml"
    path.write_text(
        "mavlink:\n  url: udpin:127.0.0.1:14551\n"
        + mavlink_extra
        + "can: {buses: [{name: b, interface: virtual, channel: x}]}\n"
        "servos: [{name: s, profile: rmd-x, can_id: 1}]\n"
        "channels: [{servo: s, source: servo_output, channel: 1}]\n" + scheduler
    )
    return path


def test_defaults_ask_for_the_command_rate_of_the_scheduler(tmp_path: Path) -> None:
    cfg = load_config(_config(tmp_path, "", "scheduler: {command_period_s: 0.04}\n"))
    settings = mavlink_settings(cfg).stream_request
    assert settings.enabled is True
    assert settings.rates_hz == {"SERVO_OUTPUT_RAW": pytest.approx(25.0)}
    assert settings.min_hz == {"SERVO_OUTPUT_RAW": pytest.approx(18.75)}


@pytest.mark.parametrize(
    ("extra", "scheduler", "words"),
    [
        ("  request_streams: {rate_hz: 0}\n", "", "greater than 0"),
        ("  request_streams: {enabled: yes_please}\n", "", "boolean"),
        ("  request_streams: {rate_hz: 10, min_rate_hz: 12}\n", "", "must be <= rate_hz"),
        ("  request_streams: {min_rate_hz: 30}\n", "", "above the requested rate 20 Hz"),
        ("  request_streams: {rate: 10}\n", "", "rate"),
    ],
)
def test_bad_request_streams_keys_are_refused_with_their_line(
    tmp_path: Path, extra: str, scheduler: str, words: str
) -> None:
    with pytest.raises(ConfigError) as err:
        load_config(_config(tmp_path, extra, scheduler))
    text = str(err.value)
    assert "request_streams" in text and words in text and ":3" in text


# ------------------------------------------------------------------ end to end over UDP


def _bridge(port: int, enabled: bool, heartbeat_timeout_s: float) -> MavlinkSide:
    settings = MavlinkSettings(
        url=f"udpin:127.0.0.1:{port}",
        heartbeat_timeout_s=heartbeat_timeout_s,
        command_period_s=0.05,
        stream_request=StreamRequestSettings.for_mirror(
            ("SERVO_OUTPUT_RAW",), 0.05, enabled=enabled
        ),
    )
    return MavlinkSide(settings, RecordingBackend())


def _requests_seen(ap: AutopilotStream) -> list:
    return [
        m
        for _, m in ap.received.messages("COMMAND_LONG")
        if m.command == mav.MAV_CMD_SET_MESSAGE_INTERVAL and m.get_srcComponent() == 140
    ]


@pytest.mark.timeout(60)
def test_bridge_moves_an_ardupilot_default_port_to_its_rate_and_again_after_reboot() -> None:
    port = free_udp_port()
    side = _bridge(port, enabled=True, heartbeat_timeout_s=1.0)
    ap = AutopilotStream(
        f"udpout:127.0.0.1:{port}", "hold", servo_output_rate_hz=ARDUPILOT_SERIAL1_SERVO_OUTPUT_HZ
    )
    with side:
        ap.start()
        try:
            assert ap.interval_s("SERVO_OUTPUT_RAW") == 1.0  # what ArduPlane gives unasked
            assert wait_until(lambda: ap.interval_s("SERVO_OUTPUT_RAW") == 0.05)
            first = _requests_seen(ap)[0]
            assert (first.target_system, first.target_component) == (1, 1)
            assert (first.param1, first.param2) == (SERVO_OUTPUT_RAW, 50_000)
            assert wait_until(
                lambda: (
                    side.stats()["stream"]["streams"]["SERVO_OUTPUT_RAW"]["answer"] == "accepted"
                )
            )
            ap.reboot(2.0)  # longer than the heartbeat timeout: forgets the request
            assert wait_until(lambda: ap.reboots == 1 and ap.interval_s("SERVO_OUTPUT_RAW") == 1.0)
            assert wait_until(lambda: ap.interval_s("SERVO_OUTPUT_RAW") == 0.05)
            assert side.stats()["stream"]["autopilot_restarts"] >= 1
        finally:
            ap.stop()


@pytest.mark.timeout(60)
def test_a_quick_reboot_is_seen_by_the_boot_time_going_back() -> None:
    port = free_udp_port()
    side = _bridge(port, enabled=True, heartbeat_timeout_s=5.0)  # no heartbeat gap to see
    ap = AutopilotStream(f"udpout:127.0.0.1:{port}", "hold", servo_output_rate_hz=1.0)
    with side:
        ap.start()
        try:
            assert wait_until(lambda: ap.interval_s("SERVO_OUTPUT_RAW") == 0.05)
            assert wait_until(lambda: len(_requests_seen(ap)) >= 1)
            # let the bridge see a few boot times before the reboot
            assert wait_until(
                lambda: side.stats()["stream"]["streams"]["SERVO_OUTPUT_RAW"]["received"] >= 5
            )
            ap.reboot(0.2)
            assert wait_until(lambda: ap.reboots == 1)
            assert wait_until(lambda: side.stats()["stream"]["autopilot_restarts"] == 1)
            assert wait_until(lambda: ap.interval_s("SERVO_OUTPUT_RAW") == 0.05)
        finally:
            ap.stop()


@pytest.mark.timeout(60)
def test_disabled_bridge_leaves_the_autopilot_rate_alone() -> None:
    port = free_udp_port()
    side = _bridge(port, enabled=False, heartbeat_timeout_s=1.0)
    ap = AutopilotStream(f"udpout:127.0.0.1:{port}", "hold", servo_output_rate_hz=1.0)
    with side:
        ap.start()
        try:
            assert wait_until(lambda: side.stats()["system_id"] == 1)
            assert wait_until(lambda: ap.received.count("HEARTBEAT") >= 2)  # the bridge talks
            assert _requests_seen(ap) == []
            assert ap.interval_s("SERVO_OUTPUT_RAW") == 1.0
        finally:
            ap.stop()


# ------------------------------------------------------------------ real ArduPlane traffic


def test_recorded_arduplane_link_reads_its_real_rate_and_no_false_reboot() -> None:
    """tests/data/plane-servos.tlog (real ArduPlane SITL SERIAL1, SERVO_OUTPUT_RAW at 20 Hz after
    another companion's request) fed to the pure core at its recorded times: the request goes to
    1/1, the recorded ACK (addressed to that other companion, 1/191) is not taken as ours, the
    measured rate is the recorded 20 Hz, and the real boot times never look like a reboot."""
    from pymavlink import mavutil

    from mavservo.mavlink.mavlink_core import MavlinkCore

    path = TEST_DATA / "plane-servos.tlog"
    log = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
    settings = MavlinkSettings(
        heartbeat_timeout_s=3.0,
        command_period_s=0.05,
        stream_request=StreamRequestSettings.for_mirror(("SERVO_OUTPUT_RAW",), 0.05),
    )
    core: MavlinkCore | None = None
    requests = []
    for _ in range(10_000):  # the file holds 4,462 messages
        msg = log.recv_match(blocking=False)
        if msg is None:
            break
        t = msg._timestamp
        if core is None:
            core = MavlinkCore(settings, RecordingBackend(), boot_time=t)
        core.on_message(msg, t)
        requests += [m for _, m in core.tick(t) if m.get_type() == "COMMAND_LONG"]
    assert core is not None
    stream = core.stats()["stream"]
    figures = stream["streams"]["SERVO_OUTPUT_RAW"]
    assert (requests[0].target_system, requests[0].target_component) == (1, 1)
    assert (requests[0].param1, requests[0].param2) == (SERVO_OUTPUT_RAW, 50_000)
    assert figures["answer"] == "no answer"  # the recorded ACK was for 1/191
    assert stream["autopilot_restarts"] == 0
    assert figures["received"] == 1785
    assert figures["received_hz"] == pytest.approx(20.0, abs=1.0)
    assert figures["low_rate_windows"] == 0
