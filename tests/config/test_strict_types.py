"""Config values YAML hands over with the wrong type, bad MAVLink URLs, and the error wording.

Each case here used to pass ``mavservo check`` (``max_speed_dps: yes`` ran a servo at 1 deg/s)
or failed only at run time without naming the key; now each is a ``FILE:LINE: key: message``.
"""

from __future__ import annotations

import io
import re
import textwrap
from pathlib import Path

import pytest

from mavservo.app.check import check_main
from mavservo.config import ConfigError, load_config_text
from mavservo.config.overrides import OverrideError, apply_overrides
from mavservo.config.urls import url_problem

SERVO = "servos:\n  - {name: a, profile: rmd-x, can_id: 1, limits_deg: [-30, 30]}\n"
LINE = re.compile(r"^(?P<file>[^:]+):(?P<line>\d+): (?P<path>[\w.\[\]]+): (?P<msg>.+)$")


def _problems(text: str) -> list[dict[str, str]]:
    with pytest.raises(ConfigError) as info:
        load_config_text(text, "bad.yaml")
    lines = str(info.value).splitlines()
    parsed = [LINE.match(line) for line in lines]
    assert all(parsed), lines
    return [m.groupdict() for m in parsed if m]


# ------------------------------------------------------------------ YAML booleans and strings

WRONG_TYPES = {
    # case: (text, line, key path, words the message must have)
    "max_speed_dps: yes": (
        "servos:\n  - {name: a, profile: rmd-x, can_id: 1, max_speed_dps: yes}\n",
        2,
        "servos[0].max_speed_dps",
        ("valid number", "found yes", "boolean"),
    ),
    "heartbeat_timeout_s: yes": (
        "mavlink:\n  heartbeat_timeout_s: yes\n" + SERVO,
        2,
        "mavlink.heartbeat_timeout_s",
        ("valid number", "found yes", "boolean"),
    ),
    "can_id: true": (
        "servos:\n  - {name: a, profile: rmd-x, can_id: true}\n",
        2,
        "servos[0].can_id",
        ("valid integer", "found true", "boolean"),
    ),
    "heartbeat_timeout_s: '3.0'": (
        "mavlink:\n  heartbeat_timeout_s: '3.0'\n" + SERVO,
        2,
        "mavlink.heartbeat_timeout_s",
        ("valid number", "'3.0'", "without quotes"),
    ),
    'tlog: "no"': (
        SERVO + 'logging:\n  tlog: "no"\n',
        4,
        "logging.tlog",
        ("valid boolean", "'no'", "true or false"),
    ),
    "limits_deg: [yes, 30]": (
        "servos:\n  - {name: a, profile: rmd-x, can_id: 1, limits_deg: [yes, 30]}\n",
        2,
        "servos[0].limits_deg[0]",
        ("valid number",),
    ),
    "channel: on (str | int)": (
        "can: {buses: [{name: b, interface: socketcan,\n  channel: on}]}\n" + SERVO,
        2,
        "can.buses[0].channel",
        ("valid string", "valid integer"),
    ),
}


@pytest.mark.parametrize("case", sorted(WRONG_TYPES))
def test_a_yaml_boolean_or_a_quoted_number_is_refused_with_its_line(case: str):
    text, line, path, words = WRONG_TYPES[case]
    problems = _problems(text)
    assert len(problems) == 1, problems
    problem = problems[0]
    assert (int(problem["line"]), problem["path"]) == (line, path)
    for word in words:
        assert word in problem["msg"], problem["msg"]


def test_integers_still_fill_float_fields_and_yaml_lists_still_fill_tuples():
    config = load_config_text(
        textwrap.dedent("""\
        mavlink: {heartbeat_timeout_s: 3}
        servos:
          - {name: a, profile: rmd-x, can_id: 1, max_speed_dps: 400, limits_deg: [-30, 30]}
        gimbals:
          - {name: g, pitch: a, neutral_pose_deg: [0, 10, 0]}
        logging: {tlog: false}
    """)
    )
    assert config.mavlink.heartbeat_timeout_s == 3.0
    servo = config.servos[0]
    assert (servo.max_speed_dps, servo.limits_deg) == (400.0, (-30.0, 30.0))
    assert config.gimbals[0].neutral_pose_deg == (0.0, 10.0, 0.0)
    assert config.logging.tlog is False


# ------------------------------------------------------------------------------ MAVLink URLs

BAD_URLS = {
    "udpin:127.0.0.1:99999": "0..65535",
    "udpin:127.0.0.1:bad": "'bad'",
    "udpout:127.0.0.1:0": "1..65535",
    "udpin:127.0.0.1": "HOST:PORT",
    "tcp::5760": "no host",
    "udpin:a:b:c": "HOST:PORT",
    "http://autopilot": "pymavlink connection string",
}


@pytest.mark.parametrize("url", sorted(BAD_URLS))
def test_a_mavlink_url_pymavlink_would_refuse_at_run_time_is_a_config_error(url: str):
    problems = _problems(f"mavlink:\n  url: '{url}'\n" + SERVO)
    assert [(p["line"], p["path"]) for p in problems] == [("2", "mavlink.url")]
    assert BAD_URLS[url] in problems[0]["msg"]


@pytest.mark.parametrize(
    "url",
    [
        "sim",
        "udpin:0.0.0.0:14550",
        "udpin:127.0.0.1:0",  # any free port
        "udp:127.0.0.1:14550",
        "udpout:10.0.0.2:14550",
        "udpbcast:192.168.1.255:14550",
        "tcp:127.0.0.1:5760",
        "tcpin:0.0.0.0:5760",
        "/dev/ttyAMA0",
        "/dev/serial/by-id/usb-ArduPilot_fmuv3-if00,921600",
        "COM3",
    ],
)
def test_usable_mavlink_urls_and_serial_paths_pass(url: str):
    assert url_problem(url) is None
    assert load_config_text(f"mavlink: {{url: '{url}'}}\n" + SERVO).mavlink.url == url


def test_monitor_outputs_are_checked_like_the_url_and_cannot_be_sim():
    problems = _problems(f"mavlink:\n  monitor_outputs: ['udpout:127.0.0.1:70000']\n{SERVO}")
    assert problems[0]["path"] == "mavlink.monitor_outputs" and "65535" in problems[0]["msg"]
    problems = _problems(f"mavlink:\n  monitor_outputs: [sim]\n{SERVO}")
    assert "only valid for mavlink.url" in problems[0]["msg"]


def test_a_bad_mavlink_option_names_the_option_not_the_key():
    config = load_config_text(SERVO)
    for url, words in (("udpin:127.0.0.1:bad", "'bad'"), ("udpin:127.0.0.1:99999", "65535")):
        with pytest.raises(OverrideError) as info:
            apply_overrides(config, mavlink=url)
        assert str(info.value).startswith(f"--mavlink {url}: ")
        assert words in str(info.value)
    assert apply_overrides(config, mavlink="udpin:0.0.0.0:14550").mavlink.url == (
        "udpin:0.0.0.0:14550"
    )


# ---------------------------------------------------------- telemetry_hz above the loop's cap


def test_check_warns_with_the_line_when_telemetry_hz_exceeds_the_telemetry_loop(
    tmp_path: Path,
):
    config = tmp_path / "fast.yaml"
    config.write_text(
        "servos:\n"
        "  - {name: a, profile: rmd-x, can_id: 1}\n"
        "  - {name: b, profile: lk, can_id: 2,\n"
        "     telemetry_hz: 1000}\n"
        "  - {name: c, profile: cubemars-ak, can_id: 3, telemetry_hz: 50}\n"  # push: no cap
        "scheduler: {telemetry_period_s: 0.1}\n"
    )
    out, err = io.StringIO(), io.StringIO()
    assert check_main([str(config)], out=out, err=err) == 0
    warnings = [line.strip() for line in out.getvalue().splitlines() if "telemetry_hz" in line]
    assert len(warnings) == 1, out.getvalue()
    assert warnings[0].startswith(f"{config}:4: servos[1].telemetry_hz: 1000 Hz")
    assert "10 Hz" in warnings[0]


# ----------------------------------------------------------------------- YAML syntax, typos


def test_a_mis_indented_line_gets_an_indentation_hint():
    text = SERVO + "  - {name: b, profile: rmd-x, can_id: 2}\n"
    text += " - {name: c, profile: lk, can_id: 3}\n"  # one space short
    with pytest.raises(ConfigError) as info:
        load_config_text(text, "bad.yaml")
    message = str(info.value)
    assert message.startswith("bad.yaml:4: invalid YAML")
    assert "check the indentation of this line and the lines above" in message


def test_an_unclosed_bracket_gets_no_indentation_hint():
    with pytest.raises(ConfigError) as info:
        load_config_text("servos: [a, b\n", "bad.yaml")
    assert "indentation" not in str(info.value)


def test_a_misspelt_required_key_is_reported_on_the_misspelt_line():
    text = "mavlink: {url: sim}\ncan: {}\nservo:\n  - {name: a, profile: rmd-x, can_id: 1}\n"
    problems = _problems(text)
    assert {(p["line"], p["path"]) for p in problems} == {("3", "servo"), ("3", "servos")}
    missing = next(p for p in problems if p["path"] == "servos")
    assert "required key is missing" in missing["msg"] and "'servo'" in missing["msg"]


def test_a_missing_key_without_a_lookalike_stays_on_its_mapping():
    problems = _problems("mavlink: {url: sim}\nlogging: {tlog: true}\n")
    assert [(p["line"], p["path"], p["msg"]) for p in problems] == [
        ("1", "servos", "required key is missing")
    ]
