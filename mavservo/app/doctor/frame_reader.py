"""What each frame the doctor receives tells it, written into the bus's findings.

The doctor's session (:mod:`.session`) decides when to listen, at which bitrate, whom to ask;
every frame it then receives goes through one reading: which configured or look-alike motor it
can be (:class:`.recognise.Recogniser`), what it announces (an ODrive heartbeat, a DroneCAN
NodeStatus), what identity it carries (ODrive version, Robstride MCU id, MyActuator model and
date, a DroneCAN GetNodeInfo answer), which actuator ids a DroneCAN node reports, a Damiao
control mode, or that no family reads it. That reading is its own part, with no bus and no
timing of its own: frames in, findings out, so a hostile stream can be fed to it directly.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Set
from typing import Any

import can

from mavservo.servos import NodeInfoReader

from .findings import BusFindings
from .recognise import Recogniser, announcements
from .wire_facts import (
    NodeStatus,
    ODriveHeartbeat,
    actuator_status,
    damiao_mode,
    odrive_version,
    rmdx_identity,
    robstride_device_id,
)

ConfiguredKey = tuple[str, int, tuple[tuple[str, Any], ...]]
"""A configured servo: (profile, id, its options' key, :func:`.recognise.options_key`)."""


class FrameReader:
    """Reads frames into ``findings``; ``configured``: the servos of the config, whose reading
    of a frame wins over look-alikes; ``node_id``: the doctor's own DroneCAN node id (the
    GetNodeInfo answers addressed to it are read)."""

    def __init__(
        self,
        findings: BusFindings,
        recogniser: Recogniser,
        configured: Set[ConfiguredKey],
        node_id: int,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.findings = findings
        self.recogniser = recogniser
        self.configured = configured
        self._node_info = NodeInfoReader(node_id)
        self._clock = clock

    def read(
        self,
        msg: can.Message,
        bitrate: int,
        how: str,
        asked: set[tuple[str, int]] | None = None,
    ) -> None:
        """Read one valid frame heard at ``bitrate``; ``how``: ``heard`` or ``answered``, and
        ``asked``: the motors just sent a request (only they can have ``answered`` it)."""
        findings = self.findings
        said = announcements(msg)
        candidates = self.recogniser.whose(msg)
        mine = [(c, whole) for c, whole in candidates if c.key in self.configured]
        if mine:  # a configured servo's reading wins over the look-alikes (Damiao's 4-bit id)
            candidates = mine
        heartbeat = isinstance(said, ODriveHeartbeat)
        if heartbeat and candidates and all(c.profile != "odrive" for c, _ in candidates):
            said = None  # another family's frame that merely fits the heartbeat's layout
        if isinstance(said, ODriveHeartbeat):
            findings.heartbeats[said.node_id] = said
        elif isinstance(said, NodeStatus):
            findings.node_statuses[said.node_id] = said
        for family, read in (("odrive", odrive_version), ("robstride", robstride_device_id)):
            identity = read(msg)
            if identity is not None:
                findings.identify(family, *identity)
        model_or_date = rmdx_identity(msg)
        identified = model_or_date is not None and any(
            c.profile == "rmd-x" and c.can_id == model_or_date[0]
            for c in self.recogniser.candidates
        )
        if identified and model_or_date is not None:  # the profile reads no such answer
            findings.identify("rmd-x", *model_or_date)
        if self._node_info.accepts(msg):  # every frame of the answer is read, not unknown
            identified = True
            info = self._node_info.push(msg, self._clock())
            if info is not None:
                findings.node_infos[info.node_id] = info
                findings.identify("dronecan", info.node_id, info.text())
        status_of = actuator_status(msg)
        if status_of is not None:
            findings.actuators.setdefault(status_of[0], set()).add(status_of[1])
        if not candidates:
            if said is None and not identified:
                findings.unknown(msg)
            return
        mode = damiao_mode(msg)
        if mode is not None and any(c.profile == "damiao-dm" for c, _ in candidates):
            findings.damiao_modes[mode[0]] = mode[1]
        names = {f"{c.profile} {c.can_id}" for c, _ in candidates}
        for candidate, complete in candidates:
            mine_to_answer = asked is None or (candidate.profile, candidate.can_id) in asked
            sighting = findings.seen(
                candidate, bitrate, how if mine_to_answer else "heard", complete
            )
            sighting.alternatives |= names - {f"{candidate.profile} {candidate.can_id}"}
