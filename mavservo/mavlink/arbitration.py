"""Who may drive a channel right now: explicit commands hold off autopilot mirroring.

An operator who sends DO_SET_SERVO to a channel that the autopilot also streams in
SERVO_OUTPUT_RAW expects the servo to stay where it was put, not to snap back 50 ms later when
the next stream sample arrives. So an explicit command claims its channel for ``hold_s`` seconds
(renewed by every further command, including each step of a DO_REPEAT_SERVO), and mirroring of
that channel is suspended until the claim expires. Priority order, highest first: failsafe (in
the backend), explicit commands, mirroring. Every decision is logged at debug level.

Pure: time comes in as an argument.
"""

from __future__ import annotations

import logging

log = logging.getLogger(__name__)

#: A channel key: ("servo", output channel) or ("actuator", actuator index).
ChannelKey = tuple[str, int]


class CommandHold:
    """Remembers, per channel, until when explicit commands own it."""

    def __init__(self, hold_s: float) -> None:
        self.hold_s = hold_s
        self._held_until: dict[ChannelKey, float] = {}
        self.mirror_suppressed = 0

    def note_command(self, key: ChannelKey, now: float) -> None:
        """An explicit command just drove ``key``: mirroring stays off it for ``hold_s``."""
        self._held_until[key] = now + self.hold_s
        log.debug(
            "arbitration: %s %d claimed by command until %.3f", key[0], key[1], now + self.hold_s
        )

    def mirror_allowed(self, key: ChannelKey, now: float) -> bool:
        """True when the autopilot stream may drive ``key`` at ``now``."""
        until = self._held_until.get(key)
        if until is None:
            return True
        if now >= until:
            del self._held_until[key]
            log.debug("arbitration: %s %d hold expired, mirroring resumes", key[0], key[1])
            return True
        self.mirror_suppressed += 1
        log.debug("arbitration: %s %d mirror sample dropped, command hold active", key[0], key[1])
        return False

    def release_all(self) -> None:
        """Forget every claim (after failsafe: fresh input of any kind may drive again)."""
        self._held_until.clear()
