"""One rule builds a simulated servo from the config, for the bridge and for ``mavservo sim``."""

from __future__ import annotations

from mavservo.config import load_config_text

CONFIG = """
servos:
  - {name: a, profile: rmd-x, can_id: 1, limits_deg: [10, 80], neutral_deg: 45}
  - {name: b, profile: rmd-x, can_id: 2}
  - {name: c, profile: rmd-x, can_id: 3}
simulation:
  servos:
    b: {physics: {initial_position_deg: -5}, faults: {silent: true}}
    default: {physics: {max_speed_dps: 90}}
"""


def test_simulated_settings_take_the_servo_s_own_then_default_and_start_inside_limits() -> None:
    config = load_config_text(CONFIG)
    physics, faults = config.simulated_settings(config.servo("a"))
    assert physics == {"max_speed_dps": 90, "initial_position_deg": 10} and faults == {}
    physics, faults = config.simulated_settings(config.servo("b"))
    assert physics == {"initial_position_deg": -5} and faults == {"silent": True}
    physics, _ = config.simulated_settings(config.servo("c"))
    assert physics["initial_position_deg"] == 0.0
