"""Whose traffic fills the bus: the measured load split into the bridge's own frames, its
servos' frames and everyone else's, and a warning when the total passes ``max_load``.

``max_load`` is checked against the planned worst case at start (``check``, the scheduler);
a bus shared with a busy node (a peripheral broadcasting sensors at 2,800 frames/s) can pass
it at run time with no plan knowing. The warning names the share of each party, so the user
knows whether to slow the bridge, its servos, or the other node. Pure: times handed in.
"""

from __future__ import annotations

from mavservo.records import LoadMeter

CHECK_EVERY_S = 1.0
"""The measured load is compared with ``max_load`` this often."""
WARN_AGAIN_S = 60.0
"""A bus that stays over ``max_load`` is warned about again after this long (with the figures
of then); one that went back under and over again at once."""


class LoadWatch:
    """Per-party load meters of one bus and the over-``max_load`` warning (module docstring)."""

    def __init__(self, bus: str, bitrate: int, window_s: float, max_load: float) -> None:
        self.bus = bus
        self.max_load = max_load
        self.servos = LoadMeter(bitrate, window_s)
        self.others = LoadMeter(bitrate, window_s)
        self.warnings = 0
        self._next_check = -float("inf")
        self._warned_at: float | None = None
        self._over = False

    def received(self, t: float, bits: int, from_servo: bool) -> None:
        """A received frame: a servo's (claimed by one) or another node's."""
        (self.servos if from_servo else self.others).add(t, bits)

    def check(self, now: float, total: float) -> str | None:
        """A warning when the measured ``total`` load (every frame, the bridge's included) is
        over ``max_load``: at most once per :data:`CHECK_EVERY_S`, again after
        :data:`WARN_AGAIN_S` while it stays over."""
        if now < self._next_check:
            return None
        self._next_check = now + CHECK_EVERY_S
        if total <= self.max_load:
            self._over = False
            return None
        again = self._warned_at is not None and now - self._warned_at < WARN_AGAIN_S
        if self._over and again:
            return None
        self._over, self._warned_at = True, now
        self.warnings += 1
        servos = self.servos.ratio(now)
        others = self.others.ratio(now)
        ours = max(0.0, total - servos - others)
        shares = {"the bridge's own": ours, "its servos'": servos, "other nodes'": others}
        most = max(shares, key=lambda k: shares[k])
        return (
            f"bus {self.bus}: measured load {total:.1%} is over max_load {self.max_load:.0%}: "
            f"the bridge's own frames {ours:.1%}, its servos' {servos:.1%}, other nodes' "
            f"{others:.1%}; most is {most} traffic"
        )
