"""ServoBackend: mapping per source, limits, slew stepping, offline servos, staggered failsafe.

The scheduler is replaced by a recording sink (the backend's only dependency below it), so the
clock is the test's and nothing sleeps. The whole chain with the real scheduler is exercised by
tests/e2e/.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from mavservo.config import load_config_text
from mavservo.control.servo_backend import ServoBackend
from mavservo.mavlink.backend import Outcome
from mavservo.servos.base import NO_FAULT, ServoState

CONFIG = """
mavlink: {url: "udpin:127.0.0.1:14599"}
can: {buses: [{name: bus0, interface: virtual, channel: t}]}
servos:
  - {name: surface, profile: rmd-x, can_id: 1, limits_deg: [-30, 30],
     failsafe: {action: neutral, timeout_s: 1.0}}
  - {name: throttle, profile: rmd-x, can_id: 2, limits_deg: [0, 90],
     failsafe: {action: position, position_deg: 5, timeout_s: 0.3}}
  - {name: hook, profile: rmd-x, can_id: 3, limits_deg: [-45, 45],
     failsafe: {action: release, timeout_s: 0.5}}
channels:
  - {servo: surface, source: servo_output, channel: 1, input: {min: 1100, max: 1900, trim: 1500},
     output_deg: [-30, 30]}
  - {servo: throttle, source: servo_output, channel: 3, input: {min: 1000, max: 2000},
     output_deg: [0, 90], max_slew_dps: 100}
  - {servo: throttle, source: actuator, index: 1, output_deg: [0, 90]}
  - {servo: hook, source: servo_output, channel: 9, input: {min: 1100, max: 1900, trim: 1500},
     output_deg: [-45, 45]}
"""


@dataclass
class RecordingSink:
    sent: list[tuple[str, float, str]] = field(default_factory=list)
    released: list[str] = field(default_factory=list)
    marked: list[str] = field(default_factory=list)
    offline: set[str] = field(default_factory=set)

    def set_setpoint(self, servo: str, angle_deg: float, source: str, t: float | None = None):
        self.sent.append((servo, angle_deg, source))
        return type("Result", (), {"accepted": True})()

    def release(self, servo: str) -> None:
        self.released.append(servo)

    def mark_failsafe(self, servo: str) -> None:
        self.marked.append(servo)

    def state(self, servo: str):
        return None

    def is_online(self, servo: str) -> bool:
        return servo not in self.offline

    def last(self, servo: str) -> float | None:
        angles = [a for s, a, _ in self.sent if s == servo]
        return angles[-1] if angles else None


@pytest.fixture
def setup() -> tuple[ServoBackend, RecordingSink]:
    config = load_config_text(CONFIG, "backend.yaml")
    sink = RecordingSink()
    backend = ServoBackend(config, {s.name: sink for s in config.servos}, on_event=lambda _: None)
    return backend, sink


def test_each_source_uses_its_own_input_range(setup) -> None:
    backend, sink = setup
    assert backend.apply_actuator(1, -1.0, "do_set_actuator", 0.0).ok
    assert sink.last("throttle") == pytest.approx(0.0)
    # PWM 2000 on channel 3 is the top of *its* range (a [-1, 1] range would deny it)
    assert backend.apply_servo_output(3, 2000, "servo_output_raw", 10.0).ok
    backend.tick(20.0)  # slew: plenty of time to get there
    assert sink.last("throttle") == pytest.approx(90.0)


def test_bad_and_unmapped_inputs_are_denied_and_nothing_is_sent(setup) -> None:
    backend, sink = setup
    assert (
        backend.apply_servo_output(1, float("nan"), "do_set_servo", 0.0).outcome is Outcome.DENIED
    )
    assert backend.apply_servo_output(1, 5000, "do_set_servo", 0.0).outcome is Outcome.DENIED
    assert backend.apply_servo_output(7, 1500, "do_set_servo", 0.0).outcome is Outcome.DENIED
    assert backend.apply_actuator(2, 0.5, "do_set_actuator", 0.0).outcome is Outcome.DENIED
    assert sink.sent == []
    assert backend.counters["rejected"] == 2


def test_offline_servo_is_temporarily_rejected(setup) -> None:
    backend, sink = setup
    sink.offline.add("surface")
    result = backend.apply_servo_output(1, 1700, "do_set_servo", 0.0)
    assert result.outcome is Outcome.TEMPORARILY_REJECTED and "surface" in result.reason
    assert sink.sent == []


def test_slew_limit_steps_toward_the_goal_on_each_tick(setup) -> None:
    backend, sink = setup
    backend.apply_servo_output(3, 1000, "servo_output_raw", 0.0)  # 0 deg, first: no limit
    backend.apply_servo_output(3, 2000, "servo_output_raw", 0.1)  # 90 deg asked, 100 deg/s
    assert sink.last("throttle") == pytest.approx(10.0)
    backend.tick(0.3)
    assert sink.last("throttle") == pytest.approx(30.0)
    backend.tick(2.0)
    assert sink.last("throttle") == pytest.approx(90.0)
    steps = [a for s, a, _ in sink.sent if s == "throttle"]
    assert all(b >= a for a, b in zip(steps, steps[1:], strict=False))


def test_gimbal_angles_are_clamped_to_the_servo_limits() -> None:
    config = load_config_text(CONFIG + "gimbals: [{name: g, pitch: surface}]\n", "backend.yaml")
    sink = RecordingSink()
    backend = ServoBackend(config, {s.name: sink for s in config.servos}, on_event=lambda _: None)
    assert backend.apply_gimbal("g", None, -90.0, None, "gimbal", 0.0).ok
    assert sink.last("surface") == pytest.approx(-30.0)
    assert backend.apply_gimbal("nope", 0, 0, 0, "gimbal", 0.0).outcome is Outcome.DENIED


def test_failsafe_actions_are_staggered_by_each_servos_timeout(setup) -> None:
    backend, sink = setup
    backend.apply_servo_output(1, 1900, "servo_output_raw", 0.0)
    backend.apply_servo_output(3, 2000, "servo_output_raw", 0.0)
    backend.tick(5.0)
    sink.sent.clear()
    backend.enter_failsafe("autopilot heartbeat lost", 10.0)
    assert sink.sent == [] and sink.released == []  # nobody is due yet
    backend.tick(10.35)  # throttle (0.3 s) is due: to 5 deg, slewing down at 100 deg/s
    assert [s for s, _, src in sink.sent if src == "failsafe"] == ["throttle"]
    backend.tick(10.6)  # hook (0.5 s): released
    assert sink.released == ["hook"]
    assert "surface" not in {s for s, _, _ in sink.sent}
    backend.tick(11.1)  # surface (1.0 s): neutral
    assert sink.last("surface") == pytest.approx(0.0)


def test_link_back_before_the_timeout_cancels_the_pending_actions(setup) -> None:
    backend, sink = setup
    backend.enter_failsafe("autopilot heartbeat lost", 0.0)
    backend.tick(0.4)  # throttle acted already
    backend.leave_failsafe(0.45)
    backend.tick(5.0)
    assert sink.released == []  # hook (0.5 s) was cancelled
    assert {s for s, _, src in sink.sent if src == "failsafe"} == {"throttle"}


def test_shutdown_failsafe_is_immediate_for_every_servo(setup) -> None:
    backend, sink = setup
    backend.failsafe_all("bridge shutting down", 0.0)
    assert sink.released == ["hook"]
    assert sink.last("surface") == pytest.approx(0.0)
    assert sink.last("throttle") == pytest.approx(5.0)


def test_health_hands_on_the_bridges_figures_as_a_copy() -> None:
    config = load_config_text(CONFIG, "backend.yaml")
    sink = RecordingSink()
    bridge_figures = {"bus0_load": 0.25, "lat_p50": 104.5, "rtt_p50": 3.0}
    backend = ServoBackend(
        config,
        {s.name: sink for s in config.servos},
        on_event=lambda _: None,
        health=lambda: bridge_figures,
    )
    health = backend.health()
    assert health == {"bus0_load": 0.25, "lat_p50": 104.5, "rtt_p50": 3.0}  # passed through
    health["bus0_load"] = 1.0
    assert bridge_figures == {"bus0_load": 0.25, "lat_p50": 104.5, "rtt_p50": 3.0}  # a copy


def test_health_without_the_bridges_figures_is_empty(setup) -> None:
    backend, _ = setup  # no bridge health
    assert backend.health() == {}


def test_a_slew_in_progress_is_abandoned_when_its_servo_goes_offline(setup) -> None:
    backend, sink = setup
    backend.apply_servo_output(3, 1000, "do_set_servo", 0.0)  # 0 deg
    backend.apply_servo_output(3, 2000, "do_set_servo", 0.1)  # 90 deg at 100 deg/s
    sink.offline.add("throttle")  # the adapter is unplugged mid-move
    sent_before = list(sink.sent)
    backend.tick(0.3)
    assert sink.sent == sent_before  # nothing queued for when it is back
    sink.offline.clear()
    backend.tick(5.0)
    assert sink.sent == sent_before  # the old move is not resumed seconds later
    assert backend.apply_servo_output(3, 1500, "do_set_servo", 5.1).ok  # a fresh one works
    assert sink.last("throttle") == pytest.approx(45.0)


def test_a_failsafe_move_waits_out_an_offline_servo_and_resumes_at_the_slew_rate(setup) -> None:
    backend, sink = setup
    backend.apply_servo_output(3, 2000, "servo_output_raw", 10.0)  # 90 deg, first: no limit
    backend.enter_failsafe("link lost", 10.0)
    backend.tick(10.4)  # throttle's failsafe (0.3 s): to 5 deg at 100 deg/s
    assert sink.last("throttle") == pytest.approx(50.0)
    sink.offline.add("throttle")
    count = len(sink.sent)
    backend.tick(10.5)
    assert len(sink.sent) == count
    sink.offline.clear()
    backend.tick(10.6)  # not a jump to 5 deg: one slew step from where it stopped
    assert sink.last("throttle") == pytest.approx(40.0)
    backend.tick(12.0)
    assert sink.last("throttle") == pytest.approx(5.0)  # the failsafe stays in force


def test_an_offline_servo_reports_no_measured_normalized_position(setup) -> None:
    backend, sink = setup
    state = ServoState(15.0, 0.0, 0.1, 30.0, NO_FAULT, 1.0)
    sink.state = lambda servo: state  # every servo last reported 15 deg
    surface = next(s for s in backend.servo_statuses() if s.name == "surface")
    assert surface.normalized == pytest.approx(0.5)
    sink.offline.add("surface")
    surface = next(s for s in backend.servo_statuses() if s.name == "surface")
    assert surface.normalized is None and not surface.online
    assert surface.state is state  # the last values stay readable (console, age)


def test_failsafe_hold_marks_the_setpoint_in_force_and_sends_nothing_new() -> None:
    """``hold`` keeps the command that was applied: no second position command (a command is
    applied once), only the mark that the bus now holds it as a failsafe (what a DroneCAN
    SafetyState plan reads)."""
    config = load_config_text(
        CONFIG.replace("failsafe: {action: neutral, timeout_s: 1.0}", "failsafe: {action: hold}"),
        "backend.yaml",
    )
    sink = RecordingSink()
    backend = ServoBackend(config, {s.name: sink for s in config.servos}, on_event=lambda _: None)
    backend.apply_servo_output(1, 1700, "servo_output_raw", 0.0)
    backend.tick(5.0)
    sent = list(sink.sent)
    backend.failsafe_all("bridge shutting down", 6.0)
    assert [s for s, _, _ in sink.sent[len(sent) :] if s == "surface"] == []
    assert sink.marked == ["surface"]
