"""The CAN ids other devices on the bus take frames on, so that no probe lands on one of them.

A frame that is one family's read can be another family's command: an RMD-X read on 0x14C is
Set_Input_Pos of ODrive node 10, 0x156 its Reboot, 0x15F its Enter_DFU_Mode. Before the doctor
sends a probe it asks who else would take that frame as their own: every configured servo,
every motor heard or answering, every ODrive heard by its heartbeat, each by its profile's own
list of receiving identifiers. A part of its own because three senders ask it (the probes, the
enable frames of ``--allow-enable``, the DroneCAN GetNodeInfo requests) and its answer depends
on the findings so far, not on the bus.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import can

from mavservo.config import ServoConfig
from mavservo.servos import FrameId

from .families import facts
from .findings import BusFindings
from .recognise import Candidate, make_candidate


class Occupants:
    """The receiving ids of the devices known when it is built (module docstring)."""

    def __init__(self, servos: Sequence[ServoConfig], findings: BusFindings) -> None:
        devices: dict[tuple[str, int], Mapping[str, Any]] = {}
        for servo in servos:
            devices.setdefault((servo.profile, servo.can_id), servo.options)
        for sighting in findings.sightings.values():
            devices.setdefault((sighting.profile, sighting.can_id), sighting.options)
        for node in findings.heartbeats:
            devices.setdefault(("odrive", node), {})
        self.ids: list[tuple[str, frozenset[str], FrameId]] = []
        """(device name, its family and the families sharing its hardware, one receiving
        identifier), for each identifier of each device."""
        for (profile, can_id), options in devices.items():
            candidate = make_candidate(profile, can_id, options)
            if candidate is None:
                continue
            group = frozenset((profile, *facts(profile).siblings))
            self.ids.extend(
                (f"{profile} {can_id}", group, frame_id) for frame_id in _receiving_ids(candidate)
            )

    def owner(self, family: str, frames: Iterable[can.Message]) -> str | None:
        """The device of another family than ``family`` that would take one of ``frames`` as
        its own, or None."""
        frames = list(frames)
        for name, group, frame_id in self.ids:
            if family not in group and any(frame_id.matches(msg) for msg in frames):
                return name
        return None


def _receiving_ids(candidate: Candidate) -> list[FrameId]:
    """The identifiers ``candidate``'s motor takes frames on (its profile's own list)."""
    try:
        return [f for f in candidate.instance.identifiers() if f.direction == "to_servo"]
    except Exception:  # noqa: BLE001 - a profile that cannot say occupies nothing known
        return []
