"""The bridge's own DroneCAN node on one bus: what the DroneCAN servos of that bus share.

A DroneCAN bus expects every participant to be a node: a node id, ``uavcan.protocol.
NodeStatus`` at 1 Hz (uptime, health, mode) and an answer to ``uavcan.protocol.GetNodeInfo``
(what ``dronecan-gui-tool`` and an autopilot's node monitor ask). Actuator commands are one
broadcast for every servo of the bus (``ArrayCommand``, up to 15 per transfer). So one object
per bus, built by the profile (:meth:`mavservo.servos.dronecan.DroneCanServo.bus_node`) and
owned by the scheduler, which stays the only writer: it hands the node the command frames of a
slot to :meth:`BridgeNode.pack`, asks it for its own frames (:meth:`BridgeNode.due`) and gives
it what it receives (:meth:`BridgeNode.receive`). Pure: no clock, no I/O; times are handed in.

Health: OK while every servo of the bus is online, WARNING while some are offline, ERROR when
none is (the scheduler tells). Mode: OPERATIONAL.

Bus sharing: an ``ArrayCommand`` from another node means a second master (an autopilot driving
the same servos): both would fight, silently. The node reports each such node id once
(:meth:`BridgeNode.take_notices`); the scheduler logs it and the bridge sends it as STATUSTEXT.

Dynamic node id allocation (``allocator: true``): the server side of ``uavcan.protocol.
dynamic_node_id.Allocation`` for nodes that start without an id, see :mod:`.alloc`.

The node sends its own traffic and owns the parts that have a job and a state of their own, each
in its module: the SafetyState broadcast (:mod:`.safety`), the GetNodeInfo answers at a bounded
rate (:mod:`.info_service`), the watch on other masters of the bus (:mod:`.bus_sharing`), the
watch on actuators that never or no longer report (:mod:`.actuator_watch`) and the allocation
server (:mod:`.alloc`). They count in the node's counters and tell the crew through its notices
(:mod:`.notices`), so the scheduler still sees one node.
"""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Literal, Protocol

import can
from pydantic import Field, field_validator, model_validator

from ..base import BusNodeError, NodeHealth, ProfileOptions
from . import wire
from .actuator_watch import ActuatorWatch, WatchedServoOptions
from .bus_sharing import SENDERS_REPORTED as SENDERS_REPORTED
from .bus_sharing import BusSharingWatch
from .info_service import GET_NODE_INFO_PER_S as GET_NODE_INFO_PER_S
from .info_service import NodeInfoService
from .notices import Notices
from .safety import SAFETY_PERIOD_S as SAFETY_PERIOD_S
from .safety import SafetyBroadcast

if TYPE_CHECKING:  # imported where used at run time: only a bus with the allocator on needs it
    from .alloc import AllocationServer

_HEX32 = re.compile(r"[0-9a-f]{32}")
_HEALTH = {"ok": wire.HEALTH_OK, "warning": wire.HEALTH_WARNING, "error": wire.HEALTH_ERROR}


class NodeOptions(ProfileOptions):
    """The bus-level ``node:`` options of a bus with DroneCAN servos."""

    node_id: int = Field(
        100, ge=1, le=127, description="the bridge's own node id on this bus (1..127)"
    )
    name: str = Field(
        "org.mavservo.bridge",
        min_length=1,
        max_length=80,
        pattern=r"^[a-z0-9_.-]+$",
        description="answered to GetNodeInfo (reverse domain name, lower case)",
    )
    allocator: bool = Field(
        False, description="serve dynamic node id allocation requests (off: static ids only)"
    )
    allocation_first_id: int = Field(
        125, ge=1, le=125, description="allocation hands out ids from here down"
    )
    safety_state: Literal["none", "safety_off"] = Field(
        "none",
        description="ardupilot.indication.SafetyState the bridge broadcasts every 500 ms, as "
        "ArduPilot's flight controller does: safety_off (SAFETY_OFF from start: ArduPilot "
        "peripherals drive their outputs) or none (never sent: they keep their outputs off)",
    )
    safety_on: Literal["stop", "failsafe_and_stop", "never"] = Field(
        "stop",
        description="with safety_state safety_off: when the bridge turns safety back on "
        "(SAFETY_ON: outputs off): at stop, also while every servo of the bus is in failsafe "
        "(failsafe_and_stop), or never",
    )
    unique_id: str | None = Field(
        None,
        pattern=r"^[0-9a-f]{32}$",
        description="the 16-byte unique id GetNodeInfo answers (32 hex digits); default: "
        "derived from the machine id and the bus name, stable across restarts",
    )
    allocation_max_entries: int = Field(
        16,
        ge=0,
        le=120,
        description="node ids the allocator hands to unique ids the config does not name, at "
        "most (a stranger making up unique ids cannot take the whole pool)",
    )
    allocation_expire_s: float = Field(
        600.0,
        ge=5.0,
        le=86400.0,
        description="an allocated id whose node has not been heard for this long is free again "
        "(the table entry goes); a node id heard on the bus stops blocking allocation after "
        "the same time",
    )
    allocation_table: dict[str, int] = Field(
        default_factory=dict,
        description="unique id (32 hex digits) -> node id the allocator handed out before "
        "(the bridge keeps it in a file next to the config)",
    )

    @field_validator("allocation_table")
    @classmethod
    def _table_entries(cls, table: dict[str, int]) -> dict[str, int]:
        for unique_id, node_id in table.items():
            if not _HEX32.fullmatch(unique_id):
                raise ValueError(f"unique id {unique_id!r} is not 32 lower-case hex digits")
            if not 1 <= node_id <= 125:
                raise ValueError(f"node id {node_id} for {unique_id} is outside 1..125")
        owners: dict[int, str] = {}
        for unique_id, node_id in sorted(table.items()):
            if node_id in owners:
                raise ValueError(
                    f"node id {node_id} is in the table twice ({owners[node_id]} and "
                    f"{unique_id}): two nodes would get one id"
                )
            owners[node_id] = unique_id
        return table

    @model_validator(mode="after")
    def _table_not_own_id(self) -> NodeOptions:
        for unique_id, node_id in self.allocation_table.items():
            if node_id == self.node_id:
                raise ValueError(
                    f"allocation_table gives {unique_id} the bridge's own node id {node_id}"
                )
        return self


class CommandedServoOptions(WatchedServoOptions, Protocol):
    """What the node reads of a DroneCAN servo's options (read-only): what the actuator
    watch reads, and the unique id the allocator hands a node id to."""

    @property
    def unique_id(self) -> str | None: ...


class CommandedServo(Protocol):
    """What the node needs of a DroneCAN servo profile."""

    can_id: int
    bridge_node_id: int
    node_actuators: frozenset[int]
    node_heard_at: float | None
    node_last_heard: float | None
    actuator_reported_at: float | None
    shutdown_hook: Callable[[], list[can.Message]] | None

    @property
    def options(self) -> CommandedServoOptions: ...

    def command_of(self, frame: can.Message) -> tuple[int, int, float] | None: ...


def frames_for_commands(count: int) -> int:
    """Frames of the ArrayCommand transfers carrying ``count`` commands (4 bytes each, 15 per
    transfer; a multi-frame transfer adds the 2-byte CRC; every frame carries 7 bytes and
    the tail byte)."""
    frames = 0
    while count > 0:
        chunk = min(count, wire.MAX_COMMANDS_PER_TRANSFER)
        payload = 4 * chunk
        frames += 1 if payload <= 7 else -(-(payload + 2) // 7)
        count -= chunk
    return frames


class BridgeNode:
    """The bridge's node on one bus (module docstring).

    It sends the node's own traffic (NodeStatus, the packed ArrayCommands, GetNodeInfo answers)
    and owns the parts with a job and a state of their own: the SafetyState broadcast
    (:class:`.safety.SafetyBroadcast`), the watch on other masters of the bus
    (:class:`.bus_sharing.BusSharingWatch`), the watch on actuators that do not report
    (:class:`.actuator_watch.ActuatorWatch`) and, with the allocator on, the allocation server
    (:class:`.alloc.AllocationServer`); they count in the node's counters and say what they
    find through its notices (:class:`.notices.Notices`).
    """

    def __init__(
        self,
        servos: Sequence[CommandedServo],
        options: NodeOptions,
        software_version: tuple[int, int],
        start: float,
        unique_id: bytes = bytes(16),
    ) -> None:
        taken = {servo.can_id for servo in servos}
        if options.node_id in taken:
            raise BusNodeError(
                f"the bridge's DroneCAN node id {options.node_id} is also a servo's node id on "
                "this bus; every node needs its own id",
                None,
                "node_id",
            )
        actuators: dict[int, int] = {}
        for index, servo in enumerate(servos):
            actuator = servo.options.actuator_id
            if actuator in actuators:
                first = servos[actuators[actuator]]
                raise BusNodeError(
                    f"actuator id {actuator} is already used on this bus by the servo with "
                    f"node id {first.can_id}: one ArrayCommand carries every actuator of the "
                    "bus, so both would take the same command",
                    index,
                    "options.actuator_id",
                )
            actuators[actuator] = index
            if servo.options.unique_id is not None and not options.allocator:
                raise BusNodeError(
                    "a servo with a unique_id gets its node id from the bridge's allocator: "
                    "set node.dronecan.allocator: true on its bus",
                    index,
                    "options.unique_id",
                )
        self.options = options
        self.node_id = options.node_id
        self.servos = list(servos)
        self.software_version = software_version
        self.start = start
        self.unique_id = bytes.fromhex(options.unique_id) if options.unique_id else unique_id
        """Answered in GetNodeInfo: the option, else what the bridge derived (machine, bus)."""
        on_node: dict[int, set[int]] = {}
        for servo in servos:
            on_node.setdefault(servo.can_id, set()).add(servo.options.actuator_id)
        for servo in servos:
            servo.bridge_node_id = self.node_id
            servo.node_actuators = frozenset(on_node[servo.can_id])
        self.counters: Counter[str] = Counter()
        self._notices = Notices()
        self._transfer_ids: Counter[int] = Counter()
        self._payloads: dict[int, Any] = {}
        self._reassembler = wire.Reassembler()
        self._queue: list[can.Message] = []
        self._next_status = start
        self._health = wire.HEALTH_OK
        self.node_info = NodeInfoService(
            self.node_id,
            options.name,
            software_version,
            self.unique_id,
            self.status_payload,
            self.counters,
            self._notices,
        )
        self.safety = SafetyBroadcast(
            self.node_id,
            options.safety_state == "safety_off",
            options.safety_on,
            sorted({s.can_id for s in servos if s.options.firmware == "ardupilot"}),
            start,
            self.counters,
            self._notices,
        )
        if self.safety.turns_on_at_stop and servos:
            servos[0].shutdown_hook = self.safety.at_stop
        self.sharing = BusSharingWatch(
            self.node_id,
            set(actuators),
            self.safety.safety_off,
            self._reassembler,
            self.counters,
            self._notices,
        )
        self.actuators = ActuatorWatch(self.servos, self.counters, self._notices)
        self.allocator: AllocationServer | None = None
        if options.allocator:
            self.allocator = self._allocation_server(servos, options, start)

    def _allocation_server(
        self, servos: Sequence[CommandedServo], options: NodeOptions, start: float
    ) -> AllocationServer:
        """The allocation server of this bus: the servos' configured unique ids, the static
        ids it must not hand out and the table kept from the last run."""
        from .alloc import AllocationServer

        configured = {
            bytes.fromhex(servo.options.unique_id): servo.can_id
            for servo in servos
            if servo.options.unique_id is not None
        }
        static = {s.can_id for s in servos if s.options.unique_id is None}
        table = {bytes.fromhex(k): v for k, v in options.allocation_table.items()}
        allocator = AllocationServer(
            self.node_id,
            configured,
            static,
            options.allocation_first_id,
            table,
            max_entries=options.allocation_max_entries,
            expire_s=options.allocation_expire_s,
            start=start,
        )
        if allocator.dropped:
            self._notices.add(
                f"DroneCAN allocation table: {len(allocator.dropped)} entries ignored "
                "(an id of the bridge, of a servo or of another entry): "
                + ", ".join(f"{uid}={nid}" for uid, nid in allocator.dropped[:4])
            )
        return allocator

    @property
    def errors(self) -> Counter[str]:
        """Received transfers addressed to the node that did not decode, by reason."""
        return self._reassembler.errors

    @property
    def foreign_masters(self) -> set[int]:
        """Other nodes reported for sending ArrayCommand on this bus."""
        return self.sharing.foreign_masters

    @property
    def safety_senders(self) -> set[int]:
        """Other nodes reported for broadcasting SafetyState on this bus."""
        return self.sharing.safety_senders

    def _next_tid(self, key: int) -> int:
        tid = self._transfer_ids[key] & 0x1F
        self._transfer_ids[key] = tid + 1
        return tid

    # ---------------------------------------------------------------------------- commands
    def pack(
        self, commands: Sequence[can.Message], in_failsafe: bool | None = False
    ) -> list[can.Message]:
        """One ArrayCommand transfer for up to 15 of the servos' one-command frames (more:
        several transfers), numbered with this node's transfer ids. ``in_failsafe``: every
        command is a failsafe setpoint (the SafetyState plan may turn safety on for it);
        None: releases only, the plan stays as it is."""
        tuples: list[tuple[int, int, float]] = []
        if in_failsafe is not None:
            self.safety.failsafe(in_failsafe)
        for msg in commands:
            known = None
            for index, servo in enumerate(self.servos):
                known = servo.command_of(msg)
                if known is not None:
                    if servo.options.firmware == "ardupilot":
                        self.safety.ardupilot_commanded()
                    release = known[1] == wire.COMMAND_TYPE_PWM and known[2] <= 0
                    self.actuators.commanded(index, release)
                    break
            if known is not None:
                tuples.append(known)
                continue
            received = wire.Reassembler().push(msg, 0.0)
            if received is None or received.dtid != wire.DTID_ARRAY_COMMAND:
                self.counters["bad_command_frame"] += 1
                continue
            tuples += [
                (int(c.actuator_id), int(c.command_type), float(c.command_value))
                for c in received.payload.commands
            ]
        frames: list[can.Message] = []
        step = wire.MAX_COMMANDS_PER_TRANSFER
        for first in range(0, len(tuples), step):
            payload = self._payload(tuples[first : first + step])
            tid = self._next_tid(wire.DTID_ARRAY_COMMAND)
            frames += wire.encode_message(payload, self.node_id, tid, wire.PRIORITY_HIGH)
        self.counters["command_transfers"] += -(-len(tuples) // step)
        return frames

    def _payload(self, commands: list[tuple[int, int, float]]) -> Any:
        """An ArrayCommand carrying ``commands``: one reused object per length, its fields
        replaced (the package's objects cost more to build than to encode)."""
        payload = self._payloads.get(len(commands))
        if payload is None:
            payload = self._payloads[len(commands)] = wire.array_command(commands)
            return payload
        for item, (actuator, kind, value) in zip(payload.commands, commands, strict=True):
            item.actuator_id, item.command_type, item.command_value = actuator, kind, value
        return payload

    # ----------------------------------------------------------------------- own traffic
    def status_payload(self, now: float) -> Any:
        return wire.node_status(now - self.start, self._health, wire.MODE_OPERATIONAL)

    def due(self, now: float, health: NodeHealth) -> list[can.Message]:
        self._health = _HEALTH.get(health, wire.HEALTH_ERROR)
        out, self._queue = self._queue, []
        if now >= self._next_status:
            period = wire.NODE_STATUS_PERIOD_S
            self._next_status += period
            if self._next_status <= now:  # far behind: no burst to catch up
                self._next_status = now + period
            out += wire.encode_message(
                self.status_payload(now),
                self.node_id,
                self._next_tid(wire.DTID_NODE_STATUS),
                wire.PRIORITY_LOW,
            )
            self.counters["node_status"] += 1
        out += self.safety.due(now)
        self.actuators.check(now)
        if self.allocator is not None:
            out += self.allocator.due(now)
            if self.allocator.pool_empty_noted():
                self._notices.add(
                    "DroneCAN allocation: no free node id left to hand out "
                    f"({self.allocator.describe_pool()}); a new node gets none until entries "
                    "expire"
                )
        return out

    def next_due(self) -> float:
        if self._queue or (self.allocator is not None and self.allocator.pending()):
            return -float("inf")
        safety = self.safety.next_due()
        return self._next_status if safety is None else min(self._next_status, safety)

    def stats(self) -> dict[str, int]:
        """Counts for the run summary: the node's own, received transfers that did not decode
        (``rx_<reason>``) and, with the allocator on, requests it ignored or did not answer."""
        out = {k: v for k, v in sorted(self.counters.items()) if v}
        out.update((f"rx_{k}", v) for k, v in sorted(self.errors.items()) if v)
        if self.allocator is not None:
            out["allocation_ignored"] = self.allocator.ignored
            out["allocation_limited"] = self.allocator.limited
            out["allocation_refused"] = self.allocator.refused
            out["allocation_rate_limited"] = self.allocator.rate_limited
            out["allocation_expired"] = self.allocator.expired
        return out

    def take_notices(self) -> list[str]:
        return self._notices.take()

    def describe(self, servo_names: Sequence[str]) -> list[str]:
        """The node's identity and the rule for sharing its bus."""
        actuators = ", ".join(
            f"{name}={servo.options.actuator_id}"
            for name, servo in zip(servo_names, self.servos, strict=False)
        )
        allocator = (
            f"on (free ids from {self.options.allocation_first_id} down)"
            if self.options.allocator
            else "off (static node ids)"
        )
        major, minor = self.software_version
        return [
            f"node id {self.node_id}, name {self.options.name}, NodeStatus 1 Hz, GetNodeInfo "
            f"answered (version {major}.{minor}, unique id {self.unique_id.hex()}); dynamic id "
            f"allocation {allocator}",
            self.safety.plan(),
            *(
                [f"warning: {self.safety.warning()}"]
                if self.safety.ardupilot_nodes and not self.safety.safety_off
                else []
            ),
            f"one ArrayCommand per command slot for actuators {actuators} "
            f"({frames_for_commands(len(self.servos))} frames)",
            "sharing the bus: other DroneCAN nodes (an autopilot's GNSS, ESCs, sensors, another "
            "controller commanding other actuator ids) may share it; no other node may command "
            "these actuator ids (an autopilot with these servos in its outputs): two masters "
            "would fight. The bridge reports every other ArrayCommand sender once (STATUSTEXT, "
            "log), saying whether it commands the bridge's actuators, and every other "
            "SafetyState sender (ArduPilot peripherals obey the last one heard). With the "
            "allocator on, no other allocation server may run on the bus.",
        ]

    def persistent_state(self) -> tuple[int, dict[str, Any]] | None:
        """``(version, allocation table)`` for the bridge to keep next to the config (None:
        no allocator); the table comes back through the ``allocation_table`` option."""
        if self.allocator is None:
            return None
        return self.allocator.version, {"allocation_table": self.allocator.table_hex()}

    def bus_frames_per_second(
        self, servo_count: int, command_hz: float
    ) -> list[tuple[float, bool, int]]:
        """The node's NodeStatus (1 Hz), the packed commands of ``servo_count`` servos at
        ``command_hz`` and its answers at their bounded rates (GetNodeInfo, allocation); the
        profile's per-servo command frames are not counted besides."""
        flows = [
            (1 / wire.NODE_STATUS_PERIOD_S, True, 8),
            (command_hz * frames_for_commands(servo_count), True, 8),
            (GET_NODE_INFO_PER_S * self.node_info_frames(), True, 8),
        ]
        if self.safety.safety_off:  # SafetyState: one single-frame transfer (1 byte and the tail)
            flows.append((1 / SAFETY_PERIOD_S, True, 2))
        if self.allocator is not None:
            from .alloc import ALLOCATION_ANSWER_FRAMES, ALLOCATION_ANSWERS_PER_S

            flows.append((ALLOCATION_ANSWERS_PER_S * ALLOCATION_ANSWER_FRAMES, True, 8))
        return flows

    def node_info_frames(self) -> int:
        """Frames of this node's GetNodeInfo answer (:meth:`.NodeInfoService.frames`)."""
        return self.node_info.frames()

    # -------------------------------------------------------------------------- receiving
    def receive(self, msg: can.Message, now: float) -> bool:
        """Answer GetNodeInfo, note foreign ArrayCommands, serve allocation; True when an
        answer waits to be sent."""
        if not msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame:
            return False
        service = wire.service_fields(msg)
        if service is not None:
            if service.destination != self.node_id or not service.request:
                return False
            received = self._reassembler.push(msg, now)
            if received is None:
                return False
            if received.dtid == wire.DTID_GET_NODE_INFO:
                answer = self.node_info.answer(received, now)
                if answer is None:
                    return False
                self._queue += answer
                return True
            self.counters["unanswered_service"] += 1
            return False
        source = wire.source_node(msg)
        dtid = wire.message_dtid(msg)
        if source == 0:
            if self.allocator is not None and dtid == wire.DTID_ALLOCATION:
                received = self._reassembler.push(msg, now)
                if received is None:
                    return False
                limited = self.allocator.limited
                rate_limited = self.allocator.rate_limited
                answered = bool(self.allocator.receive(received, now))
                if self.allocator.rate_limited != rate_limited:
                    self._notices.once(
                        "allocation_rate",
                        "DroneCAN allocation: unknown unique ids ask for new node ids faster "
                        "than the allocator hands them out: refused (counted in "
                        "allocation_rate_limited); a stranger making up unique ids?",
                    )
                if self.allocator.limited != limited:
                    self._notices.once(
                        "allocation_limited",
                        "anonymous DroneCAN allocation requests come faster than the allocator "
                        "answers: the requests beyond are not answered (counted)",
                    )
                return answered
            return False
        if dtid == wire.DTID_ARRAY_COMMAND:
            # CAN does not echo a sender's own frames: one with the bridge's id is another's
            self.sharing.command(msg, source, now)
        if dtid == wire.DTID_SAFETY_STATE:
            self.sharing.safety(msg, source, now)
        if dtid == wire.DTID_NODE_STATUS:
            self.sharing.node_status(source)
            if self.allocator is not None:
                self.allocator.seen(source, now)
        return False
