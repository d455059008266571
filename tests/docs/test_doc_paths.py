"""A page named by its path in a shipped config or an engineering record is a page that exists.

The engineering records moved under docs/engineering/ (issue 37 item 5), and paths written as
text (`docs/sitl.md` in a config's comment, which `mavservo examples` hands to every user) are
not checked by the site build, which only follows links.
"""

from __future__ import annotations

import re

import pytest

from tests.support.paths import REPO

_DOC_PATH = re.compile(r"\bdocs/[\w/-]+\.md\b")
_FILES = sorted([*(REPO / "config").glob("*.yaml"), *(REPO / "docs" / "engineering").glob("*.md")])


def test_there_are_files_to_scan() -> None:
    assert len(_FILES) > 15


@pytest.mark.parametrize("path", _FILES, ids=lambda p: str(p.relative_to(REPO)))
def test_every_docs_path_written_as_text_exists(path) -> None:
    named = set(_DOC_PATH.findall(path.read_text(encoding="utf-8")))
    assert [p for p in sorted(named) if not (REPO / p).exists()] == []
