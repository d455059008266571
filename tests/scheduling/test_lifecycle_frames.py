"""Lifecycle frames (issue 18): the scheduler sends a profile's start-up, release and shutdown
frames as it sends commands, counts them in the budget, and `failsafe: release` really turns an
RMD-X off in the built-in simulation."""

from __future__ import annotations

from pathlib import Path

import can
import pytest

from mavservo.app.bridge import Bridge
from mavservo.config import load_config
from mavservo.scheduling.schedule_core import (
    STARTUP_RETRY_S,
    Decision,
    ScheduleCore,
    SendFailure,
    ServoSpec,
    TimingConfig,
)
from mavservo.servos import RmdX
from tests.support.waiting import wait_until

T_C = 0.05


def core_with(*specs: ServoSpec, **timing: float) -> ScheduleCore:
    return ScheduleCore(list(specs), TimingConfig(telemetry_period_s=10.0, **timing), start=100.0)


def run(core: ScheduleCore, now: float) -> Decision:
    decision = core.step(now)
    for out in decision.frames:
        core.sent(out, now)
    return decision


def run_answered(core: ScheduleCore, now: float) -> Decision:
    """One step whose frames are all answered at once (a servo that is there)."""
    decision = run(core, now)
    for out in decision.frames:
        for expectation in out.expectations:
            core.on_reply(out.servo, now + 0.001, key=expectation.key)
    return decision


def frames(decision: Decision) -> list[tuple[str, str, int]]:
    """(servo, kind, first data byte) of every frame of a step."""
    return [(out.servo, out.kind, out.msg.data[0]) for out in decision.frames]


class NeedsStartUp(RmdX):
    """An RMD-X whose replies keep saying 'disabled' (as a Damiao in status 0 would)."""

    def needs_startup(self) -> bool:
        return True


def test_startup_frame_goes_right_before_the_first_command_and_only_then() -> None:
    core = core_with(
        ServoSpec("s1", RmdX(1, comm_timeout_ms=300), telemetry_hz=0),
        ServoSpec("s2", RmdX(2), telemetry_hz=0),
    )
    run(core, 100.0)  # the first telemetry tick
    core.submit("s1", 5.0, "test", t=100.01)
    first = run(core, 100.0 + T_C)
    assert frames(first) == [("s1", "lifecycle", 0xB3), ("s1", "command", 0xA4)]
    assert bytes(first.frames[0].msg.data[4:]) == (300).to_bytes(4, "little")
    core.submit("s1", 6.0, "test", t=100.06)
    core.submit("s2", 1.0, "test", t=100.06)
    second = run(core, 100.0 + 2 * T_C)
    assert frames(second) == [
        ("s1", "command", 0xA4),
        ("s2", "lifecycle", 0xB3),
        ("s2", "command", 0xA4),
    ]


def test_the_echo_of_a_lifecycle_frame_is_expected_not_late_and_not_a_latency() -> None:
    core = core_with(ServoSpec("s1", RmdX(1), telemetry_hz=0))
    core.submit("s1", 5.0, "test", t=99.0)
    startup, command = run(core, 100.0).frames
    assert len(startup.expectations) == 1 and startup.expectations[0].key == 0xB3
    echo = core.on_reply("s1", 100.001, key=0xB3)
    assert echo.kind == "lifecycle" and echo.latency_s is None
    assert core.on_reply("s1", 100.002, key=0xA4).kind == "command"


def test_a_servo_back_online_is_started_up_again_before_its_next_command() -> None:
    core = core_with(ServoSpec("s1", RmdX(1), telemetry_hz=0), reply_timeout_s=0.01)
    core.submit("s1", 5.0, "test", t=99.0)
    assert frames(run(core, 100.0))[0] == ("s1", "lifecycle", 0xB3)
    now = 100.0
    while core.is_online("s1") and now < 102.0:  # no replies: it goes offline
        now += T_C
        run(core, now)
    assert not core.is_online("s1")
    core.on_reply("s1", now + 0.001, key=0xA4)  # it answers again (maybe after a power cycle)
    after = run(core, now + STARTUP_RETRY_S + T_C)
    assert [kind for _, kind, _ in frames(after)] == ["lifecycle", "refresh"]


def test_needs_startup_sends_the_startup_frames_again_at_most_once_per_retry_period() -> None:
    core = core_with(ServoSpec("s1", NeedsStartUp(1), telemetry_hz=0))
    core.submit("s1", 5.0, "test", t=99.0)
    startups = []
    for k in range(int(2.5 / T_C)):
        now = 100.0 + k * T_C
        startups += [now for _, kind, _ in frames(run(core, now)) if kind == "lifecycle"]
    assert startups == pytest.approx([100.0, 100.0 + STARTUP_RETRY_S, 100.0 + 2 * STARTUP_RETRY_S])


def test_release_sends_motor_off_at_the_next_step_and_the_next_command_starts_up_again() -> None:
    core = core_with(ServoSpec("s1", RmdX(1), telemetry_hz=0))
    core.submit("s1", 5.0, "test", t=99.0)
    run_answered(core, 100.0)
    core.release("s1")
    assert core.wants_lifecycle_wake()
    assert core.next_deadline(100.01) == pytest.approx(100.01)  # the runner is woken for it
    assert frames(run_answered(core, 100.01)) == [("s1", "lifecycle", 0x80)]
    assert not core.wants_lifecycle_wake()
    assert frames(run_answered(core, 100.0 + T_C)) == [], "released: no refresh"
    core.submit("s1", 6.0, "test", t=100.0 + STARTUP_RETRY_S + 0.01)
    again = run_answered(core, 100.0 + STARTUP_RETRY_S + T_C)
    assert frames(again) == [("s1", "lifecycle", 0xB3), ("s1", "command", 0xA4)]


def test_a_refused_startup_frame_is_not_a_miss_and_goes_again() -> None:
    core = core_with(ServoSpec("s1", RmdX(1), telemetry_hz=0))
    core.submit("s1", 5.0, "test", t=99.0)
    startup, command = core.step(100.0).frames
    failure = core.send_failed(startup)
    assert not failure.went_offline and failure.dropped is None
    core.sent(command, 100.0)
    core.on_reply("s1", 100.001, key=0xA4)
    later = run(core, 100.0 + STARTUP_RETRY_S + T_C)
    assert frames(later)[0] == ("s1", "lifecycle", 0xB3)


def test_final_frames_are_pending_releases_then_shutdown_frames() -> None:
    class WithShutdown(RmdX):
        def shutdown_frames(self) -> list[can.Message]:
            return self.release_frames()

    core = core_with(
        ServoSpec("s1", RmdX(1), telemetry_hz=0), ServoSpec("s2", WithShutdown(2), telemetry_hz=0)
    )
    core.release("s1")
    final = core.final_frames(100.0)
    assert [(o.servo, o.lifecycle, o.msg.data[0]) for o in final] == [
        ("s1", "release", 0x80),
        ("s2", "shutdown", 0x80),
    ]


def test_the_budget_counts_startup_frames_at_the_retry_rate() -> None:
    class Silent(RmdX):
        def startup_frames(self) -> list[can.Message]:
            return []

    with_startup = core_with(ServoSpec("s1", RmdX(1), telemetry_hz=0), max_load=1.0).worst_case_load
    without = core_with(ServoSpec("s1", Silent(1), telemetry_hz=0), max_load=1.0).worst_case_load
    frame_and_echo_bits = 2 * 135  # two standard 8-byte frames, worst-case stuffing
    expected = frame_and_echo_bits / STARTUP_RETRY_S / 1_000_000
    assert with_startup - without == pytest.approx(expected, rel=0.05)


CONFIG = """
mavlink: {url: sim}
can: {buses: [{name: bus0, interface: aa55, channel: sim}]}
servos:
  - {name: released, profile: rmd-x, can_id: 1, limits_deg: [-30, 30], failsafe: {action: release}}
  - {name: held, profile: rmd-x, can_id: 2, limits_deg: [-30, 30], failsafe: {action: hold}}
channels:
  - {servo: released, source: servo_output, channel: 1, output_deg: [-30, 30]}
  - {servo: held, source: servo_output, channel: 2, output_deg: [-30, 30]}
simulation: {autopilot: {profile: sweep}}
"""


def test_failsafe_release_turns_the_simulated_rmdx_motor_off(tmp_path: Path) -> None:
    path = tmp_path / "release.yaml"
    path.write_text(CONFIG)
    bridge = Bridge(load_config(path), log_dir=False, status=lambda line: None).start()
    try:
        servos = {servo.can_id: servo for servo in bridge.emulators["bus0"].servos}
        assert wait_until(lambda: servos[1].commands > 3 and servos[2].commands > 3)
        assert servos[1].enabled and servos[2].enabled
    finally:
        summary = bridge.stop()  # shutdown: every servo to its failsafe action at once
    assert not servos[1].enabled, "failsafe release: the simulated motor is off"
    assert servos[2].enabled, "failsafe hold: the motor stays on"
    assert summary["servos"]["released"]["frames"]["lifecycle"] >= 2  # 0xB3, then 0x80
    assert summary["servos"]["held"]["frames"]["lifecycle"] == 1  # 0xB3 only


def test_a_refused_release_goes_again_at_the_next_command_slot_not_in_a_tight_loop() -> None:
    core = core_with(ServoSpec("s1", RmdX(1), telemetry_hz=0))
    core.submit("s1", 5.0, "test", t=99.0)
    run_answered(core, 100.0)
    core.release("s1")
    (release,) = core.step(100.01).frames
    assert core.send_failed(release) == SendFailure(False, None)
    assert not core.wants_lifecycle_wake()
    assert core.next_deadline(100.011) > 100.02  # no tight retry loop
    assert core.step(100.02).frames == []
    assert frames(run_answered(core, 100.0 + T_C)) == [("s1", "lifecycle", 0x80)]


def test_a_split_start_up_sends_its_second_step_at_the_next_slot_once() -> None:
    """Robstride's start-up is two steps (set-up, then the enable alone, so that arbitration
    cannot put the enable first). The enable goes at the first command slot after the motor's
    answers and reports say it is set up, not a retry interval later: the motor would ignore a
    second of commands. Only one early step per start-up: a motor that still is not running
    gets the next start-up at the retry interval, as every family does."""
    from mavservo.servos import Robstride

    def report(mode: int, t: float) -> None:  # an active report (type 0x18) from motor 1
        msg = can.Message(
            arbitration_id=0x18 << 24 | mode << 22 | 1 << 8 | 0xFD,
            is_extended_id=True,
            data=bytes.fromhex("7fff7fff7fff00fa"),
        )
        assert profile.decode(msg, t) is not None

    profile = Robstride(1)
    profile.telemetry_hz = 20.0
    core = core_with(ServoSpec("hip", profile, telemetry_hz=20.0))
    run(core, 100.0)
    enable = (0x0300FD01, True)

    def lifecycle(decision: Decision) -> list[tuple[int, bool]]:
        return [
            (out.msg.arbitration_id, bool(out.msg.is_extended_id))
            for out in decision.frames
            if out.kind == "lifecycle"
        ]

    core.submit("hip", 5.0, "test", t=100.01)
    first = run(core, 100.0 + T_C)
    assert len(lifecycle(first)) == 6 and enable not in lifecycle(first)
    report(0, 100.0 + 1.2 * T_C)  # reset mode, no fault, reports coming
    report(0, 100.0 + 1.8 * T_C)
    core.submit("hip", 5.5, "test", t=100.0 + 1.9 * T_C)
    second = run(core, 100.0 + 2 * T_C)
    assert lifecycle(second) == [enable]  # one slot later, well inside STARTUP_RETRY_S
    report(0, 100.0 + 2.5 * T_C)  # still reset mode: the enable did not take
    report(0, 100.0 + 2.9 * T_C)
    for k in range(3, int(STARTUP_RETRY_S / T_C) + 2):  # slots up to the retry interval
        now = 100.0 + k * T_C
        core.submit("hip", 5.0 + k / 10, "test", t=now - 0.01)
        decision = run(core, now)
        if now - (100.0 + 2 * T_C) < STARTUP_RETRY_S:
            assert lifecycle(decision) == [], f"early start-up again at slot {k}"
        report(0, now + 0.4 * T_C)


def test_a_command_soon_after_a_release_goes_with_its_start_up() -> None:
    """A release within STARTUP_RETRY_S of the last start-up (a link lost for a short
    failsafe timeout, then back): the next command went without its start-up frames, so an
    LK motor (off after 0x80) ignored the A4 and a braked RMD-X (locked by 0x78) was driven
    against its brake, until a refresh a second later carried 0x88 / 0x77."""
    from mavservo.servos import get_profile

    lk = get_profile("lk")(1)
    braked = RmdX(2, brake=True)
    core = core_with(ServoSpec("lk", lk, telemetry_hz=0), ServoSpec("rmd", braked, telemetry_hz=0))
    core.submit("lk", 5.0, "test", t=99.0)
    core.submit("rmd", 5.0, "test", t=99.0)
    run_answered(core, 100.0)  # start-up (0x88 / 0x77) and the first commands
    core.release("lk")
    core.release("rmd")
    assert sorted(frames(run_answered(core, 100.01))) == [
        ("lk", "lifecycle", 0x80),
        ("rmd", "lifecycle", 0x78),
        ("rmd", "lifecycle", 0x80),
    ]
    core.submit("lk", 6.0, "test", t=100.2)  # well inside STARTUP_RETRY_S of 100.0
    core.submit("rmd", 6.0, "test", t=100.2)
    again = frames(run_answered(core, 100.0 + 5 * T_C))
    assert again == [
        ("lk", "lifecycle", 0x88),
        ("lk", "command", 0xA4),
        ("rmd", "lifecycle", 0xB3),  # its communication timeout, then the brake release
        ("rmd", "lifecycle", 0x77),
        ("rmd", "command", 0xA4),
    ], again
