"""``servos[].health`` and the simulated faults in the YAML (issue 33): strict, FILE:LINE errors,
defaults derived from the servo's speed, slew, rates and physics, shown by ``mavservo check``."""

from __future__ import annotations

import io

import pytest

from mavservo.app.check import check_main
from mavservo.config import ConfigError, load_config_text
from mavservo.control.health_thresholds import health_limits
from tests.config.test_loader import LINE_FORMAT, MARK, _marked_line

SERVO = "servos:\n  - name: elevator\n    profile: rmd-x\n    can_id: 2\n"

BAD = {
    "a YAML boolean for a number": ("    health: {tolerance_deg: yes}  # <-", "tolerance_deg"),
    "an unknown key": ("    health: {tolerence_deg: 2}  # <-", "tolerence_deg"),
    "a negative time": ("    health: {jam_s: -1}  # <-", "jam_s"),
    "an unknown action": ("    health: {temperature_action: explode}  # <-", "temperature_action"),
    "warning above limit": (
        "    health: {temperature_warning_c: 90, temperature_limit_c: 80}  # <-",
        "below temperature_limit_c",
    ),
    "supply range reversed": ("    health: {supply_v: [28, 20]}  # <-", "min < max"),
    "an infinite current": ("    health: {current_limit_a: .inf}  # <-", "current_limit_a"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_a_bad_health_key_is_refused_at_its_line(case: str) -> None:
    line, words = BAD[case]
    text = SERVO + line + "\n"
    with pytest.raises(ConfigError) as info:
        load_config_text(text, "bad.yaml")
    message = str(info.value)
    match = LINE_FORMAT.match(message.splitlines()[0])
    assert match, message
    assert int(match["line"]) == _marked_line(text), message
    assert words in message


def test_an_unknown_simulated_fault_is_refused_at_its_line() -> None:
    text = SERVO + (
        f"simulation:\n  servos:\n    elevator:\n      faults: {{jamed_at_deg: 10}}  {MARK}\n"
    )
    with pytest.raises(ConfigError) as info:
        load_config_text(text, "bad.yaml")
    assert f"bad.yaml:{_marked_line(text)}:" in str(info.value)
    assert "jamed_at_deg" in str(info.value) and "jammed_at_deg" in str(info.value)


def test_the_new_simulated_faults_are_accepted() -> None:
    text = SERVO + (
        "simulation:\n  servos:\n    elevator:\n"
        "      faults: {jammed_at_deg: 10, slipping: true, supply_v: 18}\n"
    )
    config = load_config_text(text, "ok.yaml")
    assert config.simulated_settings(config.servos[0])[1] == {
        "jammed_at_deg": 10,
        "slipping": True,
        "supply_v": 18,
    }


def test_defaults_come_from_the_servo_its_slew_and_its_simulated_physics() -> None:
    text = """\
servos:
  - {name: elevator, profile: rmd-x, can_id: 2, max_speed_dps: 300, telemetry_hz: 10, bus: bus0}
  - {name: rudder, profile: rmd-x, can_id: 3, bus: real}
  - name: tuned
    profile: rmd-x
    can_id: 4
    bus: bus0
    health: {tolerance_deg: 5, jam_current_a: 1.5, temperature_action: slow, supply_v: [11, 13]}
channels:
  - {servo: elevator, source: servo_output, channel: 2, max_slew_dps: 120}
can:
  buses:
    - {name: bus0, channel: sim}
    - {name: real, channel: /dev/ttyUSB0}
simulation:
  servos:
    elevator:
      physics: {stall_current_a: 6.0, over_temperature_c: 100, voltage_v: 12.0}
"""
    limits = health_limits(load_config_text(text, "ok.yaml"))
    elevator, rudder, tuned = limits["elevator"], limits["rudder"], limits["tuned"]
    assert elevator.speed_dps == 120.0  # the slew is slower than the speed limit
    assert elevator.jam_current_a == pytest.approx(0.7 * 6.0)
    assert elevator.continuous_current_a == pytest.approx(3.0)
    assert (elevator.temperature_warning_c, elevator.temperature_limit_c) == (85.0, 95.0)
    assert (elevator.supply_min_v, elevator.supply_max_v) == pytest.approx((10.2, 13.8))
    # two telemetry periods and two command periods are in the response time
    assert elevator.response_s > 2 / 10 + 2 * 0.05
    assert rudder.speed_dps == 360.0
    assert (rudder.supply_min_v, rudder.supply_max_v) == (None, None)  # learned on hardware
    assert tuned.tolerance_deg == 5.0 and tuned.jam_current_a == 1.5
    assert tuned.temperature_action == "slow"
    assert (tuned.supply_min_v, tuned.supply_max_v) == (11.0, 13.0)


def test_check_shows_the_thresholds_in_force(tmp_path) -> None:
    path = tmp_path / "ok.yaml"
    path.write_text(
        SERVO
        + "    health: {jam_current_a: 1.5, temperature_action: hold, supply_v: [11, 13]}\n"
        + "  - {name: rudder, profile: rmd-x, can_id: 3, health: {enabled: false}}\n"
    )
    out = io.StringIO()
    assert check_main([str(path)], out=out, err=io.StringIO()) == 0
    text = out.getvalue()
    section = text[text.index("health checks") :]
    assert "elevator: tracking > 3 deg" in section
    assert ">= 1.5 A for 0.3 s" in section
    assert "limit 75 C (hold)" in section
    assert "supply: 11.0-13.0 V" in section
    assert "rudder: health checks off" in section
    assert "_hlt" in text


# ------------------------------------------------------------------ the temperature limit's action


def test_the_temperature_actions_slow_hold_and_release_in_the_backend() -> None:
    from mavservo.control.servo_backend import ServoBackend
    from mavservo.mavlink.backend import Outcome
    from tests.control.test_servo_backend import CONFIG, RecordingSink

    config = load_config_text(CONFIG, "backend.yaml")
    sink = RecordingSink()
    backend = ServoBackend(
        config, {s.name: sink for s in config.servos}, on_event=lambda _: None, slew_step_s=0.05
    )
    # slow: a 30 deg move of a 360 deg/s servo at half speed takes 30 / 180 s, in 0.05 s steps
    backend.set_health_action("surface", "slow", 0.0, slow_factor=0.5)
    assert backend.apply_servo_output(1, 1500, "test", 0.0).ok
    assert backend.apply_servo_output(1, 1900, "test", 0.05).ok
    assert sink.last("surface") == pytest.approx(9.0)  # 180 deg/s x 0.05 s
    for k in range(2, 6):
        backend.tick(0.05 * k)
    assert sink.last("surface") == pytest.approx(30.0)
    # hold: stays, refuses new setpoints with a reason; lifted, they go through again
    backend.set_health_action("surface", "hold", 0.3)
    result = backend.apply_servo_output(1, 1100, "test", 0.35)
    assert result.outcome is Outcome.TEMPORARILY_REJECTED and "overheated" in result.reason
    assert sink.last("surface") == pytest.approx(30.0)
    backend.set_health_action("surface", None, 0.4)
    assert backend.apply_servo_output(1, 1100, "test", 0.45).ok
    assert sink.last("surface") == pytest.approx(-30.0)
    # release: motor off, setpoints refused until lifted
    backend.set_health_action("hook", "release", 0.5)
    assert sink.released == ["hook"]
    assert backend.apply_servo_output(9, 1700, "test", 0.55).outcome is (
        Outcome.TEMPORARILY_REJECTED
    )
    assert backend.counters["refused_overheated"] == 2


def test_new_limits_from_a_parameter_take_effect() -> None:
    from mavservo.control.health import HealthLimits, Sample
    from mavservo.control.health_watch import HealthWatch

    watch = HealthWatch({"a": HealthLimits(supply_min_v=20.0, supply_max_v=28.0)})
    health = watch.servos["a"]
    watch.reconfigure({"a": HealthLimits(supply_min_v=10.0, supply_max_v=14.0, supply_s=0.0)})
    assert health.supply_range == (10.0, 14.0)
    assert health.update(Sample(1.0, 0.0, 0.0, 0.0, 0.1, 30.0, 12.0)) == []
    assert [e.name for e in health.update(Sample(1.1, 0.0, 0.0, 0.0, 0.1, 30.0, 24.0))] == [
        "supply"
    ]


@pytest.mark.parametrize(
    ("faults", "words"),
    [
        ("{jammed_at_deg: yes}", "expected a number"),
        ('{supply_v: "18"}', "expected a number"),
        ("{slipping: 1}", "expected true or false"),
        ("{jammed_at_deg: .nan}", "finite"),
    ],
)
def test_a_simulated_fault_of_the_wrong_type_is_refused_at_its_line(
    faults: str, words: str
) -> None:
    text = SERVO + f"simulation:\n  servos:\n    elevator:\n      faults: {faults}  {MARK}\n"
    with pytest.raises(ConfigError) as info:
        load_config_text(text, "bad.yaml")
    assert f"bad.yaml:{_marked_line(text)}:" in str(info.value)
    assert words in str(info.value)
