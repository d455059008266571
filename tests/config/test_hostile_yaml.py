"""Hostile YAML: alias bombs, alias loops, deep nesting, junk bytes, oversized files.

Each used to hang ``mavservo check``/``run`` (a 9-level alias bomb: the duplicate-key walk
visited 9**9 nodes) or end in a RecursionError traceback (``a: &x [*x]``, 1,000 brackets).
Now every input ends in the config (or a ConfigError whose every line is ``FILE:LINE: ...``),
refused while composing, before anything is expanded. Timing is measured by hand in
bench/fuzz_config.py (docs/engineering/reliability.md), not asserted here.
"""

from __future__ import annotations

import io
import re
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mavservo.app.check import check_main
from mavservo.config import ConfigError, load_config, load_config_text
from mavservo.config.yamlsource import MAX_BYTES, MAX_DEPTH, MAX_VALUES

LINE = re.compile(r"^bad\.yaml:(\d+): .+$")
SERVO = "servos:\n  - {name: a, profile: rmd-x, can_id: 1, limits_deg: [-30, 30]}\n"


def alias_bomb(levels: int, width: int = 9) -> str:
    lines = ["l0: &l0 [" + ", ".join(["lol"] * width) + "]"]
    for level in range(1, levels + 1):
        lines.append(f"l{level}: &l{level} [" + ", ".join([f"*l{level - 1}"] * width) + "]")
    return "\n".join(lines) + f"\nservos: *l{levels}\n"


def refused(text: str) -> list[tuple[int, str]]:
    """(line, message) of every problem; asserts each is a FILE:LINE line."""
    with pytest.raises(ConfigError) as info:
        load_config_text(text, "bad.yaml")
    lines = str(info.value).splitlines()
    assert lines and all(LINE.match(line) for line in lines), lines
    return [(p.line, p.message) for p in info.value.problems]


@pytest.mark.timeout(60)
def test_a_nine_level_alias_bomb_is_refused_at_the_alias_that_overflows() -> None:
    problems = refused(alias_bomb(9))
    assert len(problems) == 1
    line, message = problems[0]
    # l0 (9 values + list = 10), l1 = 91, l2 = 820, l3 = 7,381, l4 = 66,430 > 20,000: line 5
    assert line == 5
    assert f"more than {MAX_VALUES} values" in message


def test_a_document_with_too_many_values_is_refused_even_without_aliases() -> None:
    [(line, message)] = refused("servos: [" + "1, " * (MAX_VALUES + 5) + "]\n")
    assert line == 1
    assert f"more than {MAX_VALUES} values" in message


@pytest.mark.parametrize(
    "text",
    ["a: &x [*x]\n", "a: &x {b: *x}\n", "a: &x {<<: *x}\n", "servos: &s [{x: [*s]}]\n"],
)
def test_an_alias_inside_the_node_it_names_is_a_loop_with_a_line(text: str) -> None:
    [(line, message)] = refused(text)
    assert line == 1
    assert "inside the node it names" in message


@pytest.mark.parametrize("depth", [MAX_DEPTH + 1, 1000, 20_000])
def test_deep_flow_nesting_is_refused_not_a_recursion_error(depth: int) -> None:
    [(line, message)] = refused("servos: " + "[" * depth + "]" * depth + "\n")
    assert line == 1
    assert f"more than {MAX_DEPTH} levels" in message


def test_deep_block_nesting_names_the_line_where_it_gets_too_deep() -> None:
    text = "".join(" " * i + f"k{i}:\n" for i in range(200))
    [(line, message)] = refused(text)
    assert line == MAX_DEPTH
    assert "levels deep" in message


def test_aliases_that_nest_too_deep_when_expanded_are_refused() -> None:
    # each level is shallow as written, but *l30 stands for 31 nested lists
    lines = ["l0: &l0 [1]"] + [f"l{i}: &l{i} [*l{i - 1}]" for i in range(1, 40)]
    [(line, message)] = refused("\n".join(lines) + "\n")
    assert "levels deep" in message
    assert 2 <= line <= 40


def test_aliases_used_within_the_bounds_still_work() -> None:
    text = (
        "servos:\n"
        "  - {name: a, profile: rmd-x, can_id: 1, limits_deg: &lim [-30, 30]}\n"
        "  - {name: b, profile: rmd-x, can_id: 2, limits_deg: *lim}\n"
    )
    config = load_config_text(text, "ok.yaml")
    assert [tuple(s.limits_deg) for s in config.servos] == [(-30, 30), (-30, 30)]


def test_invalid_utf8_in_a_file_names_its_line(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_bytes(b"servos:\n  - name: \xff\xfebad\n")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert str(info.value).startswith(f"{path}:2: not UTF-8 text")


def test_an_oversized_file_is_refused_without_parsing_it(tmp_path: Path) -> None:
    path = tmp_path / "big.yaml"
    path.write_bytes(b"servos:\n  - name: " + b"x" * (MAX_BYTES + 10) + b"\n")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert f"{path}:1: the file is larger than" in str(info.value)


@pytest.mark.timeout(60)
def test_check_exits_2_with_the_line_for_an_alias_bomb(tmp_path: Path) -> None:
    path = tmp_path / "bomb.yaml"
    path.write_text(alias_bomb(9), encoding="utf-8")
    err = io.StringIO()
    assert check_main([str(path)], out=io.StringIO(), err=err) == 2
    assert err.getvalue().startswith(f"{path}:5: ")


# ------------------------------------------------------------------ property: any YAML-ish text

_TOKENS = st.sampled_from(
    [
        "servos",
        "name",
        "a",
        "b",
        "can_id",
        "profile",
        "rmd-x",
        "limits_deg",
        "mavlink",
        "logging",
        "1",
        "-1",
        "1e9",
        "yes",
        "null",
        "~",
        "'x'",
        '"y"',
        ": ",
        ":",
        "- ",
        "-",
        "[",
        "]",
        "{",
        "}",
        ",",
        "\n",
        "\n  ",
        "\n    ",
        " ",
        "&x ",
        "&y ",
        "*x",
        "*y",
        "<<: ",
        "? ",
        "!!binary ",
        "!!set ",
        "!tag ",
        "#c",
        "|",
        ">",
        "---\n",
        "...",
        "\t",
        "%",
        "@",
        "\x00",
        "\x7f",
        "\ufeff",
        "é",
    ]
)
yaml_ish = st.lists(_TOKENS, max_size=60).map("".join)


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(text=st.one_of(yaml_ish, st.text(max_size=200), yaml_ish.map(lambda t: SERVO + t)))
def test_any_text_loads_or_is_refused_with_file_and_line(text: str) -> None:
    try:
        load_config_text(text, "bad.yaml")
    except ConfigError as exc:
        lines = str(exc).splitlines()
        assert lines, "a ConfigError with no problem in it"
        for line in lines:
            assert LINE.match(line), line
            assert int(LINE.match(line).group(1)) >= 1


@pytest.mark.timeout(60)
@pytest.mark.parametrize("text", [alias_bomb(9), "a: &x [*x]\n", "servos: " + "[" * 1000])
def test_run_exits_2_with_the_line_for_hostile_yaml(
    tmp_path: Path, text: str, capsys: pytest.CaptureFixture[str]
) -> None:
    from mavservo.app.run import main

    path = tmp_path / "hostile.yaml"
    path.write_text(text, encoding="utf-8")
    assert main(["--config", str(path), "--no-log", "--quiet", "--duration", "0.1"]) == 2
    err = capsys.readouterr().err
    assert re.search(rf"^{re.escape(str(path))}:\d+: ", err, re.M), err
    assert "Traceback" not in err
