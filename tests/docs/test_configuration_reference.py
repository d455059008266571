"""docs/configuration.md is the schema's own reference: committed, current, and complete.

Issue 37 item 5: "a configuration reference generated from the schema (every key, type,
default, meaning; CI fails when it is stale)".
"""

from __future__ import annotations

from pathlib import Path

import yaml

from mavservo.config.reference import reference_markdown, rows, undocumented
from mavservo.config.schema import Config
from mavservo.servos import BUILT_IN, get_profile

REPO = Path(__file__).resolve().parents[2]
PAGE = REPO / "docs" / "configuration.md"
REGENERATE = "python -m mavservo.config.reference > docs/configuration.md"


def test_the_committed_reference_is_what_the_schema_writes_now() -> None:
    assert PAGE.read_text(encoding="utf-8") == reference_markdown(), (
        f"docs/configuration.md is stale: run `{REGENERATE}` and commit it"
    )


def test_every_key_has_a_meaning() -> None:
    assert undocumented() == [], (
        "add a docstring under each of these fields (mavservo/config/schema.py, "
        f"health_schema.py or the profile's Options), then `{REGENERATE}`"
    )


def test_every_key_of_the_commented_example_is_in_the_reference() -> None:
    """The reference walks the models; the keys a real file uses (config/sim.yaml, commented key
    by key) must all be rows of it, in the same dotted form, so nothing a user writes is missing
    (a walk that skipped a list, a mapping by name or a union would fail here)."""
    documented = {row.key for row in rows(Config, "")}
    # each family's options are rows of its own table, `options.KEY`
    documented |= {
        f"servos[].{row.key}"
        for name in BUILT_IN
        for row in rows(get_profile(name).Options, "options.")
    }
    with (REPO / "config" / "sim.yaml").open(encoding="utf-8") as handle:
        used = set(_keys(yaml.safe_load(handle), ""))
    # the free-form mappings (interface options, scripts, physics) are not schema keys
    used = {key for key in used if not key.startswith(_FREE_FORM)}
    assert used - documented == set()
    assert len(used) > 60  # the walk over sim.yaml really found its keys


_FREE_FORM = ("simulation.autopilot.script[].", "can.buses[].options.")


def _keys(value: object, prefix: str) -> list[str]:
    """Dotted keys of a loaded YAML document, lists as ``[]``, as the reference writes them."""
    found: list[str] = []
    if isinstance(value, dict):
        for key, item in value.items():
            path = f"{prefix}{key}"
            found.append(path)
            found += _keys(item, f"{path}.")
    elif isinstance(value, list):
        for item in value:
            found += _keys(item, f"{prefix.removesuffix('.')}[].")
    return found


def test_a_bound_a_default_and_a_choice_read_as_a_user_writes_them() -> None:
    page = reference_markdown()
    assert "| `mavlink.heartbeat_timeout_s` | number (> 0) | `2` |" in page
    assert "| `servos[].limits_deg` | [number, number] | `[-180, 180]` |" in page
    assert "| `logging.level` | one of `debug`, `info`, `warning`, `error` | `info` |" in page
    assert "| `servos[].name` | text (at most 32 characters) | **required** |" in page
    assert "Literal" not in page and "NoneType" not in page and "Annotated" not in page
