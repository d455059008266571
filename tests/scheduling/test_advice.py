"""The advice part alone (scheduling/advice.py): once per servo, to the log and on_event."""

from __future__ import annotations

import logging

import can

from mavservo.scheduling.advice import ServoAdvice
from mavservo.scheduling.schedule_core import ServoSpec
from mavservo.servos import RmdX


class Advisable(RmdX):
    """An RMD-X that recognises frames with first byte 0xEE as its own in another protocol."""

    def diagnose(self, msg: can.Message) -> str | None:
        return "answers in another protocol" if msg.data[:1] == b"\xee" else None

    def silence_hint(self) -> str | None:
        return "check its id"


OTHER = can.Message(arbitration_id=0x7FF, data=b"\xee" + bytes(7), is_extended_id=False)
NOISE = can.Message(arbitration_id=0x7FF, data=bytes(8), is_extended_id=False)


def test_advice_goes_once_per_servo_to_the_log_and_on_event(caplog):
    advice = ServoAdvice("bus0", [ServoSpec("a", Advisable(1)), ServoSpec("plain", RmdX(2))])
    events: list[str] = []
    advice.on_event = events.append
    with caplog.at_level(logging.WARNING, logger="mavservo.scheduling.runner"):
        advice.diagnose(NOISE)
        advice.diagnose(OTHER)
        advice.diagnose(OTHER)
        advice.advise("a", "something else")
    assert events == ["servo a: answers in another protocol"]
    assert [r.getMessage() for r in caplog.records] == [
        "scheduler bus0: servo a: answers in another protocol"
    ]


def test_only_an_advising_profile_names_the_causes_of_silence():
    advice = ServoAdvice("bus0", [ServoSpec("a", Advisable(1)), ServoSpec("plain", RmdX(2))])
    assert advice.silence_hint("a") == "check its id"
    assert advice.silence_hint("plain") is None


def test_an_on_event_that_raises_is_logged_not_raised(caplog):
    advice = ServoAdvice("bus0", [ServoSpec("a", Advisable(1))])

    def broken(text: str) -> None:
        raise RuntimeError("console gone")

    advice.on_event = broken
    with caplog.at_level(logging.ERROR, logger="mavservo.scheduling.runner"):
        advice.announce("bus load 60 %")
    assert "scheduler bus0: on_event failed" in caplog.text
