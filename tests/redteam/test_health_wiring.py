"""Red-team findings on the health monitor's wiring (review of issue 33): each test failed on
main 00d11a1 and passes with its fix."""

from __future__ import annotations

import math

import pytest

from mavservo.config import load_config_text
from mavservo.control.health import Health, HealthLimits, Sample, ServoHealth
from mavservo.control.servo_backend import ServoBackend
from tests.control.test_servo_backend import CONFIG, RecordingSink


def test_an_overheated_servo_on_hold_is_not_moved_by_a_new_trim() -> None:
    """``temperature_action: hold`` refuses new setpoints, but a PARAM_SET of the channel's trim
    (``reconfigure``) re-sent the servo where its last input maps now: from 15 to 18 deg, on a
    servo held for overheating."""
    config = load_config_text(CONFIG, "backend.yaml")
    sink = RecordingSink()
    backend = ServoBackend(
        config, {s.name: sink for s in config.servos}, on_event=lambda _: None, slew_step_s=0.05
    )
    assert backend.apply_servo_output(1, 1700, "test", 0.0).ok
    held = sink.last("surface")
    assert held == pytest.approx(15.0)
    backend.set_health_action("surface", "hold", 0.1)
    retrimmed = load_config_text(CONFIG.replace("trim: 1500}", "trim: 1400}", 1), "backend.yaml")
    sent = len(sink.sent)
    backend.reconfigure(retrimmed, 0.2)
    for k in range(3, 10):
        backend.tick(0.1 * k)
    assert sink.last("surface") == pytest.approx(held)
    assert not [a for s, a, _ in sink.sent[sent:] if s == "surface" and a != held]
    # lifted, the new trim applies to the next input as to any
    backend.set_health_action("surface", None, 1.0)
    assert backend.apply_servo_output(1, 1700, "test", 1.1).ok
    assert sink.last("surface") != pytest.approx(held)


def test_a_servo_slowed_for_its_temperature_is_not_called_late_for_the_slowed_move() -> None:
    """``temperature_action: slow`` slews the servo's moves to ``slow_factor`` of its speed;
    the tracking check kept judging them at the full speed and raised "not following" for a
    healthy 90 deg move made at the lowered speed (0.2 x 360 deg/s)."""
    limits = HealthLimits(
        speed_dps=360.0, response_s=0.5, temperature_action="slow", slow_factor=0.2
    )
    health = ServoHealth("elevator", limits)
    slowed = limits.speed_dps * limits.slow_factor
    events = []
    t = 0.0
    while t < 4.0:  # overheated at once (80 C over the 75 C limit), a 90 deg step at t = 1
        setpoint = 0.0 if t < 1.0 else 90.0
        position = 0.0 if t < 1.05 else min(90.0, slowed * (t - 1.05))
        moving = 0.0 < position < 90.0
        sample = Sample(t, setpoint, position, slowed if moving else 0.0, math.nan, 80.0)
        events += health.update(sample)
        t = round(t + 0.05, 10)
    assert [e.check for e in events] == [Health.HOT, Health.OVERHEATED]
    assert Health.TRACKING not in health.active


def test_temperature_release_is_refused_for_a_family_with_no_motor_off_frame() -> None:
    """``failsafe: release`` is refused where the profile has no motor-off frame; the health
    monitor's ``temperature_action: release`` was accepted there, and at the limit its text said
    "released (motor off)" while the generic DroneCAN servo kept holding (and heating)."""
    from mavservo.config import ConfigError

    text = """servos:
  - name: elevator
    profile: dronecan
    can_id: 20
    health: {temperature_action: release}
"""
    with pytest.raises(ConfigError, match="no motor-off frame"):
        load_config_text(text, "bad.yaml")
    # a family that has one (an ArduPilot peripheral's output: PWM 0) keeps the choice
    ok = text.replace(
        "can_id: 20\n", "can_id: 20\n    options: {firmware: ardupilot, command: pwm}\n"
    )
    assert load_config_text(ok, "ok.yaml").servos[0].health.temperature_action == "release"


def test_a_lying_reading_makes_no_giant_text() -> None:
    """A decoded float far out of any range (a lying float field: 1e38 deg, 1e38 A) was printed
    in full: a jammed text of about 100 digits, several STATUSTEXT chunks for one reply."""
    limits = HealthLimits(jam_s=0.0, jam_current_a=1.0, tolerance_deg=3.0)
    health = ServoHealth("elevator", limits)
    events = []
    for k in range(12):
        sample = Sample(0.1 * k, 10.0, -1e38, 0.0, 3e38, 25.0)
        events += health.update(sample)
    jammed = [e for e in events if e.check is Health.JAMMED and e.active]
    assert jammed, events
    assert len(jammed[0].text) < 100, jammed[0].text
    assert "1e+38" in jammed[0].text


def test_a_jam_clears_once_the_servo_is_released() -> None:
    """A jammed servo the crew (or failsafe) releases is told nothing any more: its jam stayed
    active for good (fault bit, gimbal MOTOR_ERROR), since the check needs a setpoint to judge;
    "not following" cleared in the same case."""
    health = ServoHealth("hook", HealthLimits(jam_s=0.3, clear_s=1.0, jam_current_a=2.0))
    events = []
    for k in range(30):  # told 20 deg, stuck at 0 at 2.5 A
        events += health.update(Sample(0.1 * k, 20.0, 0.0, 0.0, 2.5, 30.0))
    assert Health.JAMMED in health.active
    for k in range(30, 60):  # released: no setpoint, motor off
        events += health.update(Sample(0.1 * k, None, 0.0, 0.0, 0.0, 30.0))
    assert Health.JAMMED not in health.active
    assert [(e.check, e.active) for e in events if e.check is Health.JAMMED] == [
        (Health.JAMMED, True),
        (Health.JAMMED, False),
    ]


def test_a_learned_supply_range_allows_a_lithium_pack_discharging_in_flight() -> None:
    """A servo fed from a 4S pack, learned at take-off (16.8 V, full): a +-15 % band called
    14.2 V (3.55 V a cell, mid-flight) a supply fault; 12.4 V (3.1 V a cell) still is one."""
    health = ServoHealth("elevator", HealthLimits(supply_s=0.5, supply_learn_s=2.0))
    events = []
    t = 0.0
    for volts, seconds in ((16.8, 3.0), (15.6, 3.0), (14.2, 3.0), (13.3, 3.0)):
        for _ in range(int(seconds / 0.1)):
            events += health.update(Sample(t, 0.0, 0.0, 0.0, 0.5, 30.0, volts))
            t = round(t + 0.1, 10)
    assert events == [], events
    for _ in range(20):
        events += health.update(Sample(t, 0.0, 0.0, 0.0, 0.5, 30.0, 12.4))
        t = round(t + 0.1, 10)
    assert [(e.check, e.active) for e in events] == [(Health.SUPPLY, True)]


def test_the_bridges_event_list_is_bounded() -> None:
    """Every health transition is an event (console, event list); the list grew for the whole
    run, so a servo flickering across a threshold (or a lying one) grew the bridge's memory
    without bound: 50,000 transitions kept 50,000 entries."""
    from mavservo.app.bridge import Bridge
    from mavservo.app.bridge_events import EVENTS_KEPT

    config = load_config_text(CONFIG, "backend.yaml")
    bridge = Bridge(config, log_dir=False, status=lambda line: None)
    for n in range(50_000):
        bridge.notes.note(f"elevator: hot, 66 C (warning 65 C) #{n}")
    assert len(bridge.events) <= 2 * EVENTS_KEPT
    assert bridge.events[-1][1].endswith("#49999")
