"""Whose is a frame: every family's profile, at every id of its range and in every mode the
doctor knows, asked ``is_reply`` and ``decode`` (the profiles' own reading of their frames), plus
the ODrive heartbeat and DroneCAN NodeStatus (:mod:`.wire_facts`).

A CAN frame does not say who sent it, and families overlap (RMD-X and LK share 0x240 + id; the
MIT packing answers on a master id): a frame can have several candidates. The doctor prefers the
configured servos' reading and names the others as alternatives.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import can

from mavservo.servos import ServoProfile, get_profile, node_reports_of

from .families import facts
from .wire_facts import NodeStatus, ODriveHeartbeat, node_status, odrive_heartbeat

log = logging.getLogger(__name__)


def options_key(options: Mapping[str, Any]) -> tuple[tuple[str, Any], ...]:
    """Options as a hashable, order-free key."""
    return tuple(sorted((str(k), repr(v)) for k, v in options.items()))


@dataclass(frozen=True)
class Candidate:
    """One reading of a frame: a ``profile`` motor at ``can_id`` with ``options``."""

    profile: str
    can_id: int
    options: tuple[tuple[str, Any], ...]
    raw_options: Mapping[str, Any]
    instance: ServoProfile

    @property
    def key(self) -> tuple[str, int, tuple[tuple[str, Any], ...]]:
        return (self.profile, self.can_id, self.options)


def make_candidate(profile: str, can_id: int, options: Mapping[str, Any]) -> Candidate | None:
    """A candidate, or None when the profile refuses that id or those options."""
    cls = get_profile(profile)
    try:
        instance = cls(can_id, cls.Options.model_validate(dict(options)))
    except Exception:  # noqa: BLE001 - a combination the profile does not take is no candidate
        return None
    return Candidate(profile, can_id, options_key(options), dict(options), instance)


def family_variants(
    profile: str, configured: Iterable[Mapping[str, Any]] = ()
) -> list[dict[str, Any]]:
    """The option sets to try for ``profile``: the configured ones first, then the modes the
    doctor knows (each only once)."""
    out: list[dict[str, Any]] = []
    seen: set[Any] = set()
    for options in [*configured, *facts(profile).variants]:
        key = options_key(options)
        if key not in seen:
            seen.add(key)
            out.append(dict(options))
    return out


#: Distinct frame heads whose candidates are remembered: a hostile stream of random ids cannot
#: grow the cache past this (frames beyond it are recognised without it).
MAX_HEADS = 4096


class Recogniser:
    """Candidates of every family given, over their id ranges (or ``ids``).

    Asking ~1,200 profiles about every frame of a busy bus would cost seconds per second, so
    the candidates whose ``is_reply`` accepts a frame are remembered by the frame's head (id,
    format, length, first byte: what every family's ``is_reply`` looks at); only they decode
    the next frames with that head.
    """

    def __init__(
        self,
        families: Mapping[str, Sequence[Mapping[str, Any]]],
        ids: Mapping[str, Iterable[int]] | None = None,
    ) -> None:
        self.candidates: list[Candidate] = []
        for profile, configured in families.items():
            cls = get_profile(profile)
            id_range = (ids or {}).get(profile) or range(cls.min_id, cls.max_id + 1)
            for options in family_variants(profile, configured):
                for can_id in id_range:
                    candidate = make_candidate(profile, can_id, options)
                    if candidate is not None:
                        self.candidates.append(candidate)
        self._heads: dict[tuple[int, bool, bool, int, bytes], list[Candidate]] = {}

    def whose(self, msg: can.Message) -> list[tuple[Candidate, bool]]:
        """Every candidate whose profile reads ``msg`` as its own, and whether the frame gave
        a whole state (False: the start of a multi-frame report, which says less)."""
        if msg.is_error_frame:
            return []
        data = bytes(msg.data)
        head = (msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame, msg.dlc, data[:1])
        replying = self._heads.get(head)
        if replying is None:
            replying = [c for c in self.candidates if self._is_reply(c, msg)]
            if len(self._heads) < MAX_HEADS:
                self._heads[head] = replying
        out = []
        for candidate in replying:
            try:
                profile = candidate.instance
                if not profile.is_reply(msg):
                    continue
                reports = node_reports_of(profile)
                complete = reports is None or reports.completes_report(msg)
                if profile.decode(msg, 0.0) is not None and complete:
                    out.append((candidate, True))
                elif not complete:
                    out.append((candidate, False))
            except Exception as exc:  # noqa: BLE001 - a hostile frame must not stop the doctor
                log.debug("%s %d: %s", candidate.profile, candidate.can_id, exc)
        return out

    @staticmethod
    def _is_reply(candidate: Candidate, msg: can.Message) -> bool:
        try:
            return bool(candidate.instance.is_reply(msg))
        except Exception:  # noqa: BLE001 - a hostile frame must not stop the doctor
            return False


def announcements(msg: can.Message) -> ODriveHeartbeat | NodeStatus | None:
    """An ODrive heartbeat or a DroneCAN NodeStatus, the frames that say "I am here"."""
    return node_status(msg) or odrive_heartbeat(msg)
