"""Parameters listed only where they can take effect (issue 30, item 4).

SRVn_TRIM, SRVn_REV and SRVn_SLEW act on the channels that drive a servo; a gimbal axis servo
has no channel, so every set of them was refused while ground stations listed them. They are
now left out of the table, the PARAM_REQUEST_LIST, and the metadata file for such servos.
"""

from __future__ import annotations

from mavservo.app.component_metadata import parameter_metadata
from mavservo.config import load_config_text
from mavservo.config.parameters import parameter_table
from tests.support.paths import TEST_DATA

CONFIG = """\
servos:
  - {name: aileron, profile: rmd-x, can_id: 1}
  - {name: pan, profile: rmd-x, can_id: 2}
  - {name: tilt, profile: rmd-x, can_id: 3}
channels:
  - {source: servo_output, channel: 1, servo: aileron}
gimbals:
  - {name: cam, component_id: 154, yaw: pan, pitch: tilt}
"""


def test_channel_parameters_only_for_servos_a_channel_drives() -> None:
    names = [p.name for p in parameter_table(load_config_text(CONFIG, "<test>"))]
    assert {"SRV1_TRIM", "SRV1_REV", "SRV1_SLEW"} <= set(names)
    for number in (2, 3):  # the gimbal's axes: their own limits and failsafe, no channel
        assert not {f"SRV{number}_TRIM", f"SRV{number}_REV", f"SRV{number}_SLEW"} & set(names)
        assert {f"SRV{number}_MIN", f"SRV{number}_MAX", f"SRV{number}_FS_ACT"} <= set(names)


def test_every_listed_parameter_can_be_set_to_its_own_value() -> None:
    """A parameter the bridge lists must accept at least the value it reports."""
    from mavservo.config.parameters import current_values, with_values

    config = load_config_text(CONFIG, "<test>")
    for name, value in current_values(config).items():
        with_values(config, {name: value})  # raises ParameterError if refused


def test_the_metadata_describes_the_same_list() -> None:
    config = load_config_text(CONFIG, "<test>")
    table = parameter_table(config)
    described = [p["name"] for p in parameter_metadata(table)["parameters"]]
    assert described == [p.name for p in table] and "SRV2_TRIM" not in described


def test_the_metadata_file_validates_against_mavlinks_parameter_schema() -> None:
    """``mavservo params --metadata`` and the FTP server write the same JSON; parameter.schema.json
    (tests/data/component_metadata) wants ``version`` 3 or more, which version 1 failed."""
    import json

    import jsonschema

    schema = json.loads((TEST_DATA / "component_metadata" / "parameter.schema.json").read_text())
    table = parameter_table(load_config_text(CONFIG, "<test>"))
    jsonschema.validate(parameter_metadata(table), schema)


def test_the_ranges_a_gcs_sees_are_what_a_set_accepts() -> None:
    """The metadata a ground station reads gave the limit and failsafe angles +-36,000 deg
    while a PARAM_SET past the file's limits was refused (review3): each angle parameter now
    ranges over the file's limits, and with the file as the envelope the edges are accepted
    and a step past them is refused, naming the file's limits."""
    import pytest

    from mavservo.config.parameters import ParameterError, with_values

    text = CONFIG.replace(
        "{name: aileron, profile: rmd-x, can_id: 1}",
        "{name: aileron, profile: rmd-x, can_id: 1, limits_deg: [-25, 35]}",
    ).replace("yaw: pan, pitch: tilt}", "yaw: pan, pitch: tilt, limits_deg: {yaw: [-80, 80]}}")
    config = load_config_text(text, "<test>")
    shown = {
        p["name"]: p for p in parameter_metadata(parameter_table(config, config))["parameters"]
    }
    for name in ("SRV1_MIN", "SRV1_MAX", "SRV1_FS_POS"):
        assert (shown[name]["min"], shown[name]["max"]) == (-25.0, 35.0), name
    assert (shown["GMB1_YAW_MIN"]["min"], shown["GMB1_YAW_MAX"]["max"]) == (-80.0, 80.0)
    narrowed = with_values(config, {"SRV1_MIN": -10.0}, envelope=config)
    assert (
        with_values(narrowed, {"SRV1_MIN": -25.0}, envelope=config).servos[0].limits_deg[0] == -25
    )
    with pytest.raises(ParameterError, match="outside -25..35 deg .the config file's limits"):
        with_values(narrowed, {"SRV1_MIN": -25.5}, envelope=config)
    with pytest.raises(ParameterError, match="outside -80..80 deg"):
        with_values(config, {"GMB1_YAW_MAX": 81.0}, envelope=config)
