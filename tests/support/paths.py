"""Where the tests find the repository and their recorded data, wherever a test file sits."""

from __future__ import annotations

from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
"""The repository's root: config/, docs/, bench/, examples/ and README.md are under it."""

TEST_DATA = REPO / "tests" / "data"
"""Recordings, reference vectors, MAVLink XML and schemas the tests read (tests/data/README.md)."""
