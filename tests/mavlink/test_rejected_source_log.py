"""A flood of spoofed messages from a source not in ``allowed_sources`` is counted one by one
but logged a line per interval, over real UDP against the whole Bridge.

Why: on an unsigned link anyone can send a known message from any (system, component); the core
logged one WARNING per rejected message, so an attacker decided how fast the journal grew
(500 spoofed commands, 500 lines). Now: one line per ``REFUSAL_LOG_INTERVAL_S`` for the kind,
saying how many were kept quiet, and ``rejected_source`` still counts every message.
"""

from __future__ import annotations

import logging
import math
import re
import time
from collections.abc import Iterator

import pytest

from mavservo.mavlink.commands import REFUSAL_LOG_INTERVAL_S
from tests.redteam.test_bridge_security import GCS, ROGUE, Rig, set_servo
from tests.support.waiting import wait_until

SPOOFED = 500
BATCH = 50  # sent in batches the bridge reads before the next: no kernel drop decides the count


@pytest.fixture
def open_rig() -> Iterator[Rig]:
    rig = Rig(signing=False)
    yield rig
    rig.close()


def rejected_source(rig: Rig) -> int:
    return int(rig.stats()["core"].get("rejected_source", 0))


def test_spoofed_flood_from_a_source_not_allowed_gives_a_handful_of_lines(
    open_rig: Rig, caplog: pytest.LogCaptureFixture
) -> None:
    rig = open_rig
    rogue = rig.peer(ROGUE)
    caplog.set_level(logging.WARNING, logger="mavservo.mavlink.mavlink_core")
    started = time.monotonic()
    for batch in range(SPOOFED // BATCH):
        for i in range(BATCH):
            set_servo(rogue, 1, 1000 + i)
        assert wait_until(lambda b=batch: rejected_source(rig) >= (b + 1) * BATCH)
    elapsed = time.monotonic() - started
    assert rejected_source(rig) == SPOOFED
    lines = [r.getMessage() for r in caplog.records if "not in allowed_sources" in r.getMessage()]
    # one line when the flood starts, then at most one per interval it lasted
    assert 1 <= len(lines) <= 2 + math.ceil(elapsed / REFUSAL_LOG_INTERVAL_S)
    assert len(lines) < 20
    quiet = sum(int(m.group(1)) for line in lines if (m := re.search(r"\((\d+) more", line)))
    assert len(lines) + quiet <= SPOOFED  # what the lines account for never exceeds the count
    assert rig.setpoint("left") is None  # nothing of it applied
    gcs = rig.peer(GCS)
    set_servo(gcs, 1, 1500)
    assert wait_until(lambda: rig.setpoint("left") == pytest.approx(0.0))
