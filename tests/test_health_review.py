"""Red-team findings on the health monitor's wiring (review of issue 33): each test failed on
main 00d11a1 and passes with its fix."""

from __future__ import annotations

import pytest
from test_servo_backend import CONFIG, RecordingSink

from mavservo.config import load_config_text
from mavservo.control.servo_backend import ServoBackend


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
