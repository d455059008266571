"""``check``'s words are a YAML user's, not Python's (issue 37, the smaller items): the profile
listing says "one of: a, b", "text, optional", "true or false"; an unknown profile gets a
did-you-mean; a CAN frame id written as ``can_id`` is named as one; ``params`` lists the gimbal
telemetry rate only for a config with a gimbal."""

from __future__ import annotations

import re

import pytest

from mavservo.app.check import profiles_listing
from mavservo.config import ConfigError, load_config_text, parameter_table

GIMBAL = """
servos:
  - {name: pan, profile: rmd-x, can_id: 1}
gimbals:
  - {name: g, yaw: pan}
"""


def test_the_profile_listing_has_no_python_types() -> None:
    listing = profiles_listing()
    for python in ("Literal", "None", "str |", "| None", "allowed bool", "dict", "default '"):
        assert python not in listing, python
    assert re.search(r"^    model: one of: MF, MG, MS; default MF - ", listing, re.M)
    assert re.search(r"^    brake: true or false; default false - ", listing, re.M)
    assert re.search(
        r"^    multi_turn_poll_every: 1\.\.1000, optional; default null - ", listing, re.M
    )
    assert re.search(r"^    unique_id: text, optional; default null - ", listing, re.M)
    assert re.search(r"^    reply_bytes: one of: 6, 8; default 8 - ", listing, re.M)


@pytest.mark.parametrize(
    ("written", "meant"), [("rmdx", "rmd-x"), ("RMD_X", "rmd-x"), ("odrv", "odrive")]
)
def test_an_unknown_profile_gets_a_did_you_mean(written: str, meant: str) -> None:
    with pytest.raises(ConfigError) as caught:
        load_config_text(f"servos: [{{name: a, profile: {written}, can_id: 1}}]\n", "p.yaml")
    assert f"unknown servo profile {written!r} (did you mean {meant!r}?)" in str(caught.value)


def test_a_frame_id_written_as_can_id_is_named_with_what_to_write() -> None:
    with pytest.raises(ConfigError) as caught:
        load_config_text(
            "servos:\n  - {name: a, profile: rmd-x, can_id: 0x141}\n"
            "  - {name: b, profile: lk, can_id: 0x145}\n"
            "  - {name: c, profile: rmd-x, can_id: 40}\n",
            "ids.yaml",
        )
    text = str(caught.value)
    assert (
        "ids.yaml:2: servos[0].can_id: rmd-x servo ids are 1..32, got 321 (0x141): that is the "
        "command frame id of rmd-x servo 1 on the bus, not a servo id; write `can_id: 1`"
    ) in text
    assert "lk servo 5 on the bus, not a servo id; write `can_id: 5`" in text
    assert "ids.yaml:4: servos[2].can_id: rmd-x servo ids are 1..32, got 40\n" in text + "\n"
    assert " a rmd-x" not in text


def test_the_gimbal_rate_parameter_only_with_a_gimbal() -> None:
    plain = load_config_text("servos: [{name: a, profile: rmd-x, can_id: 1}]\n")
    names = {p.name for p in parameter_table(plain)}
    assert "TEL_NVF_HZ" in names and "TEL_GAS_HZ" not in names
    assert "TEL_GAS_HZ" in {p.name for p in parameter_table(load_config_text(GIMBAL))}


def test_params_lists_what_the_table_has(tmp_path, capsys) -> None:
    from mavservo.app import params_command

    path = tmp_path / "plain.yaml"
    path.write_text("servos: [{name: a, profile: rmd-x, can_id: 1}]\n")
    assert params_command.main([str(path)]) == 0
    out = capsys.readouterr().out
    assert "TEL_NVF_HZ" in out and "TEL_GAS_HZ" not in out
