"""The config is parsed once (issue 31, item 1): the schema validates a servo's options and a
bus's node options into their typed models when the file is loaded, and everything built from
it afterwards (the schedulers' servo specs, the bus nodes, the bus-load budget, the cross
checks, the MAVLink settings) uses those, never the mapping again; a PARAM_SET is one
validation of the whole config that takes the unchanged options over."""

from __future__ import annotations

import dataclasses
from collections import Counter
from pathlib import Path
from typing import Any

import can
import pytest
from pydantic import ValidationError

from mavservo.config import bus_loads, load_config
from mavservo.config.parameters import with_values
from mavservo.config.schema import Config, KeptOptions
from mavservo.config.semantic import cross_checks
from mavservo.config.views import mavlink_settings, servo_specs, telemetry_rates, timing_config
from mavservo.mavlink.settings import TelemetryRates
from mavservo.scheduling.runner import Scheduler
from mavservo.servos.dronecan.node import NodeOptions
from mavservo.servos.dronecan.profile import DroneCanOptions
from tests.support.paths import REPO

DRONECAN = REPO / "config" / "dronecan.yaml"


@pytest.fixture
def validations(monkeypatch: pytest.MonkeyPatch) -> Counter[str]:
    """How often each options model validates a mapping, by model name."""
    counts: Counter[str] = Counter()
    for model in (DroneCanOptions, NodeOptions):
        original = model.model_validate.__func__  # type: ignore[attr-defined]

        def counting(cls: Any, *args: Any, _original: Any = original, **kwargs: Any) -> Any:
            counts[cls.__name__] += 1
            return _original(cls, *args, **kwargs)

        monkeypatch.setattr(model, "model_validate", classmethod(counting))
    return counts


def _start_everything(config: Any) -> None:
    """What the bridge and ``check`` build from a loaded config, short of opening ports."""
    assert not cross_checks(config)
    bus_loads(config)
    for bus in config.can.buses:
        with can.Bus(interface="virtual", channel=f"views-{bus.name}") as vbus:
            Scheduler(
                vbus,
                servo_specs(config, bus.name),
                timing_config(config, bus),
                node_options=bus.node_options(),
            )
    mavlink_settings(config)


def test_options_are_validated_once_when_the_file_is_loaded(validations: Counter[str]) -> None:
    """Four DroneCAN servos and one bridge node: four options validations and one node
    options validation at load, none after (before: each servo's options again for every
    profile built, the node options in the budget, the checks and the scheduler)."""
    config = load_config(DRONECAN)
    loaded = Counter(validations)
    assert loaded == {"DroneCanOptions": len(config.servos), "NodeOptions": 1}
    _start_everything(config)
    assert validations == loaded


def test_a_parameter_set_is_one_validated_rebuild(
    validations: Counter[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """PARAM_SET: the config validated once more as a whole (its typed views with it), and the
    MAVLink side's rates read from the rebuilt config. The options no parameter writes are
    taken over, not validated again (before: 4 DroneCanOptions and 1 NodeOptions
    validations on this config for one TEL_NVF_HZ)."""
    config = load_config(DRONECAN)
    whole = _count_config_validations(monkeypatch)
    validations.clear()
    updated = with_values(config, {"TEL_NVF_HZ": 7.0})
    assert validations == {} and whole == {"Config": 1}
    assert mavlink_settings(updated).telemetry.named_value_float_hz == 7.0
    assert telemetry_rates(updated.mavlink.telemetry).named_value_float_hz == 7.0
    assert updated.servos[0].profile_options() is config.servos[0].profile_options()
    assert updated.can.buses[0].node_options() == config.can.buses[0].node_options()
    assert not validations and whole == {"Config": 1}


def test_a_rebuild_validates_options_that_differ_even_by_type_only(
    validations: Counter[str],
) -> None:
    """Only an identical options mapping is taken over: one whose value changed, or whose
    value has another type (1.0 for 1, which the strict options model refuses), is validated
    and refused as from the file."""
    config = load_config(DRONECAN)
    kept = KeptOptions(config).context()
    raw = config.model_dump()
    raw["servos"][1]["options"]["actuator_id"] = 9
    validations.clear()
    rebuilt = Config.model_validate(raw, context=kept)
    assert validations == {"DroneCanOptions": 1}
    assert rebuilt.servos[1].profile_options().actuator_id == 9
    assert rebuilt.servos[0].profile_options() is config.servos[0].profile_options()
    raw["servos"][1]["options"]["actuator_id"] = 2.0
    with pytest.raises(ValidationError, match="actuator_id"):
        Config.model_validate(raw, context=kept)
    raw["servos"][1]["options"]["actuator_id"] = 2
    raw["can"]["buses"][0]["node"]["dronecan"]["node_id"] = 300
    with pytest.raises(ValidationError, match="node_id"):
        Config.model_validate(raw, context=kept)


def test_a_live_parameter_set_is_one_walk_with_one_validation(
    validations: Counter[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The owner's whole walk of one PARAM_SET: one validation of the config, no options
    validated again, no parameter table rebuilt (before: 4 + 1 options validations and two
    tables), the rebuilt config handed once to where it takes effect."""
    from mavservo.config import parameters
    from mavservo.control.live_parameters import LiveParameters

    config = load_config(DRONECAN)
    applied: list[Config] = []

    class Target:
        def apply(self, updated: Config, now: float) -> None:
            applied.append(updated)

    owner = LiveParameters(config, base=config, overlay={}, saver=None, target=Target())
    whole = _count_config_validations(monkeypatch)
    tables = Counter[str]()
    table = parameters.parameter_table

    def counting_table(*args: Any, **kwargs: Any) -> Any:
        tables["parameter_table"] += 1
        return table(*args, **kwargs)

    monkeypatch.setattr(parameters, "parameter_table", counting_table)
    validations.clear()
    result = owner.set("TEL_NVF_HZ", 7.0, (255, 190))
    assert result.accepted and result.value == 7.0
    assert (validations, whole, tables) == ({}, {"Config": 1}, {})
    assert [c.mavlink.telemetry.named_value_float_hz for c in applied] == [7.0]
    assert owner.config is applied[0] and owner.value("TEL_NVF_HZ") == 7.0


def _count_config_validations(monkeypatch: pytest.MonkeyPatch) -> Counter[str]:
    counts: Counter[str] = Counter()
    original = Config.model_validate.__func__  # type: ignore[attr-defined]

    def counting(cls: Any, *args: Any, **kwargs: Any) -> Any:
        counts[cls.__name__] += 1
        return original(cls, *args, **kwargs)

    monkeypatch.setattr(Config, "model_validate", classmethod(counting))
    return counts


def test_the_servo_profile_carries_the_validated_options() -> None:
    config = load_config(DRONECAN)
    [spec, *_] = servo_specs(config, "bus0")
    options = config.servos[0].profile_options()
    assert isinstance(options, DroneCanOptions) and options.actuator_id == 1
    assert spec.profile.options is options
    assert spec.profile is not servo_specs(config, "bus0")[0].profile  # state is per scheduler
    assert config.can.buses[0].node_options()["dronecan"] == NodeOptions(
        node_id=100, name="org.mavservo.bridge"
    )


def test_the_telemetry_defaults_are_the_mavlink_sides(tmp_path: Path) -> None:
    """One set of telemetry defaults: a config without ``telemetry:`` gives the MAVLink
    side's own TelemetryRates (before: two classes with copied defaults)."""
    path = tmp_path / "c.yaml"
    path.write_text(
        "can: {buses: [{name: b, interface: virtual, channel: x}]}\n"
        "servos: [{name: s, profile: rmd-x, can_id: 1}]\n"
    )
    assert mavlink_settings(load_config(path)).telemetry == TelemetryRates()


def test_mavlink_settings_take_every_key_of_the_section(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text(
        "mavlink:\n"
        "  url: udpin:127.0.0.1:14600\n"
        "  system_id: 7\n"
        "  autopilot: {system: 3, component: 2, flavour: px4, link: router}\n"
        "  heartbeat_timeout_s: 3.5\n"
        "  allowed_sources: [{system: 255, component: 190}]\n"
        "  parameter_writers: anyone\n"
        "  act_on_autopilot_commands: true\n"
        "  repeat_servo_cycle: milliseconds\n"
        "  command_hold_s: 1.5\n"
        "  mirror: {servo_output_raw: false, actuator_output_status: true,"
        " actuator_output_status_units: normalized}\n"
        "  servo_output_port_width: 8\n"
        "  telemetry: {esc_first_index: 5, name_prefix: t, esc_telemetry_hz: 1}\n"
        "  request_streams: {rate_hz: 10}\n"
        "  servo_component_id: 141\n"
        "  monitor_outputs: ['udpout:127.0.0.1:14700']\n"
        "  link_budget_bytes_s: null\n"
        "  signing: {key: '" + "ab" * 32 + "', accept_unsigned: true}\n"
        "can: {buses: [{name: b, interface: virtual, channel: x}]}\n"
        "servos: [{name: s, profile: rmd-x, can_id: 1}]\n"
        "channels: [{servo: s, source: servo_output, channel: 3, input: {trim: 1520}}]\n"
        "scheduler: {command_period_s: 0.04, refresh_interval_s: 0.2}\n"
    )
    settings = mavlink_settings(load_config(path))
    assert settings.signing is not None and settings.signing.key == bytes([0xAB] * 32)
    assert settings.signing.accept_unsigned
    expected = {
        "url": "udpin:127.0.0.1:14600",
        "system_id": 7,
        "autopilot_system": 3,
        "autopilot_component": 2,
        "autopilot_flavour": "px4",
        "autopilot_link": "router",
        "heartbeat_timeout_s": 3.5,
        "allowed_sources": frozenset({(255, 190)}),
        "parameter_writers": "anyone",
        "act_on_autopilot_commands": True,
        "repeat_servo_cycle": "milliseconds",
        "command_hold_s": 1.5,
        "mirror_servo_output_raw": False,
        "mirror_actuator_output_status": True,
        "actuator_output_status_units": "normalized",
        "servo_output_port_width": 8,
        "telemetry": TelemetryRates(esc_first_index=5, name_prefix="t", esc_telemetry_hz=1.0),
        "servo_component_id": 141,
        "channel_trims_us": {3: 1520.0},
        "command_period_s": 0.04,
        "monitor_outputs": ("udpout:127.0.0.1:14700",),
        "link_budget_bytes_s": None,
    }
    got = dataclasses.asdict(settings)
    assert {key: getattr(settings, key) for key in expected} == expected
    assert got["stream_request"] == {
        "enabled": True,
        "rates_hz": {"ACTUATOR_OUTPUT_STATUS": 10.0},
        "min_hz": {"ACTUATOR_OUTPUT_STATUS": 7.5},
        "gimbal_setpoint_hz": 0.0,  # no gimbal in this config: none asked of PX4
        "gimbal_setpoint_min_hz": 0.0,
    }


def test_node_option_problems_are_each_on_their_own_line(tmp_path: Path) -> None:
    """Checked once by the family's NodeOptions, each problem at its key's line (before: all
    of them in one message on the ``node:`` line)."""
    from mavservo.config import ConfigError

    path = tmp_path / "c.yaml"
    path.write_text(
        "can:\n"
        "  buses:\n"
        "    - name: b\n"
        "      interface: virtual\n"
        "      channel: x\n"
        "      node:\n"
        "        dronecan:\n"
        "          node_id: 300\n"
        "          bogus: 1\n"
        "servos: [{name: s, profile: dronecan, can_id: 5, options: {actuator_id: 1}}]\n"
    )
    with pytest.raises(ConfigError) as err:
        load_config(path)
    text = str(err.value)
    assert ":8: can.buses[0].node.dronecan.node_id:" in text and "127" in text
    assert ":9: can.buses[0].node.dronecan.bogus:" in text


def test_a_copy_with_other_options_is_not_given_the_old_ones() -> None:
    """``model_copy(update=...)`` skips validation (the tests' helpers use it): a servo or bus
    copied with other options gets those, validated, never the originals' kept ones."""
    config = load_config(DRONECAN)
    servo, bus = config.servos[0], config.can.buses[0]
    copied = servo.model_copy(update={"options": {"actuator_id": 7}})
    assert copied.profile_options().actuator_id == 7
    assert servo.profile_options().actuator_id == 1
    assert servo.model_copy().profile_options() is servo.profile_options()  # kept, not redone
    moved = bus.model_copy(update={"node": {"dronecan": {"node_id": 42}}})
    assert moved.node_options()["dronecan"].node_id == 42
    assert bus.node_options()["dronecan"].node_id == 100
