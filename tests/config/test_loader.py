"""The config loader: shipped examples, each class of bad config, FILE:LINE messages, check."""

from __future__ import annotations

import io
import re
import secrets
import textwrap
from pathlib import Path

import pytest

from mavservo.app.check import check_main, resolved_mapping
from mavservo.config import (
    ConfigError,
    bus_loads,
    default_config_path,
    load_config,
    load_config_text,
)
from tests.app.test_run_cli import run_mavservo
from tests.support.paths import REPO

SHIPPED = sorted((REPO / "config").glob("*.yaml"))
MARK = "# <-"  # the line a test expects its error on carries this marker
LINE_FORMAT = re.compile(r"^(?P<file>[^:]+):(?P<line>\d+): (?:(?P<path>[\w.\[\]]+): )?(?P<msg>.+)$")


def _marked_line(text: str) -> int:
    lines = [n for n, line in enumerate(text.splitlines(), 1) if MARK in line]
    assert len(lines) == 1, "a bad-config case marks exactly one line"
    return lines[0]


def _errors(text: str, filename: str = "bad.yaml", base_dir: Path | None = None) -> list[dict]:
    with pytest.raises(ConfigError) as info:
        load_config_text(text, filename, base_dir=base_dir)
    lines = str(info.value).splitlines()
    parsed = [LINE_FORMAT.match(line) for line in lines]
    assert all(parsed), f"every problem line must be FILE:LINE: path: message, got {lines}"
    return [m.groupdict() for m in parsed if m]


def _with_key(tmp_path: Path) -> Path:
    (tmp_path / "signing.key").write_text(secrets.token_hex(32) + "\n")
    return tmp_path


# ------------------------------------------------------------------------------ shipped configs


def test_the_expected_examples_are_shipped():
    assert {p.name for p in SHIPPED} >= {
        "sim.yaml",
        "ardupilot-sitl.yaml",
        "plane-surfaces.yaml",
        "gimbal.yaml",
    }


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.name)
def test_every_shipped_config_validates(path: Path, tmp_path: Path):
    # Key files are relative to the config and never shipped: provide one beside a copy.
    config = load_config_text(path.read_text(), str(path), base_dir=_with_key(tmp_path))
    assert config.servos
    for load in bus_loads(config):
        assert 0 < load.load <= load.max_load


def test_packaged_default_is_identical_to_config_sim_yaml():
    assert default_config_path().read_bytes() == (REPO / "config" / "sim.yaml").read_bytes()


def test_default_config_is_all_simulated_and_covers_the_recorded_plane():
    config = load_config(default_config_path())
    assert config.mavlink.url == "sim"
    assert all(bus.channel == "sim" for bus in config.can.buses)
    mapped = {c.channel for c in config.channels if c.source == "servo_output"}
    assert {1, 2, 3, 4, 9, 10} <= mapped
    assert config.gimbals and len(config.gimbals[0].axes()) == 3
    assert {config.servo(s).profile for s in config.gimbals[0].axes().values()} == {"cubemars-ak"}


def test_every_key_of_the_template_is_commented():
    # sim.yaml is the user's template: the first occurrence of every key explains it.
    seen: set[str] = set()
    for number, line in enumerate(default_config_path().read_text().splitlines(), 1):
        key = re.match(r"^\s*(?:- )?\{?([a-z_]+):", line)
        if key is None or line.lstrip().startswith("#") or key[1] in seen:
            continue
        seen.add(key[1])
        assert "#" in line, f"sim.yaml line {number}: first use of {key[1]!r} has no comment"
    assert len(seen) > 40


def test_signing_configs_refuse_to_load_without_their_key_file(tmp_path: Path):
    text = (REPO / "config" / "plane-surfaces.yaml").read_text()
    errors = _errors(text, "plane-surfaces.yaml", base_dir=tmp_path)
    assert [e["path"] for e in errors] == ["mavlink.signing.key_file"]
    # the error says how to make the missing file, not only that it is missing
    assert "secrets.token_hex(32)" in errors[0]["msg"] and "chmod 600" in errors[0]["msg"]
    key_line = next(
        n
        for n, line in enumerate(text.splitlines(), 1)
        if "key_file:" in line and not line.lstrip().startswith("#")
    )
    assert int(errors[0]["line"]) == key_line


def test_minimal_config_is_short_and_gets_defaults():
    config = load_config_text(
        textwrap.dedent("""
        servos:
          - {name: a, profile: rmd-x, can_id: 1}
        channels:
          - {servo: a, source: servo_output, channel: 1}
    """)
    )
    assert config.mavlink.url == "sim"
    assert config.bus_of(config.servos[0]).name == "bus0"
    assert config.channel_output_deg(config.channels[0]) == config.servos[0].limits_deg
    assert config.channels[0].input.resolved_trim == 1500


# ---------------------------------------------------------------------------------- bad configs

BASE = """\
servos:
  - {name: left, profile: rmd-x, can_id: 1}
  - {name: right, profile: rmd-x, can_id: 2}
"""

BAD_CASES = {
    "typo key": (
        "unknown key 'limts_deg'",
        "servos[2].limts_deg",
        BASE
        + """\
  - name: third
    profile: rmd-x
    can_id: 3
    limts_deg: [-10, 10]   # <-
""",
    ),
    "typo section": (
        "unknown key 'chanels'",
        "chanels",
        BASE
        + """\
chanels: []   # <-
""",
    ),
    "wrong type": (
        "valid integer",
        "channels[0].channel",
        BASE
        + """\
channels:
  - servo: left
    source: servo_output
    channel: one   # <-
""",
    ),
    "missing required key": (
        "required",
        "servos[2].can_id",
        BASE
        + """\
  - {name: third, profile: rmd-x}   # <-
""",
    ),
    "unknown source": (
        "servo_output",
        "channels[0].source",
        BASE
        + """\
channels:
  - servo: left
    source: servo_out   # <-
    channel: 1
""",
    ),
    "unknown profile": (
        "cubemars-ak",
        "servos[1].profile",
        """\
servos:
  - {name: a, profile: rmd-x, can_id: 1}
  - name: b
    profile: rmdx   # <-
    can_id: 2
""",
    ),
    "bad yaml syntax": (
        "invalid YAML",
        None,
        BASE
        + """\
channels:
  - {servo: left, source: servo_output, channel: 1   # <-
""",
    ),
    "duplicate yaml key": (
        "duplicate key",
        "scheduler.command_period_s",
        BASE
        + """\
scheduler:
  command_period_s: 0.05
  command_period_s: 0.02   # <-
""",
    ),
    "overlapping channel": (
        "already mapped",
        "channels[1].channel",
        BASE
        + """\
channels:
  - {servo: left, source: servo_output, channel: 1}
  - servo: right
    source: servo_output
    channel: 1   # <-
""",
    ),
    "servo driven twice by one source": (
        "already driven",
        "channels[1].servo",
        BASE
        + """\
channels:
  - {servo: left, source: actuator, index: 1}
  - source: actuator
    index: 2
    servo: left   # <-
""",
    ),
    "duplicate can id": (
        "collides",
        "servos[2].can_id",
        BASE
        + """\
  - name: third
    profile: rmd-x
    can_id: 2   # <-
""",
    ),
    "rmd-x and lk share an id layout": (
        "0x141",
        "servos[2].can_id",
        BASE
        + """\
  - name: lk_one
    profile: lk
    can_id: 1   # <-
""",
    ),
    "cubemars ids collide among themselves": (
        "collides",
        "servos[1].can_id",
        """\
servos:
  - {name: a, profile: cubemars-ak, can_id: 7}
  - name: b
    profile: cubemars-ak
    can_id: 7   # <-
""",
    ),
    "unknown servo in channel": (
        "expected the name of a servo",
        "channels[0].servo",
        BASE
        + """\
channels:
  - source: servo_output
    channel: 1
    servo: lefty   # <-
""",
    ),
    "unknown servo in gimbal": (
        "expected the name of a servo",
        "gimbals[0].pitch",
        BASE
        + """\
gimbals:
  - name: g
    roll: left
    pitch: nobody   # <-
""",
    ),
    "unknown bus": (
        "expected one of the buses",
        "servos[2].bus",
        BASE
        + """\
  - name: third
    profile: rmd-x
    can_id: 3
    bus: bus9   # <-
""",
    ),
    "over budget": (
        "exceeds max_load",
        "can.buses[0].max_load",
        """\
can:
  buses:
    - name: bus0
      max_load: 0.01   # <-
"""
        + BASE,
    ),
    "read interval too long": (
        "less than or equal to 0.05",
        "can.buses[0].read_interval_s",
        """\
can:
  buses:
    - name: bus0
      read_interval_s: 0.5   # <-
"""
        + BASE,
    ),
    "bad signing key": (
        "64 hexadecimal",
        "mavlink.signing.key",
        """\
mavlink:
  signing:
    key: "abc123"   # <-
"""
        + BASE,
    ),
    "unordered limits": (
        "low < high",
        "servos[2].limits_deg",
        BASE
        + """\
  - name: third
    profile: rmd-x
    can_id: 3
    limits_deg: [30, -30]   # <-
""",
    ),
    "failsafe position outside limits": (
        "inside limits_deg",
        "servos[2].failsafe.position_deg",
        BASE
        + """\
  - name: third
    profile: rmd-x
    can_id: 3
    limits_deg: [-30, 30]
    failsafe:
      action: position
      position_deg: 45   # <-
""",
    ),
    "gimbal component id": (
        "171..175",
        "gimbals[0].component_id",
        BASE
        + """\
gimbals:
  - name: g
    component_id: 160   # <-
    roll: left
""",
    ),
    "servo component id": (
        "140..153",
        "mavlink.servo_component_id",
        """\
mavlink:
  servo_component_id: 1   # <-
"""
        + BASE,
    ),
    "telemetry rate not positive": (
        "greater than 0",
        "servos[2].telemetry_hz",
        BASE
        + """\
  - name: third
    profile: rmd-x
    can_id: 3
    telemetry_hz: 0   # <-
""",
    ),
    "pwm trim outside input range": (
        "min < trim < max",
        "channels[0].input",
        BASE
        + """\
channels:
  - servo: left
    source: servo_output
    channel: 1
    input: {min: 1100, max: 1900, trim: 2000}   # <-
""",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_CASES))
def test_each_class_of_bad_config_names_file_key_path_and_line(case: str):
    expected_text, expected_path, text = BAD_CASES[case]
    with pytest.raises(ConfigError) as info:
        load_config_text(text, "bad.yaml")
    message = str(info.value)
    first = message.splitlines()[0]
    assert first.startswith(f"bad.yaml:{_marked_line(text)}: "), message
    assert expected_text in first, message
    if expected_path is not None:
        match = LINE_FORMAT.match(first)
        assert match and match["path"] == expected_path, message


def test_all_problems_of_a_pass_are_reported_together():
    text = BASE + textwrap.dedent("""\
        channels:
          - {servo: left, source: servo_output, channel: x, colour: red}
        scheduler: {comand_period_s: 0.1}
    """)
    paths = {e["path"] for e in _errors(text)}
    assert paths == {"channels[0].channel", "channels[0].colour", "scheduler.comand_period_s"}


def test_unknown_key_suggests_the_close_match():
    errors = _errors(BASE + "scheduler: {comand_period_s: 0.1}\n")
    assert "did you mean 'command_period_s'" in errors[0]["msg"]


def test_empty_file_is_an_error_not_a_default():
    errors = _errors("# nothing here\n")
    assert len(errors) == 1 and "empty" in errors[0]["msg"]


def test_unreadable_file_is_a_config_error(tmp_path: Path):
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "missing.yaml")


def test_key_file_is_resolved_next_to_the_config(tmp_path: Path):
    key = secrets.token_hex(32)
    (tmp_path / "signing.key").write_text(key)
    path = tmp_path / "c.yaml"
    path.write_text("mavlink:\n  signing: {key_file: signing.key}\n" + BASE)
    config = load_config(path)
    assert config.mavlink.signing is not None
    assert config.mavlink.signing.secret_key() == bytes.fromhex(key)


def test_key_file_with_garbage_is_refused(tmp_path: Path):
    (tmp_path / "signing.key").write_text("not a key\n")
    errors = _errors("mavlink:\n  signing: {key_file: signing.key}\n" + BASE, base_dir=tmp_path)
    assert errors[0]["path"] == "mavlink.signing.key_file" and errors[0]["line"] == "2"


# ---------------------------------------------------------------------------------- bus budget


def _sim_text(**replacements: str) -> str:
    text = default_config_path().read_text()
    for old, new in replacements.items():
        assert old in text
        text = text.replace(old, new)
    return text


def test_reported_over_budget_load_is_the_computed_worst_case():
    relaxed = load_config_text(_sim_text())
    load = bus_loads(relaxed)[0].load
    tight = f"max_load: {load * 0.9:.4f}"
    errors = _errors(_sim_text(**{"max_load: 0.35": tight}))
    assert f"{load:.3f}" in errors[0]["msg"]


def test_budget_follows_rates_and_bitrate():
    base = bus_loads(load_config_text(_sim_text()))[0].load
    slower_bus = bus_loads(
        load_config_text(
            _sim_text(**{"bitrate: 1000000": "bitrate: 500000", "max_load: 0.35": "max_load: 1.0"})
        )
    )[0].load
    assert slower_bus == pytest.approx(2 * base)
    immediate = bus_loads(
        load_config_text(
            _sim_text(
                **{
                    "command_mode: periodic": "command_mode: immediate",
                    "max_load: 0.35": "max_load: 1.0",
                }
            )
        )
    )[0].load
    assert immediate > base


# ------------------------------------------------------------------------------- check command


def test_check_main_prints_mapping_and_load_and_returns_zero():
    out, err = io.StringIO(), io.StringIO()
    assert check_main([str(default_config_path())], out=out, err=err) == 0
    text = out.getvalue()
    config = load_config(default_config_path())
    for servo in config.servos:
        assert servo.name in text
    assert re.search(r"bus0: R = 0\.\d+", text)
    assert "paper" not in text  # a user has no paper: the heading says what R counts
    assert err.getvalue() == ""


def test_check_main_returns_two_and_reports_every_bad_file(tmp_path: Path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(BAD_CASES["typo key"][2])
    out, err = io.StringIO(), io.StringIO()
    status = check_main(
        [str(default_config_path()), str(bad), str(tmp_path / "nope.yaml")], out=out, err=err
    )
    assert status == 2
    assert f"{bad}:{_marked_line(bad.read_text())}: servos[2].limts_deg" in err.getvalue()
    assert "nope.yaml" in err.getvalue()
    assert "Traceback" not in err.getvalue()
    assert "valid" in out.getvalue()  # the good one is still shown


#: families with no motor-off frame (``check --profiles``: "failsafe release: no"): CubeMars AK
#: servo mode and DroneCAN's ArrayCommand have no command that turns the motor off
WITHOUT_MOTOR_OFF = ("cubemars-ak", "dronecan")
RELEASE_CASE = """\
servos:
  - name: s
    profile: {profile}
    can_id: 11
    failsafe:
      action: {action}   # <-
channels:
  - {{servo: s, source: servo_output, channel: 1}}
"""


@pytest.mark.parametrize("profile", WITHOUT_MOTOR_OFF)
def test_check_exits_2_for_failsafe_release_on_a_family_without_motor_off(
    tmp_path: Path, profile: str
) -> None:
    """``release`` promises motor off: ``mavservo check`` refuses it, at the action's line,
    for a family that cannot; the same servo with ``hold``, and a family that can release
    (rmd-x), pass."""
    bad = tmp_path / f"{profile}-release.yaml"
    bad.write_text(RELEASE_CASE.format(profile=profile, action="release"))
    proc = run_mavservo("check", str(bad))
    assert proc.returncode == 2, proc.stdout + proc.stderr
    line = f"{bad}:{_marked_line(bad.read_text())}: servos[0].failsafe.action: "
    assert line in proc.stderr, proc.stderr
    assert f"the {profile} profile has no motor-off frame" in proc.stderr
    assert "Traceback" not in proc.stderr
    fine = []
    for fine_profile, action in ((profile, "hold"), ("rmd-x", "release")):
        path = tmp_path / f"{fine_profile}-{action}.yaml"
        path.write_text(RELEASE_CASE.format(profile=fine_profile, action=action))
        fine.append(str(path))
    out, err = io.StringIO(), io.StringIO()
    assert check_main(fine, out=out, err=err) == 0, err.getvalue()


def test_resolved_mapping_shows_reverse_and_clamping():
    text = resolved_mapping(
        load_config_text(
            BASE
            + textwrap.dedent("""\
        channels:
          - {servo: left, source: servo_output, channel: 1, reverse: true,
             output_deg: [-30, 30]}
          - {servo: right, source: servo_output, channel: 2, output_deg: [-300, 300]}
    """)
        )
    )
    rows = {line.split()[1]: line for line in text.splitlines() if line.startswith("  servo ")}
    assert "+30.0 / +0.0 / -30.0" in rows["1"]
    assert "-180.0* / +0.0 / +180.0*" in rows["2"]


# ------------------------------------------------------------------------------- parser fuzzing

from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from mavservo.config.schema import ServoConfig  # noqa: E402

SERVO_FIELDS = set(ServoConfig.model_fields)


@settings(max_examples=60, deadline=None)
@given(st.text(max_size=300))
def test_any_text_gives_a_config_or_a_config_error(text: str):
    try:
        load_config_text(text, "fuzz.yaml")
    except ConfigError as exc:
        assert str(exc).startswith("fuzz.yaml")


YAML_WORDS = {"on", "off", "yes", "no", "y", "n", "true", "false", "null"}


@settings(max_examples=40, deadline=None)
@given(
    # YAML 1.1 reads on/off/yes/no/y/n/true/false/null as booleans or null, not as key names
    st.from_regex(r"[a-z][a-z_]{0,15}", fullmatch=True).filter(
        lambda k: k not in SERVO_FIELDS and k not in YAML_WORDS
    ),
    st.integers(0, 8),
    st.integers(0, 3),
)
def test_an_unknown_key_anywhere_in_a_servo_is_reported_on_its_line(key, servo_index, position):
    lines = default_config_path().read_text().splitlines()
    starts = [
        n
        for n, line in enumerate(lines)
        if line.startswith("  - name:")
        and n < next(i for i, x in enumerate(lines) if x.startswith("channels:"))
    ]
    start = starts[servo_index]
    insert_at = start + 1 + position
    lines.insert(insert_at, f"    {key}: 1")
    errors = _errors("\n".join(lines) + "\n", "sim.yaml")
    assert [(e["line"], e["path"]) for e in errors] == [
        (str(insert_at + 1), f"servos[{servo_index}].{key}")
    ]


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        # the url deleted from a hardware config leaves `mavlink:` with nothing under it
        ("mavlink:\n", "'mavlink' is empty (nothing under it); write its keys under it"),
        ("mavlink: udpin:0.0.0.0:14550\n", "expected keys under 'mavlink', found"),
        ("can:\n  buses:\n", "'buses' is empty (nothing under it); write its items"),
        ("can:\n  buses: can0\n", "expected items (lines starting with '- ') under 'buses'"),
    ],
)
def test_an_empty_or_flat_section_is_named_in_yaml_terms(text: str, expected: str):
    messages = [e["msg"] for e in _errors(text + "servos: []\n")]
    assert any(expected in m for m in messages), messages
    assert not any("instance of" in m or "valid dictionary" in m for m in messages), messages


@pytest.mark.parametrize(("written", "meant"), [(921, "921600"), (57, "57600"), (115, "115200")])
def test_an_ardupilot_baud_code_is_refused_with_the_baud_rate_it_stands_for(written, meant):
    # SERIAL2_BAUD 921 copied into the config: the link would be silent at 921 baud
    errors = _errors(f"mavlink:\n  url: /dev/serial0\n  baud: {written}\n" + BASE)
    assert [e["path"] for e in errors] == ["mavlink.baud"] and errors[0]["line"] == "3"
    assert f"write baud: {meant}" in errors[0]["msg"]


def test_a_slow_but_real_baud_rate_is_accepted():
    config = load_config_text("mavlink:\n  url: /dev/serial0\n  baud: 1200\n" + BASE, "ok.yaml")
    assert config.mavlink.baud == 1200


def test_an_unclosed_brace_names_the_line_it_opened_on():
    # PyYAML reports the next line ("expected ',' or '}', but got '-'"), where nothing is wrong
    text = BASE.replace("can_id: 1}", "can_id: 1") + "channels: []\n"
    errors = _errors(text)
    assert len(errors) == 1 and errors[0]["line"] == "3"
    assert "the '{' on line 2 is not closed: is its '}' missing?" in errors[0]["msg"]


def test_an_unclosed_bracket_inside_a_multiline_mapping_is_named():
    text = "servos:\n  - {name: a, profile: rmd-x, can_id: 1, limits_deg: [-10, 10,\n     x: 1}\n"
    (error,) = _errors(text)
    assert "the '[' on line 2 is not closed: is its ']' missing?" in error["msg"]
