"""Whether each servo of a bus is heard: online, or offline until it is heard again.

Pure (no clock, no I/O): the policy core (:mod:`.schedule_core`) tells it every miss (a reply
that timed out, a frame the bus refused) and every reply, and asks it at each step which
pushing servos fell silent. Its own part because it has its own state per servo (misses in a
row, when it was last heard) and its own rules, one per telemetry shape (schedule core's module
docstring, "Liveness"): a *polled* servo is alive while it answers; a *pushing* servo while its
pushes keep coming (silent for more than ``offline_after_missed`` push periods plus one
``reply_timeout_s``, it goes offline, commanded or not); a servo taken offline by refused
sends, with nothing to probe it with, comes back when a send works again. What going offline
does to a servo's setpoints is the core's business, not this part's.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence


class _Heard:
    __slots__ = ("missed", "last_heard", "silence_limit_s")

    def __init__(self, silence_limit_s: float | None) -> None:
        self.missed = 0
        """Misses in a row since it was last heard."""
        self.last_heard = 0.0
        """When it last reported (or the schedule started): a pusher's silence is from here."""
        self.silence_limit_s = silence_limit_s


class Liveness:
    """Online/offline of the servos ``servos`` (``(name, push period or None)``).

    ``offline_on_sends``: the servos offline because the bus refused their frames (not because
    replies stopped), that have not answered since.
    """

    def __init__(
        self,
        servos: Sequence[tuple[str, float | None]],
        offline_after_missed: int,
        reply_timeout_s: float,
    ) -> None:
        self._limit = offline_after_missed
        self._servos = {
            name: _Heard(
                None if period is None else offline_after_missed * period + reply_timeout_s
            )
            for name, period in servos
        }
        self._pushers = [
            (name, heard)
            for name, heard in self._servos.items()
            if heard.silence_limit_s is not None
        ]
        self.offline_on_sends: set[str] = set()

    def anchor(self, start: float) -> None:
        """The schedule starts at ``start``: every servo's silence is counted from there."""
        for heard in self._servos.values():
            heard.last_heard = start

    def is_online(self, name: str) -> bool:
        return self._servos[name].missed < self._limit

    def silence_limit_s(self, name: str) -> float | None:
        """How long a pushing servo may stay silent before it is offline (None: not pushing)."""
        return self._servos[name].silence_limit_s

    def missed(self, name: str, *, on_send: bool) -> bool:
        """Count one miss (``on_send``: a refused frame); True if it goes offline with it."""
        heard = self._servos[name]
        heard.missed += 1
        if heard.missed != self._limit:
            return False
        if on_send:
            self.offline_on_sends.add(name)
        else:
            self.offline_on_sends.discard(name)
        return True

    def heard(self, name: str, t: float) -> bool:
        """``name`` reported at ``t``; True if it was offline (it is back)."""
        heard = self._servos[name]
        back = heard.missed >= self._limit
        heard.missed = 0
        heard.last_heard = max(heard.last_heard, t)
        self.offline_on_sends.discard(name)
        return back

    def fell_silent(self, now: float) -> Sequence[str]:
        """The pushing servos online until now whose pushes stopped: offline from now."""
        silent: list[str] | None = None  # built only when one falls silent (rare), not per step
        for name, heard in self._pushers:
            limit = heard.silence_limit_s
            assert limit is not None
            if heard.missed >= self._limit or now - heard.last_heard <= limit:
                continue
            heard.missed = self._limit
            self.offline_on_sends.discard(name)
            silent = silent or []
            silent.append(name)
        return silent or ()

    def back_on_send(self, nothing_to_probe: Callable[[str], bool]) -> list[str]:
        """A send worked: the servos offline on refused sends that nothing else could bring
        back (not pushing, and ``nothing_to_probe``: no setpoint, no polls) are online again."""
        back: list[str] = []
        for name in list(self.offline_on_sends):
            heard = self._servos[name]
            pushing = heard.silence_limit_s is not None  # a pusher is back when it pushes
            if not pushing and heard.missed >= self._limit and nothing_to_probe(name):
                heard.missed = 0
                self.offline_on_sends.discard(name)
                back.append(name)
        return back
