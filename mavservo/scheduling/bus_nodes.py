"""The bus nodes one scheduler owns: what the servos of a family on its bus share (DroneCAN:
the bridge's own node, one ArrayCommand for every servo, a heartbeat), see ``docs/profiles.md``,
"Bus nodes".

Pure bookkeeping around the profiles' :class:`~mavservo.servos.base.BusNode` objects, no
threads and no clock: the runner (:mod:`mavservo.scheduling.runner`) calls it under its lock and
stays the only writer to the bus. It builds the nodes from the bus-level ``node:`` options,
groups the command frames of a step into what goes on the wire (:meth:`BusNodes.batches`),
collects the nodes' own frames and notices, and reads their state worth keeping.
"""

from __future__ import annotations

import hashlib
import socket
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can

from mavservo.servos import BusNode, NodeHealth, ProfileOptions, ServoProfile, node_family

from .busload import FrameFlow
from .schedule_core import Outgoing, ScheduleError, ServoSpec, TimingConfig

Batch = tuple[list[Outgoing], list[can.Message]]
"""Frames of a step as they go on the wire: the scheduler's frames and the CAN frames that
carry them (one each, or one packed transfer for several servos' commands)."""


_MACHINE_ID_FILES = ("/etc/machine-id", "/var/lib/dbus/machine-id")


def software_version() -> tuple[int, int]:
    """mavservo's major and minor version (the package's own ``__version__``, so a source
    checkout says what it is too), for a bus node's GetNodeInfo answer."""
    from mavservo import __version__

    try:
        major, minor, *_ = __version__.split(".")
        return int(major), int(minor)
    except ValueError:
        return (0, 0)


def machine_identity() -> bytes:
    """This machine's id (systemd's ``/etc/machine-id``), else its host name."""
    for path in _MACHINE_ID_FILES:
        try:
            text = Path(path).read_text(encoding="ascii").strip()
        except (OSError, UnicodeDecodeError):
            continue
        if text:
            return text.encode()
    return socket.gethostname().encode()


def node_unique_id(bus: str, machine: bytes | None = None) -> bytes:
    """A bus node's 16-byte unique id: stable for one machine and bus across restarts, and
    different for another machine or another bus (a DroneCAN tool tells two bridges, or two
    buses of one bridge, apart by it)."""
    identity = machine if machine is not None else machine_identity()
    return hashlib.sha256(b"mavservo-bus-node\0" + identity + b"\0" + bus.encode()).digest()[:16]


def command_hz(spec: ServoSpec, timing: TimingConfig) -> float:
    """Worst-case commands per second (every slot, or back to back for ``immediate``)."""
    hz = 1 / timing.command_period_s
    if spec.command_mode == "immediate":
        hz = max(hz, 1 / timing.immediate_min_spacing_s)
    return hz


@dataclass
class FamilyNode:
    """The servos of one family on one bus and the node they share (see :func:`family_nodes`)."""

    family: str
    """The profile name (the key of the bus's ``node:`` options)."""
    members: list[int]
    """Indices of its servos in the list given to :func:`family_nodes`."""
    node: BusNode | None
    """The node, or None: the family builds none, or it refused (``error``)."""
    error: ValueError | None = None
    """Why the family refused its servos or options (a :class:`BusNodeError` names the key)."""


def family_nodes(
    profiles: Sequence[ServoProfile],
    options: Mapping[str, ProfileOptions],
    bus: str,
    now: float = 0.0,
) -> list[FamilyNode]:
    """Group the servos of one bus by family and build each family's bus node (DroneCAN: one
    node for all its servos) from the bus's validated ``node:`` options: the one place this is
    done, for the scheduler, the bus-load budget and the config's checks alike. A refusal is
    returned, not raised, for each caller to report in its own terms."""
    groups: dict[type[ServoProfile], list[int]] = {}
    for index, profile in enumerate(profiles):
        groups.setdefault(type(profile), []).append(index)
    built: list[FamilyNode] = []
    for cls, members in groups.items():
        family = node_family(cls)
        if family is None:
            continue
        try:
            node = family.bus_node(
                [profiles[i] for i in members],
                options.get(cls.name) or family.NodeOptions(),
                software_version(),
                now,
                node_unique_id(bus),
            )
        except ValueError as exc:  # BusNodeError names the servo or option at fault
            built.append(FamilyNode(cls.name, members, None, exc))
            continue
        built.append(FamilyNode(cls.name, members, node))
    return built


class BusNodes:
    """The nodes of one bus, their servos and their traffic (module docstring)."""

    def __init__(
        self,
        bus: str,
        servos: Sequence[ServoSpec],
        timing: TimingConfig,
        options: Mapping[str, ProfileOptions],
        now: float,
    ) -> None:
        self.nodes: list[tuple[str, BusNode, list[str]]] = []
        """``(profile name, node, its servos' names)``."""
        self.node_of: dict[str, BusNode] = {}
        self.flows: list[FrameFlow] = []
        """What the nodes put on the bus (their heartbeat, the packed commands), for the
        budget; the servos in :attr:`node_of` are not counted for their own commands."""
        self._notices: list[str] = []
        for built in family_nodes([spec.profile for spec in servos], options, bus, now):
            if built.error is not None:
                raise ScheduleError(
                    f"bus {bus}: {built.family} node: {built.error}"
                ) from built.error
            if built.node is None:
                continue
            group = [servos[i] for i in built.members]
            node = built.node
            self.nodes.append((built.family, node, [spec.name for spec in group]))
            self.node_of.update((spec.name, node) for spec in group)
            hz = max(command_hz(spec, timing) for spec in group)
            self.flows += [
                FrameFlow(rate, extended, dlc)
                for rate, extended, dlc in node.bus_frames_per_second(len(group), hz)
            ]

    def __bool__(self) -> bool:
        return bool(self.nodes)

    def batches(self, frames: Sequence[Outgoing]) -> list[Batch]:
        """The frames of a step as they go on the wire: each on its own, except the commands of
        servos that share a node, which the node packs together where the first of them stood
        (DroneCAN: one ArrayCommand for all of them)."""
        if not self.node_of:
            return [([out], [out.msg]) for out in frames]
        batches: list[Batch] = []
        packed: dict[int, tuple[BusNode, int]] = {}
        for out in frames:
            # a release is a command too where the node carries it (DroneCAN: an ArduPilot
            # output's PWM 0 in the ArrayCommand, numbered with the node's transfer ids)
            packs = out.kind in ("command", "refresh") or (
                out.kind == "lifecycle" and out.lifecycle == "release"
            )
            node = self.node_of.get(out.servo) if packs else None
            if node is None:
                batches.append(([out], [out.msg]))
                continue
            if id(node) not in packed:
                packed[id(node)] = (node, len(batches))
                batches.append(([], []))
            batches[packed[id(node)][1]][0].append(out)
        for node, index in packed.values():
            outs = batches[index][0]
            setpoints = [out.setpoint for out in outs if out.kind != "lifecycle"]
            failsafe = (
                all(sp is not None and sp.source == "failsafe" for sp in setpoints)
                if setpoints
                else None  # releases only: says nothing about failsafe
            )
            batches[index] = (outs, node.pack([out.msg for out in outs], failsafe))
        return batches

    def due(self, now: float, is_online: Callable[[str], bool]) -> list[can.Message]:
        """The nodes' own frames due by ``now``, each told its bus's health."""
        return [
            msg for _, node, names in self.nodes for msg in node.due(now, _health(names, is_online))
        ]

    def next_due(self) -> float:
        return min((node.next_due() for _, node, _ in self.nodes), default=float("inf"))

    def receive(self, msg: can.Message, t: float) -> tuple[bool, list[str]]:
        """Give a received frame to every node: whether an answer waits, and new notices."""
        wake = False
        notices: list[str] = []
        for _, node, _ in self.nodes:
            wake = node.receive(msg, t) or wake
            notices += node.take_notices()
        self._notices += notices
        return wake, notices

    def collect(self) -> list[str]:
        """Notices the nodes raised outside :meth:`receive` (at start, in ``due``: a silent
        actuator, an empty allocation pool), kept for :meth:`take_notices` and returned."""
        fresh = [notice for _, node, _ in self.nodes for notice in node.take_notices()]
        self._notices += fresh
        return fresh

    def take_notices(self) -> list[str]:
        notices, self._notices = self._notices, []
        return notices

    def states(self) -> list[tuple[str, tuple[int, dict[str, Any]]]]:
        """``(profile name, (version, state))`` of the nodes with state worth keeping."""
        return [
            (profile, state)
            for profile, node, _ in self.nodes
            if (state := node.persistent_state()) is not None
        ]


def _health(names: list[str], is_online: Callable[[str], bool]) -> NodeHealth:
    """OK while every servo of the node is online, WARNING while some are, ERROR when none."""
    online = sum(1 for name in names if is_online(name))
    if online == len(names):
        return "ok"
    return "warning" if online else "error"
