"""``mavservo check`` says what each link gets for the configured autopilot (issue 38 item 5,
issue 39), and the autopilot keys are checked like every other key."""

from __future__ import annotations

import io
from pathlib import Path

import pytest

from mavservo.app.check import check_main
from mavservo.config import ConfigError, load_config_text
from tests.support.paths import REPO

SERVO = "servos: [{name: s, profile: rmd-x, can_id: 1}]\n"


def _check(path: Path) -> str:
    out, err = io.StringIO(), io.StringIO()
    assert check_main([str(path)], out, err) == 0, err.getvalue()
    return out.getvalue()


def test_check_prints_what_the_px4_link_gets_and_plans_without_esc_telemetry() -> None:
    text = _check(REPO / "config" / "px4-sitl.yaml")
    assert "what each link gets (autopilot: px4):" in text
    assert (
        "to PX4: sends ESC_INFO, ESC_STATUS, COMPONENT_METADATA; not ESC_TELEMETRY_x_TO_y" in text
    )
    assert "ESC_TELEMETRY: 0 Hz on the link" in text  # the budget gives it no share
    assert "to ArduPilot" not in text


def test_check_with_auto_lists_each_autopilot(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text("mavlink: {url: 'udpin:127.0.0.1:14600', autopilot: {link: router}}\n" + SERVO)
    text = _check(path)
    assert "mavlink.autopilot.link: router" in text
    assert (
        "to ArduPilot: sends ESC_TELEMETRY_x_TO_y, ESC_INFO, ESC_STATUS, COMPONENT_METADATA" in text
    )
    assert "to PX4: sends ESC_INFO, ESC_STATUS, COMPONENT_METADATA; not ESC_TELEMETRY" in text


def test_a_wrong_flavour_is_a_config_error_on_its_line() -> None:
    with pytest.raises(ConfigError) as info:
        load_config_text("mavlink:\n  autopilot: {flavour: px5}\n" + SERVO, "c.yaml")
    assert "c.yaml:2" in str(info.value) and "flavour" in str(info.value)
