"""When a servo's lifecycle frames go out: its start-up before a command, its release (motor
off) after a ``release``, its shutdown when the scheduler stops.

Pure (no clock, no I/O): the policy core (:mod:`.schedule_core`) asks it at every command it
puts on the bus and at every step, and wraps the frames it returns with their expected replies.
Its own part because it is its own small state machine, with its own state per servo (started,
the last start-up, the split start-up's early step, when release frames are due) and its own
rules, which the core's rules about setpoints, polls and liveness only touch at three points: a
servo back online or released starts up again, a new setpoint cancels a pending release, a
refused lifecycle frame goes again. The rules (schedule core's module docstring, "Lifecycle
frames"): start-up frames right before a servo's first command, again before the next command
after it was offline (it may have been power-cycled) or after a release, and again when the
profile's ``needs_startup()`` says so, never twice within ``STARTUP_RETRY_S`` (the bus budget
counts them at that rate); release frames at once after ``release`` (again at the next command
slot if the bus refused them).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import can

from mavservo.servos import ServoProfile, SplitStartup, release_frames_of

STARTUP_RETRY_S = 1.0
"""Start-up frames go out again at most this often for one servo (``needs_startup`` may stay
true while a servo refuses to start); the budget counts them at this rate."""


class ServoLifecycle:
    """One servo's start-up state: asked once per command, so it is held by the servo's slot
    in the core and answers without a lookup."""

    __slots__ = ("profile", "_split", "started", "_last_startup", "_continued")

    def __init__(self, profile: ServoProfile) -> None:
        self.profile = profile
        self._split = profile if isinstance(profile, SplitStartup) else None
        """Its profile as a :class:`SplitStartup` (resolved once: asked at every command)."""
        self.started = False
        """Its start-up frames went out since the schedule began, it came back online, or it
        was released."""
        self._last_startup = -math.inf
        self._continued = False
        """The early next step of its latest start-up went (``servos.base.SplitStartup``)."""

    def startup_frames(self, now: float) -> list[can.Message] | None:
        """The start-up frames to put before a command at ``now``; None when none are due."""
        split = self._split
        early = (
            self.started and not self._continued and split is not None and split.startup_continues()
        )
        if now - self._last_startup < STARTUP_RETRY_S and not early:
            return None  # the budget counts start-ups at this rate: it is a ceiling
        if self.started and not self.profile.needs_startup():
            return None
        self._continued = early  # one early step per start-up; a retry starts over
        self.started = True
        self._last_startup = now
        return self.profile.startup_frames()

    def restart(self, *, now_too: bool = False) -> None:
        """Start up again before the next command (back online, or its start-up refused).

        ``now_too``: not a retry either, so even within ``STARTUP_RETRY_S`` of the last one (a
        release: an LK motor off ignores A4 until 0x88, an RMD-X brake locked by the release
        would be driven against until 0x77)."""
        self.started = False
        if now_too:
            self._last_startup = -math.inf


class Lifecycles:
    """Every servo's lifecycle on one bus; release frames in configuration order.

    The servos with release frames pending are kept apart, so a step with none pending (nearly
    every step) costs one check, not a loop over the servos.
    """

    def __init__(self, servos: Sequence[tuple[str, ServoProfile]]) -> None:
        self.servos = {name: ServoLifecycle(profile) for name, profile in servos}
        self._order = [name for name, _ in servos]
        self._release_due: dict[str, float] = {}
        """When each servo's pending release frames are due: at once after ``release``, at the
        next command slot after the bus refused them."""

    def release(self, name: str) -> None:
        """Release frames at the next step (if the family has any); start up again before the
        next command, even within ``STARTUP_RETRY_S`` (releases come from a lost link or a
        health limit, each at most once per new setpoint)."""
        life = self.servos[name]
        if release_frames_of(life.profile):
            self._release_due[name] = -math.inf
        else:
            self._release_due.pop(name, None)
        life.restart(now_too=True)

    def cancel_release(self, name: str) -> None:
        """A new setpoint: the pending release frames of ``name`` (if any) do not go."""
        if self._release_due:
            self._release_due.pop(name, None)

    def release_refused(self, name: str, released: bool, next_slot: float) -> None:
        """The bus refused ``name``'s release frames: again at ``next_slot`` if it is still
        released (not in a tight loop)."""
        if released:
            self._release_due[name] = next_slot

    def next_release(self) -> float:
        """When the earliest pending release frames are due (inf: none pending)."""
        return min(self._release_due.values()) if self._release_due else math.inf

    def wants_wake(self) -> bool:
        """True when release frames wait to go at once (the runner is woken for them)."""
        return self.next_release() == -math.inf

    def due_releases(self, now: float) -> Sequence[tuple[str, list[can.Message]]]:
        """The release frames due at ``now``, per servo in configuration order (taken)."""
        if not self._release_due:
            return ()  # nearly every step: nothing built
        due = [n for n in self._order if self._release_due.get(n, math.inf) <= now]
        for name in due:
            del self._release_due[name]
        return [(name, release_frames_of(self.servos[name].profile)) for name in due]

    def final_frames(self, name: str) -> tuple[list[can.Message], list[can.Message]]:
        """``name``'s pending release frames (taken) and its shutdown frames, at the stop."""
        profile = self.servos[name].profile
        pending = self._release_due.pop(name, None) is not None
        return (release_frames_of(profile) if pending else []), profile.shutdown_frames()
