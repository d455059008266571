"""Ask the autopilot for the streams the bridge mirrors, and measure what actually arrives.

Why: an autopilot streams on a companion port only what its own parameters say. On current
ArduPilot the SERIAL1 stream rates are ``MAV2_*`` parameters (the old ``SR1_*`` names are
ignored) and their default gave SERVO_OUTPUT_RAW at 1 Hz, so a bridge that only listens moves
its servos once a second. The bridge therefore sends MAV_CMD_SET_MESSAGE_INTERVAL for each
mirrored message to the autopilot it follows (system/component as heard in its HEARTBEAT):

* when that autopilot is first heard, and again when it comes back after a heartbeat gap or
  reboots (its boot time goes backwards): a reboot forgets every SET_MESSAGE_INTERVAL;
* until it is ACKed (ACCEPTED), at most ``MAX_ATTEMPTS`` sends ``RETRY_S`` apart; a refusal
  (DENIED, UNSUPPORTED, ...) or silence is logged once and not retried until the next trigger.

Whatever was asked, the rate received is measured over ``WINDOW_S`` windows, reported in the
stats (summary, ``metrics.json``) and logged; a rate below what the servos need is a warning,
at most one line per ``WARN_INTERVAL_S``, and only while the autopilot is heard (an autopilot
that died sends nothing: advice about its stream rate would be wrong advice).

An accepted request whose rate stays low (under :data:`REASK_FRACTION` of the asked rate for a
whole window) is asked again, at most every :data:`REASK_INTERVAL_S`: behind a router several
bridges (and a ground station) set the same autopilot port's rate, and the last request wins,
so a second bridge asking 10 Hz drops the first one to 10 Hz until someone asks again.
PX4 (its HEARTBEAT says so, or ``mavlink.autopilot.flavour``) streams the gimbal setpoints
(GIMBAL_DEVICE_SET_ATTITUDE) at 5 Hz on its onboard link by default (``mavlink_main.cpp``,
MAVLINK_MODE_ONBOARD), which moved a hosted gimbal 30-205 ms after its command (PX4 SITL); with
gimbals hosted, that stream is asked for at the same rate as the outputs and measured and warned
about like them (:meth:`StreamRequester.set_flavour`). ArduPilot's mount driver sends them from
its own update, not as a stream: it is not asked.

Pure: no I/O, time comes in as an argument.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.mavlink.autopilot_flavour import ARDUPILOT, FlavourFacts
from mavservo.mavlink.commands import RateLimitedLog
from mavservo.mavlink.settings import StreamRequestSettings

log = logging.getLogger(__name__)

#: Seconds between sends of an unanswered request, and how many sends before giving up.
RETRY_S = 1.0
MAX_ATTEMPTS = 5
#: Length of one rate measurement window (s): long enough that a 1 Hz stream reads 1 Hz.
WINDOW_S = 5.0
#: At most one "rate too low" warning per message per this many seconds.
WARN_INTERVAL_S = 60.0
#: A boot time that goes back by more than this (s) means the autopilot rebooted.
REBOOT_BACKSTEP_S = 1.0
#: Restarts seen closer together than this (s) are counted, not acted on: on an unsigned link a
#: spoofer alternating boot times would otherwise make the bridge send a request every tick.
RESTART_HOLDOFF_S = 5.0
#: An accepted stream that arrives under this fraction of the asked rate is asked again ...
REASK_FRACTION = 0.8
#: ... at most this often (s), so a port that cannot deliver costs one command per interval.
REASK_INTERVAL_S = 15.0
#: The gimbal setpoints, asked of an autopilot that streams them (PX4).
GIMBAL_SETPOINT = "GIMBAL_DEVICE_SET_ATTITUDE"
#: SERVO_OUTPUT_RAW.time_usec is a uint32 of microseconds: it wraps every ~71.6 minutes.
UINT32_US_WRAP_S = 2**32 / 1e6

RESULT_NAMES = {
    mavlink2.MAV_RESULT_ACCEPTED: "accepted",
    mavlink2.MAV_RESULT_TEMPORARILY_REJECTED: "temporarily rejected",
    mavlink2.MAV_RESULT_DENIED: "denied",
    mavlink2.MAV_RESULT_UNSUPPORTED: "unsupported",
    mavlink2.MAV_RESULT_FAILED: "failed",
}


@dataclass
class _Stream:
    """One requested message: the request's state and the rate measurement."""

    name: str
    msg_id: int
    rate_hz: float
    min_hz: float
    attempts: int = 0
    next_send: float | None = None
    result: str = "not sent"
    window_start: float | None = None
    window_count: int = 0
    received_hz: float | None = None
    received: int = 0
    requests_sent: int = 0
    low_windows: int = 0
    reasks: int = 0
    last_reask: float | None = None
    verdict_due: float | None = None


class StreamRequester:
    """Decides when to send SET_MESSAGE_INTERVAL and measures the received rates."""

    def __init__(self, settings: StreamRequestSettings, heartbeat_timeout_s: float) -> None:
        self.settings = settings
        self.heartbeat_timeout_s = heartbeat_timeout_s
        self.streams = {
            name: _Stream(
                name=name,
                msg_id=_message_id(name),
                rate_hz=rate,
                min_hz=settings.min_hz.get(name, 0.0),
            )
            for name, rate in settings.rates_hz.items()
        }
        self.target: tuple[int, int] | None = None
        self.autopilot_restarts = 0
        self.restarts_ignored = 0
        self._last_restart: float | None = None
        self._last_heartbeat: float | None = None
        self._boot_time: dict[str, float] = {}
        self._warn = RateLimitedLog(WARN_INTERVAL_S)
        #: how to raise a rate on the autopilot in force (ArduPilot's until told otherwise)
        self._advice = ARDUPILOT.rate_advice
        self._autopilot_name = "autopilot"

    def set_flavour(self, facts: FlavourFacts, now: float) -> None:
        """The autopilot's flavour (px4: issue 39): its advice in the warnings, and the gimbal
        setpoints asked of it when it streams them (and gimbals are hosted)."""
        self._advice = facts.rate_advice
        self._autopilot_name = facts.name
        wanted = facts.streams_gimbal_setpoints and self.settings.gimbal_setpoint_hz > 0
        present = GIMBAL_SETPOINT in self.streams
        if wanted and not present:
            stream = _Stream(
                name=GIMBAL_SETPOINT,
                msg_id=_message_id(GIMBAL_SETPOINT),
                rate_hz=self.settings.gimbal_setpoint_hz,
                min_hz=self.settings.gimbal_setpoint_min_hz,
            )
            self.streams[GIMBAL_SETPOINT] = stream
            if self.target is not None:
                self._start(stream, now)
        elif present and not wanted:
            del self.streams[GIMBAL_SETPOINT]

    # ------------------------------------------------------------------ what the autopilot says

    def on_heartbeat(self, source: tuple[int, int], now: float) -> None:
        """A HEARTBEAT of the followed autopilot: first contact or back after a gap -> ask."""
        gap = None if self._last_heartbeat is None else now - self._last_heartbeat
        self._last_heartbeat = now
        if source != self.target:
            self.target = source
            self._start_requests(now, f"autopilot {source[0]}/{source[1]} heard")
        elif gap is not None and gap > self.heartbeat_timeout_s:
            self._restarted(now, f"autopilot back after {gap:.1f} s without a heartbeat")

    def on_message(self, msg: Any, now: float) -> None:
        """Any other message of the followed autopilot: count it, watch its boot time."""
        kind = msg.get_type()
        if self._boot_time_went_back(kind, msg):
            self._restarted(now, f"autopilot rebooted ({kind} boot time went back)")
        stream = self.streams.get(kind)
        if stream is not None:
            self._close_window(stream, now)  # a message on the boundary opens the next window
            stream.received += 1
            stream.window_count += 1

    def on_ack(self, command: int, result: int, now: float) -> None:
        """A COMMAND_ACK from the autopilot to us for SET_MESSAGE_INTERVAL.

        The ACK names the command, not the message: it is taken as the answer to the oldest
        request still waiting (requests go out one message at a time, in order)."""
        if command != mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL:
            return
        waiting = [s for s in self.streams.values() if s.result == "sent"]
        if not waiting:
            return
        stream = waiting[0]
        stream.result = RESULT_NAMES.get(result, f"result {result}")
        stream.next_send = None
        if result == mavlink2.MAV_RESULT_ACCEPTED:
            log.info("autopilot accepted %s at %g Hz", stream.name, stream.rate_hz)
        else:
            log.warning(
                "%s refused SET_MESSAGE_INTERVAL for %s (%s): it streams at the rate its "
                "settings give (%s); set mavlink.request_streams.enabled false to stop asking",
                self._autopilot_name,
                stream.name,
                stream.result,
                self._advice,
            )

    # ------------------------------------------------------------------ time

    def tick(self, now: float) -> list[tuple[int, int, int, int, int]]:
        """Requests due now, as (target system, target component, message id, interval us,
        confirmation); also closes rate windows (and warns)."""
        for stream in self.streams.values():
            self._close_window(stream, now)
            self._judge(stream, now)
        if not self.settings.enabled or self.target is None:
            return []
        out = []
        for stream in self.streams.values():
            if stream.next_send is None or now < stream.next_send:
                continue
            if any(s.result == "sent" for s in self.streams.values() if s is not stream):
                continue  # one request in flight at a time, so ACKs match requests
            if stream.attempts >= MAX_ATTEMPTS:
                stream.next_send = None
                stream.result = "no answer"
                log.warning(
                    "autopilot %d/%d did not answer SET_MESSAGE_INTERVAL for %s after %d tries",
                    *self.target,
                    stream.name,
                    MAX_ATTEMPTS,
                )
                continue
            interval_us = round(1e6 / stream.rate_hz)
            out.append((*self.target, stream.msg_id, interval_us, stream.attempts))
            stream.attempts += 1
            stream.requests_sent += 1
            stream.result = "sent"
            stream.next_send = now + RETRY_S
        return out

    def stats(self) -> dict[str, Any]:
        """Per message: asked and received rates, the autopilot's answer, counts."""
        streams = {
            s.name: {
                "requested_hz": s.rate_hz if self.settings.enabled else None,
                "needed_hz": s.min_hz,
                "received_hz": None if s.received_hz is None else round(s.received_hz, 2),
                "received": s.received,
                "requests_sent": s.requests_sent,
                "answer": s.result if self.settings.enabled else "disabled",
                "low_rate_windows": s.low_windows,
                "asked_again": s.reasks,
            }
            for s in self.streams.values()
        }
        return {
            "streams": streams,
            "autopilot_restarts": self.autopilot_restarts,
            "restarts_ignored": self.restarts_ignored,
        }

    # ------------------------------------------------------------------ internals

    def _restarted(self, now: float, why: str) -> None:
        """Ask again after a restart, unless the last restart was under RESTART_HOLDOFF_S ago."""
        if self._last_restart is not None and 0 <= now - self._last_restart < RESTART_HOLDOFF_S:
            self.restarts_ignored += 1
            return
        self._last_restart = now
        self.autopilot_restarts += 1
        self._start_requests(now, why)

    def _start_requests(self, now: float, why: str) -> None:
        """(Re)start every request and every rate window from now."""
        if self.settings.enabled and self.streams:
            log.info("asking for %s: %s", _rates_text(self.streams), why)
        for stream in self.streams.values():
            self._start(stream, now)

    def _start(self, stream: _Stream, now: float) -> None:
        """(Re)start one stream's request and rate window from now."""
        stream.attempts = 0
        stream.next_send = now if self.settings.enabled else None
        stream.result = "not sent"
        stream.window_start = now
        stream.window_count = 0
        stream.received_hz = None  # the rate of before the (re)start is not this one's
        stream.verdict_due = None

    def _autopilot_heard(self, now: float) -> bool:
        return (
            self._last_heartbeat is not None
            and now - self._last_heartbeat <= self.heartbeat_timeout_s
        )

    def _close_window(self, stream: _Stream, now: float) -> None:
        if stream.window_start is None or now - stream.window_start < WINDOW_S:
            return
        if not self._autopilot_heard(now):
            # gcs (issue 30): no rate, no advice about a silent autopilot; measure afresh
            stream.window_start, stream.window_count = now, 0
            return
        if (
            stream.result in ("sent", "not sent")
            and self.settings.enabled
            and stream.received_hz is None
        ):
            # still asking (after a start): a window that began before the answer would
            # under-read the rate; a re-ask of a measured stream goes on measuring
            stream.window_start, stream.window_count = now, 0
            return
        first = stream.received_hz is None
        stream.received_hz = stream.window_count / (now - stream.window_start)
        stream.window_start, stream.window_count = now, 0
        if first:
            log.info(
                "%s arrives at %.1f Hz (asked %s)",
                stream.name,
                stream.received_hz,
                f"{stream.rate_hz:g} Hz" if self.settings.enabled else "nothing: disabled",
            )
        if stream.received_hz < stream.min_hz:
            stream.low_windows += 1
        # the verdict waits one heartbeat timeout: a window cut short by the autopilot dying
        # reads low, and advice about its stream rate would then be wrong advice
        if stream.verdict_due is None:
            stream.verdict_due = now + self.heartbeat_timeout_s

    def _judge(self, stream: _Stream, now: float) -> None:
        """A low window's warning and re-ask, once it is clear the autopilot still talks."""
        if stream.verdict_due is None or now < stream.verdict_due:
            return
        stream.verdict_due = None
        if not self._autopilot_heard(now) or stream.received_hz is None:
            return
        if stream.received_hz < stream.min_hz:
            self._warn_low(stream, now)
        self._reask_if_low(stream, now)

    def _reask_if_low(self, stream: _Stream, now: float) -> None:
        """An accepted rate that did not stay: someone else (another bridge, a GCS) set the
        port lower after us. Ask again, at most every REASK_INTERVAL_S."""
        if not self.settings.enabled or stream.result != "accepted" or stream.received_hz is None:
            return
        if stream.received_hz >= REASK_FRACTION * stream.rate_hz:
            return
        if stream.last_reask is not None and now - stream.last_reask < REASK_INTERVAL_S:
            return
        stream.last_reask = now
        stream.reasks += 1
        stream.attempts = 0
        stream.next_send = now
        stream.result = "not sent"
        log.info(
            "asking again for %s at %g Hz: it arrives at %.1f Hz though the autopilot accepted; "
            "another component asked its port for another rate (with several bridges behind a "
            "router, ask the same rate on every bridge)",
            stream.name,
            stream.rate_hz,
            stream.received_hz,
        )

    def _warn_low(self, stream: _Stream, now: float) -> None:
        quiet = self._warn.quiet_since_last(stream.name, now)
        if quiet is None:
            return
        gimbal = stream.name == GIMBAL_SETPOINT
        log.warning(
            "%s arrives at %.1f Hz, below the %g Hz the %s need (asked %s, %s's answer: %s); "
            "%s move in steps. %s%s%s",
            stream.name,
            stream.received_hz,
            stream.min_hz,
            "gimbal servos" if gimbal else "servos",
            f"{stream.rate_hz:g} Hz" if self.settings.enabled else "nothing",
            self._autopilot_name,
            stream.result if self.settings.enabled else "disabled",
            "gimbal servos" if gimbal else "servos",
            self._advice,
            # PX4 streams no setpoints without a MAVLink gimbal (gimbal module, output_mavlink)
            " (none at all: PX4 needs MNT_MODE_OUT 2, MAVLink gimbal v2, and has to find the "
            "gimbal)"
            if gimbal and stream.received_hz == 0
            else "",
            f" ({quiet} low windows since the last line)" if quiet else "",
        )

    def _boot_time_went_back(self, kind: str, msg: Any) -> bool:
        """True when this message's boot time is more than a step behind the last one seen."""
        now_boot = boot_time_s(kind, msg)
        if now_boot is None:
            return False
        last = self._boot_time.get(kind)
        self._boot_time[kind] = now_boot
        if last is None or now_boot >= last - REBOOT_BACKSTEP_S:
            return False
        wrapped = kind == "SERVO_OUTPUT_RAW" and last > UINT32_US_WRAP_S - 60.0
        return not wrapped


def boot_time_s(kind: str, msg: Any) -> float | None:
    """The autopilot's time since boot carried by a message, in seconds, or None."""
    if kind in ("SERVO_OUTPUT_RAW", "ACTUATOR_OUTPUT_STATUS"):
        return float(msg.time_usec) / 1e6
    if kind in ("ATTITUDE", "SYSTEM_TIME"):
        return float(msg.time_boot_ms) / 1e3
    return None


def _message_id(name: str) -> int:
    msg_id = getattr(mavlink2, f"MAVLINK_MSG_ID_{name}", None)
    if msg_id is None:
        raise ValueError(f"unknown MAVLink message {name!r}")
    return int(msg_id)


def _rates_text(streams: Mapping[str, _Stream]) -> str:
    return ", ".join(f"{s.name} at {s.rate_hz:g} Hz" for s in streams.values())


def set_message_interval(
    target_system: int, target_component: int, msg_id: int, interval_us: int, confirmation: int
) -> Any:
    """The COMMAND_LONG that asks ``target`` to send ``msg_id`` every ``interval_us``."""
    return mavlink2.MAVLink_command_long_message(
        target_system,
        target_component,
        mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL,
        min(confirmation, 255),
        float(msg_id),
        float(interval_us),
        0,
        0,
        0,
        0,
        0,
    )
