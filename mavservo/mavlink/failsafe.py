"""Autopilot heartbeat watchdog: link lost -> servos to their failsafe; link back -> announce.

The bridge must not keep flying the last commanded surface positions when the autopilot is gone
(cable pulled, autopilot rebooting). The monitor only decides; the MAVLink side calls the backend
(``enter_failsafe`` / ``leave_failsafe``) and announces the transitions. After recovery nothing
moves until a fresh command or stream sample arrives (the backend enforces that).

The watchdog arms on the first HEARTBEAT: before the autopilot has ever been seen there is nothing
to lose, and a bridge started before the autopilot must not begin in failsafe. Pure: time comes in.
"""

from __future__ import annotations

import enum

#: The one STATUSTEXT of each transition (CRITICAL, NOTICE; both essential: never dropped for
#: other texts, never counted as a repeat). One message each: at most 50 characters, so no
#: ground station shows one cut in two (issue 37: the failsafe sent two texts per event, the
#: servo side's "failsafe cleared: servos move again on fresh commands" chunked mid-word;
#: the servo side's words now go to the console only).
LOST_TEXT = "servo bridge: autopilot lost, servos in failsafe"
RECOVERED_TEXT = "servo bridge: autopilot back, waiting for commands"


class FailsafeEvent(enum.Enum):
    LOST = "lost"
    RECOVERED = "recovered"


class HeartbeatWatchdog:
    """Tracks the watched autopilot's HEARTBEAT and reports transitions exactly once each."""

    def __init__(self, timeout_s: float) -> None:
        self.timeout_s = timeout_s
        self.last_heartbeat: float | None = None
        self.in_failsafe = False
        self.failsafe_count = 0
        #: checks past the deadline that waited for the reader to catch up
        self.deferred = 0

    def heartbeat(self, now: float) -> FailsafeEvent | None:
        """The autopilot's HEARTBEAT arrived at ``now``; RECOVERED when it ends a failsafe."""
        self.last_heartbeat = now
        if self.in_failsafe:
            self.in_failsafe = False
            return FailsafeEvent.RECOVERED
        return None

    def check(self, now: float, read_until: float | None = None) -> FailsafeEvent | None:
        """LOST once when no HEARTBEAT has arrived for ``timeout_s``.

        ``read_until``: the time up to which everything the link received has been read and
        handled (None: now). A heartbeat that arrived before the deadline may still wait
        unread behind a backlog, or in a process the machine starved: the decision waits
        until the reader has caught up with the deadline, at most one more ``timeout_s`` (a
        reader stuck for good still ends in failsafe). Why (issue 40): under a 1,000/s flood
        on a loaded machine the autopilot's heartbeat, sent on time, was read 2.6 s late and
        the failsafe ran (throttle to idle) for a healthy autopilot."""
        if self.in_failsafe or self.last_heartbeat is None:
            return None
        deadline = self.last_heartbeat + self.timeout_s
        if now < deadline:
            return None
        if read_until is not None and read_until < deadline and now < deadline + self.timeout_s:
            self.deferred += 1
            return None
        self.in_failsafe = True
        self.failsafe_count += 1
        return FailsafeEvent.LOST
