"""MAV_CMD_DO_SET_ACTUATOR's param 7 means the same thing on both sides of the built-in demo.

The MAVLink spec defines param 7 as the "index of actuator set (i.e. if set to 1, Actuator 1
becomes Actuator 7)": set 0 carries actuators 1..6. The bridge maps ``source: actuator``
channels by that 1-based actuator number; the stream simulator's script names the set with
``set_index``. A new-user trial found the simulator sending the quick start's event as set 1 while
the bridge read it as actuators 7..12, so the payload servo never moved: these tests run the
scripted event through the real bridge, and check the shipped config's event addresses a mapped
actuator.
"""

from __future__ import annotations

import math

import pytest

from mavservo.app.bridge import Bridge
from mavservo.config import ConfigError, load_config, load_config_text
from mavservo.config.autopilot_script import SetActuator, parse_event
from tests.support.bridge import MAV_CMD_DO_SET_ACTUATOR, MAV_RESULT_ACCEPTED, Recorder
from tests.support.paths import REPO
from tests.support.waiting import wait_until

ACTUATOR_SET_SIZE = 6  # the spec: params 1..6 carry one set of six actuators

CONFIG = """
mavlink: {url: sim}
can: {buses: [{name: bus0, interface: aa55, channel: sim}]}
servos:
  - {name: payload, profile: rmd-x, can_id: 1, limits_deg: [0, 90], telemetry_hz: 10}
channels:
  - {servo: payload, source: actuator, index: 1, input: {min: -1, max: 1}, output_deg: [0, 90]}
simulation:
  autopilot:
    profile: hold
    script:
      - {at: 0.3, do_set_actuator: {values: [-0.5], set_index: 0}}
"""


def test_scripted_do_set_actuator_reaches_the_bridge_and_moves_the_mapped_servo() -> None:
    recorder = Recorder()
    config = load_config_text(CONFIG, "actuator.yaml")
    bridge = Bridge(config, log_dir=False, observers=[recorder], status=lambda _: None)
    bridge.start()
    try:
        stream = bridge.autopilot_sim
        servo = bridge.emulators["bus0"].servos[0]
        assert wait_until(lambda: stream.commands.idle and stream.commands.commands, 8.0)
        assert wait_until(lambda: abs(servo.position_deg - 22.5) < 0.5, 8.0), servo.position_deg
    finally:
        summary = bridge.stop()
    [record] = stream.commands.commands
    assert record.command == MAV_CMD_DO_SET_ACTUATOR and record.params[6] == 0.0
    assert record.result == MAV_RESULT_ACCEPTED and record.ack_from == (1, 140)
    # -0.5 on [-1, 1] -> [0, 90] deg is 22.5 deg, from the command, not from mirroring
    assert (22.5, "do_set_actuator") in recorder.setpoints["payload"]
    assert servo.target_deg == pytest.approx(22.5, abs=0.01)
    assert summary["mavlink"]["commands"].get("ignored_not_ours", 0) == 0


def test_set_index_is_param_7_of_the_spec_set_0_is_actuators_1_to_6() -> None:
    first = SetActuator((0.1, math.nan, -0.3))
    assert first.set_index == 0 and first.actuators() == {1: 0.1, 3: -0.3}
    second = SetActuator((0.5,), set_index=1)  # "if set to 1, Actuator 1 becomes Actuator 7"
    assert second.actuators() == {7: 0.5}
    with pytest.raises(ValueError, match="set_index"):
        SetActuator((0.5,), set_index=-1)


def test_the_old_group_key_is_an_error_that_says_what_to_write() -> None:
    with pytest.raises(ValueError, match="write 'set_index'.*0 = actuators 1..6"):
        parse_event({"at": 1, "do_set_actuator": {"values": [0.5], "group": 1}})


@pytest.mark.parametrize(
    ("event", "message"),
    [
        ({"do_set_actuator": {"values": [0.5], "set_indx": 0}}, r"unknown key\(s\) \['set_indx'\]"),
        ({"do_set_actuator": {"values": 0.5}}, "needs a list of up to 6 numbers"),
        ({"do_set_actuator": {"set_index": 0}}, r"missing \['values'\]"),
        ({"do_set_servo": {"channel": 9, "pwm": 1100, "pmw": 1}}, "allowed: channel, pwm"),
        ({"gimbal": {"pich": -30}}, "allowed: flags, pitch, roll, yaw"),
        ({"teleport": {}}, "known: do_set_servo"),
    ],
)
def test_script_typos_are_errors_naming_the_key(event: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        parse_event({"at": 1.0, **event})


def test_old_group_key_in_a_config_names_the_file_line_and_the_new_key(tmp_path) -> None:
    old = CONFIG.replace("set_index: 0", "group: 1")
    path = tmp_path / "old.yaml"
    path.write_text(old)
    with pytest.raises(ConfigError) as caught:
        load_config(path)
    text = str(caught.value)
    assert "old.yaml" in text and "set_index" in text
    line = next(i for i, row in enumerate(old.splitlines(), 1) if "script:" in row)
    assert f":{line}" in text or f":{line + 1}" in text, text


def test_the_quick_start_do_set_actuator_event_addresses_a_mapped_actuator() -> None:
    config = load_config(REPO / "config" / "sim.yaml")
    mapped = {c.index for c in config.channels if c.source == "actuator"}
    script = config.simulation.autopilot.script
    events = [e["do_set_actuator"] for e in script if "do_set_actuator" in e]
    assert events, "the quick start demonstrates DO_SET_ACTUATOR"
    for event in events:
        base = int(event.get("set_index", 0)) * ACTUATOR_SET_SIZE
        given = {base + i + 1 for i, v in enumerate(event["values"]) if v is not None}
        assert given and given <= mapped, (event, mapped)


def test_stream_cli_refuses_an_old_script_with_one_clear_line(tmp_path, capsys) -> None:
    from mavservo.sim.autopilot.sitl_command import main

    script = tmp_path / "old.yaml"
    script.write_text("- {at: 1.0, do_set_actuator: {values: [0.5], group: 1}}\n")
    url = "udpout:127.0.0.1:9"  # never opened: the script is checked first
    assert main(["stream", "--url", url, "--script", str(script), "--duration", "1"]) == 2
    err = capsys.readouterr().err
    assert "old.yaml" in err and "event 1" in err and "set_index: 0" in err
    assert "Traceback" not in err
