"""Liveness of servos that push their status (finding 8), on the pure policy core.

Fake clock, no threads. A pushing servo (CubeMars AK: no telemetry requests) is alive while
its pushes come; silent for more than ``offline_after_missed`` push periods (plus one
``reply_timeout_s``) it is offline, whether or not it was ever commanded, through the same
``Decision.went_offline`` / ``dropped`` path as a polled servo; its next push brings it back
(a working send does not).
"""

from __future__ import annotations

import pytest

from mavservo.scheduling.schedule_core import Decision, ScheduleCore, ServoSpec, TimingConfig
from mavservo.servos import CubeMarsAK, RmdX

START = 100.0
T_C = 0.05
PUSH_HZ = 10.0
PUSH_PERIOD = 1 / PUSH_HZ
K = 3
TIMEOUT = 0.05
LIMIT = K * PUSH_PERIOD + TIMEOUT


def pusher(name: str = "cm", can_id: int = 1, hz: float | None = PUSH_HZ) -> ServoSpec:
    return ServoSpec(name, CubeMarsAK(can_id), telemetry_hz=hz)


def make_core(*specs: ServoSpec) -> ScheduleCore:
    timing = TimingConfig(offline_after_missed=K, reply_timeout_s=TIMEOUT)
    return ScheduleCore(list(specs), timing, start=START)


def run(core: ScheduleCore, start: float, end: float, *, pushes: bool) -> list[Decision]:
    """Step every command period from ``start`` to ``end``; frames are sent; the servo pushes
    every push period when ``pushes`` (and answers nothing else)."""
    decisions = []
    steps = round((end - start) / T_C)
    next_push = start
    for i in range(steps + 1):
        now = start + i * T_C
        if pushes and now >= next_push - 1e-9:
            for name in core.servo_names:
                core.on_reply(name, now)
            next_push += PUSH_PERIOD
        decision = core.step(now)
        for out in decision.frames:
            core.sent(out, now)
        decisions.append(decision)
    return decisions


def went_offline(decisions: list[Decision]) -> list[str]:
    return [name for d in decisions for name in d.went_offline]


def test_an_uncommanded_pushing_servo_goes_offline_when_its_pushes_stop() -> None:
    core = make_core(pusher())
    run(core, START, START + 1.0, pushes=True)
    assert core.is_online("cm")
    last_push = START + 1.0
    silent = run(core, START + 1.0 + T_C, START + 3.0, pushes=False)
    assert went_offline(silent) == ["cm"]  # once, not on every step
    first_offline = next(d for d in silent if d.went_offline)
    offline_at = START + 1.0 + T_C * (1 + silent.index(first_offline))
    # not before its silence limit, and within one step after it
    assert LIMIT < offline_at - last_push <= LIMIT + T_C + 1e-9
    assert not core.is_online("cm")


def test_a_pushing_servo_that_never_reported_goes_offline_from_the_start() -> None:
    core = make_core(pusher())
    decisions = run(core, START, START + 1.0, pushes=False)
    assert went_offline(decisions) == ["cm"]
    assert not core.is_online("cm")


def test_pushes_within_the_limit_keep_it_online_and_the_next_push_brings_it_back() -> None:
    core = make_core(pusher())
    run(core, START, START + 2.0, pushes=True)
    # a short gap, under k periods, is not an outage
    run(core, START + 2.0 + T_C, START + 2.0 + K * PUSH_PERIOD, pushes=False)
    assert core.is_online("cm")
    run(core, START + 2.5, START + 4.0, pushes=False)
    assert not core.is_online("cm")
    match = core.on_reply("cm", START + 4.02)
    assert match.back_online and core.is_online("cm")


def test_a_setpoint_not_yet_sent_is_dropped_when_the_pushes_stop() -> None:
    """The trial's gimbal servos: pushing, uncommanded, adapter unplugged; the first command in
    the outage was accepted. Now it is dropped unsent when the silence limit passes first."""
    core = make_core(pusher())
    run(core, START, START + 1.0, pushes=True)
    last_push = START + 1.0
    run(core, last_push + T_C, last_push + 6 * T_C, pushes=False)
    assert core.is_online("cm")  # 0.30 s silent, under the 0.35 s limit
    late = core.submit("cm", -51.0, "gimbal", last_push + 0.31)
    decision = core.step(last_push + 0.37)  # also serves the 0.35 slot, after the check
    assert decision.went_offline == ["cm"]
    assert [(name, sp.seq) for name, sp in decision.dropped] == [("cm", late.seq)]
    assert [out.kind for out in decision.frames] == []  # nothing goes out to it


def test_a_working_send_does_not_bring_a_silent_pushing_servo_back() -> None:
    core = make_core(pusher("cm", 1), ServoSpec("rmd", RmdX(1), telemetry_hz=0))
    core.submit("rmd", 5.0, "test", START)
    run(core, START, START + 1.0, pushes=False)
    assert not core.is_online("cm")
    decision = core.step(START + 1.05)
    for out in decision.frames:
        assert "cm" not in core.sent(out, START + 1.05)
    assert not core.is_online("cm")


def test_polled_servos_are_not_judged_by_pushes() -> None:
    core = make_core(ServoSpec("rmd", RmdX(1)))
    assert core.push_silence_limit_s("rmd") is None
    # polled and answering every request: online however long nothing is pushed
    for i in range(60):
        now = START + i * T_C
        decision = core.step(now)
        for out in decision.frames:
            core.sent(out, now)
            for expectation in out.expectations:
                core.on_reply("rmd", now + 0.001, expectation.key)
    assert core.is_online("rmd")


@pytest.mark.parametrize(("hz", "limit"), [(None, K * 0.09 + TIMEOUT), (50.0, K * 0.02 + TIMEOUT)])
def test_the_silence_limit_follows_the_push_rate(hz, limit) -> None:
    core = make_core(pusher(hz=hz))
    assert core.push_silence_limit_s("cm") == pytest.approx(limit)


def test_the_console_reads_waiting_until_the_first_report() -> None:
    from mavservo.app.console import status_line

    row = {
        "servo": "cm",
        "setpoint_deg": None,
        "position_deg": None,
        "velocity_dps": None,
        "current_a": None,
        "temperature_c": None,
        "faults": "",
        "online": True,
        "age_s": None,
    }
    assert " waiting " in status_line(row)
    assert " online " in status_line({**row, "age_s": 0.02, "position_deg": 1.0})
    assert " OFFLINE " in status_line({**row, "online": False})
