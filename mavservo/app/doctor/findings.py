"""What the doctor learnt of one bus: the motors it heard or that answered, the announcements,
identities and counts, and the bounded tallies of what no family reads.

The findings are the doctor's record, filled by its session (:mod:`.session`: the bitrate
search, the probes, the scans) and the frame reader (:mod:`.frame_reader`), and read by the
verdict (:mod:`.verdict`) and the printout; kept apart from both so each side depends on the
record, not on the other.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import can

from mavservo.config import BusConfig
from mavservo.servos import NodeInfo

from .recognise import Candidate
from .wire_facts import NodeStatus, ODriveHeartbeat

#: Distinct ids of unreadable frames counted one by one: a hostile stream of random ids
#: (up to ~8,000 frames/s at 1 Mbit/s) cannot grow the count past this.
MAX_UNKNOWN_IDS = 1024


@dataclass
class Sighting:
    """A motor the doctor heard or that answered: ``how`` is ``heard`` (unasked) or
    ``answered`` (a probe's reply); ``bitrate`` where."""

    profile: str
    can_id: int
    options: dict[str, Any]
    bitrate: int
    how: str
    frames: int = 0
    states: int = 0
    """Frames that decoded to a whole state (what proves it is this servo)."""
    alternatives: set[str] = field(default_factory=set)


@dataclass
class BusFindings:
    """Everything the doctor learnt of one bus."""

    bus: BusConfig
    listen_only: bool
    listened: dict[int, int] = field(default_factory=dict)
    """Bitrate -> valid frames heard while listening."""
    error_frames: dict[int, int] = field(default_factory=dict)
    unsupported: dict[int, str] = field(default_factory=dict)
    """Bitrates the adapter refused, and why."""
    open_error: str | None = None
    """Why the adapter did not open at all (at the configured bitrate): nothing else ran."""
    working_bitrate: int | None = None
    sightings: dict[tuple[str, int, tuple[tuple[str, Any], ...], int], Sighting] = field(
        default_factory=dict
    )
    heartbeats: dict[int, ODriveHeartbeat] = field(default_factory=dict)
    node_statuses: dict[int, NodeStatus] = field(default_factory=dict)
    unknown_ids: Counter[tuple[int, bool]] = field(default_factory=Counter)
    unknown_overflow: int = 0
    """Frames of ids no family reads beyond the first :data:`MAX_UNKNOWN_IDS` distinct ones."""
    damiao_modes: dict[int, str] = field(default_factory=dict)
    """Damiao motor id -> its CTRL_MODE register as read."""
    identities: dict[tuple[str, int], str] = field(default_factory=dict)
    """(family, id) -> what an identity read said (ODrive version, Robstride MCU id)."""
    actuators: dict[int, set[int]] = field(default_factory=dict)
    """DroneCAN node -> the actuator ids its actuator Status reports carry."""
    node_infos: dict[int, NodeInfo] = field(default_factory=dict)
    """DroneCAN node -> its answer to GetNodeInfo."""
    node_info_asked: set[int] = field(default_factory=set)
    node_info_skipped: str | None = None
    """Why no GetNodeInfo was asked at all (the doctor's node id is taken on the bus)."""
    probed_bitrates: list[int] = field(default_factory=list)
    sent: int = 0
    enable_sent: int = 0
    left_enabled: list[str] = field(default_factory=list)
    """Motors enabled by ``--allow-enable`` whose disable the bus refused every time."""
    scan_s: float | None = None
    scanned: int = 0
    spared: Counter[str] = field(default_factory=Counter)
    """Device ("odrive 10") -> probes not sent because they land on that device's ids: a
    frame that is another family's read can be this device's command (an RMD-X read on 0x14C
    is Set_Input_Pos of ODrive node 10, 0x156 its Reboot, 0x15F its Enter_DFU_Mode)."""

    @property
    def noisy(self) -> bool:
        """More frames no family reads than frames some family reads: on such a bus a frame
        that fits a family's layout is as likely chance as a motor, so a motor only heard
        (never answering a request) is not taken for one."""
        unknown = sum(self.unknown_ids.values()) + self.unknown_overflow
        return unknown > sum(s.frames for s in self.sightings.values())

    def identify(self, family: str, can_id: int, said: str) -> None:
        """Keep what an identity read said; a family with several reads (RMD-X model and
        software date) keeps each once, in the order heard."""
        known = self.identities.get((family, can_id))
        if known is None:
            self.identities[(family, can_id)] = said
        elif said not in known.split(", "):
            self.identities[(family, can_id)] = f"{known}, {said}"

    def node_info_said(self, node: int) -> str:
        """What GetNodeInfo told of DroneCAN ``node``, or why nothing."""
        info = self.node_infos.get(node)
        if info is not None:
            return info.text()
        if self.node_info_skipped is not None:
            return self.node_info_skipped
        if node in self.node_info_asked:
            return "no GetNodeInfo answer"
        return "GetNodeInfo not asked"

    def unknown(self, msg: can.Message) -> None:
        """Count a frame no family reads, by id; a flood of random ids is counted in one
        bucket past :data:`MAX_UNKNOWN_IDS` distinct ones (what is printed is the top 8)."""
        key = (msg.arbitration_id, msg.is_extended_id)
        if key in self.unknown_ids or len(self.unknown_ids) < MAX_UNKNOWN_IDS:
            self.unknown_ids[key] += 1
        else:
            self.unknown_overflow += 1

    def seen(self, candidate: Candidate, bitrate: int, how: str, complete: bool) -> Sighting:
        key = (*candidate.key, bitrate)
        sighting = self.sightings.get(key)
        if sighting is None:
            sighting = Sighting(
                candidate.profile, candidate.can_id, dict(candidate.raw_options), bitrate, how
            )
            self.sightings[key] = sighting
        elif how == "answered":
            sighting.how = how
        sighting.frames += 1
        sighting.states += complete
        return sighting
