"""Every YAML block of the user guide is something ``mavservo check`` accepts.

A reader copies the guide's snippets into a config: an adapter's ``can:`` block, a ``mavlink:``
link, a whole file. A snippet that names a key the schema does not have, or a value it refuses,
would stop that reader at start-up. Snippets that are part of a file are completed with the
least the schema requires (a servo) before loading; nothing is opened (the loader checks, it
does not connect).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from mavservo.config import load_config_text
from tests.support.paths import REPO

#: The pages a newcomer follows from the box to the first flight (the reference pages show parts
#: of the shipped example files, which their own tests load whole).
GUIDE_PAGES = sorted(
    [
        *(REPO / "docs" / name for name in ("install.md", "first-run.md", "service.md")),
        *(REPO / "docs" / "hardware").glob("*.md"),
    ]
)
_YAML = re.compile(r"```yaml\n(.*?)```", re.S)
_SCHEMA_KEYS = {"mavlink", "can", "servos", "channels", "gimbals", "scheduler", "logging"}


def _snippets() -> list[tuple[str, str]]:
    found = []
    for page in GUIDE_PAGES:
        for index, match in enumerate(_YAML.finditer(page.read_text(encoding="utf-8"))):
            document = yaml.safe_load(match.group(1))
            # config snippets only: a block of other YAML (a servos[].health example) is whole
            if isinstance(document, dict) and set(document) <= _SCHEMA_KEYS | {"simulation"}:
                found.append((f"{page.relative_to(REPO)}#{index}", match.group(1)))
    return found


SNIPPETS = _snippets()


def test_the_guide_has_config_snippets_to_check() -> None:
    pages = {name.split("#")[0] for name, _ in SNIPPETS}
    assert "docs/hardware/adapters.md" in pages and "docs/first-run.md" in pages
    assert len(SNIPPETS) >= 7


@pytest.mark.parametrize(("name", "text"), SNIPPETS, ids=[name for name, _ in SNIPPETS])
def test_a_guide_snippet_is_a_valid_config(name: str, text: str) -> None:
    document = yaml.safe_load(text)
    document.setdefault("servos", [{"name": "s1", "profile": "rmd-x", "can_id": 1}])
    # a whole file as the guide shows it is loaded as it is; a part gets the rest added
    load_config_text(yaml.safe_dump(document), filename=name, base_dir=Path("/"))
