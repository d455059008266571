"""Servo profiles bent for tests that count frames exactly."""

from __future__ import annotations

import can

from mavservo.servos import RmdX


class RmdXWithoutStartUp(RmdX):
    """An RMD-X that sends no start-up frame (0xB3): for the tests of the command and poll
    policy, which count frames exactly; lifecycle frames have tests of their own
    (tests/scheduling/test_lifecycle_frames.py)."""

    def startup_frames(self) -> list[can.Message]:
        return []
