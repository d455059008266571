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
dynamic_node_id.Allocation`` for nodes that start without an id, see :mod:`.dronecan_alloc`.
"""

from __future__ import annotations

import re
from collections import Counter, deque
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Literal, Protocol

import can
from pydantic import Field, field_validator, model_validator

from ..base import BusNodeError, NodeHealth, ProfileOptions
from . import wire

if TYPE_CHECKING:  # imported where used at run time: only a bus with the allocator on needs it
    from .alloc import AllocationServer

_HEX32 = re.compile(r"[0-9a-f]{32}")
GET_NODE_INFO_PER_S = 4
"""GetNodeInfo answers per second at most (a tool or node monitor asks once per node it
sees): each answer is about nine frames for a one-frame request, so an unbounded answer rate
would let any node on the bus fill it with the bridge's traffic. Requests beyond are counted
(``get_node_info_limited``) and not answered; the asker asks again."""
_HEALTH = {"ok": wire.HEALTH_OK, "warning": wire.HEALTH_WARNING, "error": wire.HEALTH_ERROR}
SAFETY_PERIOD_S = 0.5
"""``ardupilot.indication.SafetyState`` every 500 ms, as ArduPilot's flight controller sends it
(``AP_DroneCAN``, its 2 Hz safety broadcast); a peripheral that hears nothing keeps its state."""
SENDERS_REPORTED = 8
"""Other nodes reported by name (a second ArrayCommand sender, a SafetyState broadcaster), at
most: a source id costs a stranger nothing, and each report is a WARNING line and a STATUSTEXT;
the senders beyond are counted (``senders_not_reported``) and said once."""
SILENT_ACTUATOR_S = 3.0
"""A servo whose node is alive and which is commanded, but which has sent no report of its
own actuator for this long, is warned about once (its commands are likely ignored)."""


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


class CommandedServoOptions(Protocol):
    """What the node reads of a DroneCAN servo's options (read-only)."""

    @property
    def actuator_id(self) -> int: ...

    @property
    def unique_id(self) -> str | None: ...

    @property
    def firmware(self) -> str: ...

    @property
    def command(self) -> str: ...


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
    """The bridge's node on one bus (module docstring)."""

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
        self.safety_off = options.safety_state == "safety_off"
        """The SafetyState plan: broadcast at all (SAFETY_OFF from start)."""
        self._safety_next = start
        self._safety_sent: bool | None = None
        self._failsafe = False
        self._commanded_since: dict[int, float | None] = {}
        """Servo index -> when the node first saw it commanded (None: in the slot just packed,
        the time comes with the next :meth:`due`)."""
        self._silent_warned: set[int] = set()
        self._packed: set[int] = set()
        """Servo indexes commanded in the slots packed since the last :meth:`due`."""
        self._last_commanded: dict[int, float] = {}
        """Servo index -> when the node last packed a command for it (set in :meth:`due`)."""
        self._stopped_warned: set[int] = set()
        """Servos warned about for a Status that stopped (again once one comes)."""
        if self.safety_off and options.safety_on != "never" and servos:
            servos[0].shutdown_hook = self._safety_on_at_stop
        self.ardupilot_nodes = sorted(
            {s.can_id for s in servos if s.options.firmware == "ardupilot"}
        )
        self._transfer_ids: Counter[int] = Counter()
        self._payloads: dict[int, Any] = {}
        self._reassembler = wire.Reassembler()
        self._queue: list[can.Message] = []
        self._info_answers: deque[float] = deque(maxlen=GET_NODE_INFO_PER_S)
        self._next_status = start
        self._health = wire.HEALTH_OK
        self.counters: Counter[str] = Counter()
        self.foreign_masters: set[int] = set()
        """Other nodes reported for sending ArrayCommand (see :meth:`_foreign_command`)."""
        self._masters_of_ours: set[int] = set()
        """Those of them reported for commanding the bridge's actuators (two masters)."""
        self.safety_senders: set[int] = set()
        """Other nodes reported for broadcasting SafetyState (see :meth:`_foreign_safety`)."""
        self._notices: list[str] = []
        self._safety_warning_due = bool(self.ardupilot_nodes and not self.safety_off)
        """Say it again with the first command: a ground station that connects after the
        start never heard the start's text, and the first command is when it matters."""
        if self._safety_warning_due:
            self._notices.append(self._safety_warning())
        self._conflict_noted = False
        self._noted: set[str] = set()
        self.allocator: AllocationServer | None = None
        if options.allocator:
            from .alloc import AllocationServer

            configured = {
                bytes.fromhex(servo.options.unique_id): servo.can_id
                for servo in servos
                if servo.options.unique_id is not None
            }
            static = {s.can_id for s in servos if s.options.unique_id is None}
            table = {bytes.fromhex(k): v for k, v in options.allocation_table.items()}
            self.allocator = AllocationServer(
                self.node_id,
                configured,
                static,
                options.allocation_first_id,
                table,
                max_entries=options.allocation_max_entries,
                expire_s=options.allocation_expire_s,
                start=start,
            )
            if self.allocator.dropped:
                self._notices.append(
                    f"DroneCAN allocation table: {len(self.allocator.dropped)} entries ignored "
                    "(an id of the bridge, of a servo or of another entry): "
                    + ", ".join(f"{uid}={nid}" for uid, nid in self.allocator.dropped[:4])
                )

    @property
    def errors(self) -> Counter[str]:
        """Received transfers addressed to the node that did not decode, by reason."""
        return self._reassembler.errors

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
            self._failsafe = in_failsafe and self.options.safety_on == "failsafe_and_stop"
        for msg in commands:
            known = None
            for index, servo in enumerate(self.servos):
                known = servo.command_of(msg)
                if known is not None:
                    if self._safety_warning_due and servo.options.firmware == "ardupilot":
                        self._safety_warning_due = False
                        self._notices.append(self._safety_warning())
                    self._commanded_since.setdefault(index, None)
                    if known[1] != wire.COMMAND_TYPE_PWM or known[2] > 0:  # not a release
                        self._packed.add(index)
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
        out += self._safety_due(now)
        self._check_silent_actuators(now)
        if self.allocator is not None:
            out += self.allocator.due(now)
            if self.allocator.pool_empty_noted():
                self._notices.append(
                    "DroneCAN allocation: no free node id left to hand out "
                    f"({self.allocator.describe_pool()}); a new node gets none until entries "
                    "expire"
                )
        return out

    # ------------------------------------------------------------------------- safety
    def _safety_frames(self, off: bool) -> list[can.Message]:
        self._safety_sent = off
        self.counters["safety_off" if off else "safety_on"] += 1
        return wire.encode_message(
            wire.safety_state(off),
            self.node_id,
            self._next_tid(wire.DTID_SAFETY_STATE),
            wire.PRIORITY_LOW,
        )

    def _safety_due(self, now: float) -> list[can.Message]:
        """SafetyState every 500 ms (at once when it changes): SAFETY_OFF, or SAFETY_ON while
        the plan says failsafe and every commanded servo is in failsafe."""
        if not self.safety_off:
            return []
        off = not self._failsafe
        if now < self._safety_next and off == self._safety_sent:
            return []
        self._safety_next = now + SAFETY_PERIOD_S
        return self._safety_frames(off)

    def _safety_on_at_stop(self) -> list[can.Message]:
        """SAFETY_ON once as the bridge stops (the plan's ``stop``): outputs off."""
        return self._safety_frames(False)

    def _safety_warning(self) -> str:
        nodes = ", ".join(map(str, self.ardupilot_nodes))
        return (
            f"DroneCAN nodes {nodes} run ArduPilot firmware, which keeps its outputs off until "
            "it hears SafetyState SAFETY_OFF, and the bridge sends none (safety_state: none): "
            "their servos will not move; set node.dronecan.safety_state: safety_off"
        )

    def safety_plan(self) -> str:
        """The SafetyState plan, as ``check`` prints it."""
        if not self.safety_off:
            return (
                "SafetyState: not sent (safety_state: none): ArduPilot peripherals (AP_Periph) "
                "keep their outputs off; other DroneCAN servos do not care"
            )
        on = {
            "stop": "SAFETY_ON when the bridge stops",
            "failsafe_and_stop": "SAFETY_ON while every servo of the bus is in failsafe and "
            "when the bridge stops",
            "never": "never SAFETY_ON (outputs stay enabled after the bridge stops; "
            "ArduPilot peripherals still zero them 200 ms after the last command)",
        }[self.options.safety_on]
        return (
            f"SafetyState: SAFETY_OFF every {SAFETY_PERIOD_S * 1000:g} ms from start (as "
            f"ArduPilot's flight controller); {on}"
        )

    # ------------------------------------------------------------------------- silence
    def _check_silent_actuators(self, now: float) -> None:
        """Warn once per servo whose node is alive and which is commanded but never reports
        its actuator: the node ignores the command (a command type it does not act on, an
        actuator id it does not have); and once per episode for one that did report and
        stopped while its node goes on (:meth:`_check_stopped_actuators`)."""
        for index in self._packed:
            self._last_commanded[index] = now
        self._packed.clear()
        self._check_stopped_actuators(now)
        for index, since in list(self._commanded_since.items()):
            if since is None:
                self._commanded_since[index] = now
                continue
            servo = self.servos[index]
            if index in self._silent_warned or servo.actuator_reported_at is not None:
                continue
            alive = servo.node_heard_at
            if alive is None or now - max(since, alive) < SILENT_ACTUATOR_S:
                continue
            self._silent_warned.add(index)
            self.counters["silent_actuators"] += 1
            options = servo.options
            if options.firmware == "ardupilot":
                # AP_Periph sends actuator Status only as a SITL build (rc_out.cpp,
                # sim_update_actuator) or with its actuator telemetry set up (actuator_telem.cpp,
                # no position): a real board that drives its outputs is silent here
                self._notices.append(
                    f"DroneCAN node {servo.can_id} is alive but never reports Status for "
                    f"actuator {options.actuator_id}: expected of a real AP_Periph board (it "
                    "sends actuator Status only as a SITL build, or with its ACT telemetry set "
                    "up): the position is not known, the servo is online on NodeStatus alone; "
                    "if the node is a SITL build, check the actuator id"
                )
                continue
            self._notices.append(
                f"DroneCAN node {servo.can_id} is alive but never reports Status for actuator "
                f"{options.actuator_id}: commands ignored? check the command type (command: "
                f"{options.command}; ArduPilot peripherals act on unitless and pwm only) and "
                "the actuator id"
            )

    def _check_stopped_actuators(self, now: float) -> None:
        """An actuator that reported and has sent nothing for :data:`SILENT_ACTUATOR_S` while
        it is commanded and its node's NodeStatus goes on: the servo stays online on that
        NodeStatus, its last position shown as if current, so the crew is told (once per
        episode; a report ends it). A released servo is not commanded: an ArduPilot SITL node
        stops its Status then, as it should."""
        for index, servo in enumerate(self.servos):
            reported = servo.actuator_reported_at
            if reported is None:
                continue
            if now - reported < SILENT_ACTUATOR_S:
                self._stopped_warned.discard(index)
                continue
            commanded = self._last_commanded.get(index)
            node = servo.node_last_heard
            if (
                index in self._stopped_warned
                or commanded is None
                or now - commanded > 1.0
                or node is None
                or now - node > SILENT_ACTUATOR_S
            ):
                continue
            self._stopped_warned.add(index)
            self.counters["stopped_actuators"] += 1
            self._notices.append(
                f"DroneCAN node {servo.can_id} is alive but actuator "
                f"{servo.options.actuator_id} has sent no Status for {now - reported:.0f} s "
                "while commanded: its position shown is that old (the servo stays online on the "
                "node's NodeStatus); a failed actuator or a broken output?"
            )

    def next_due(self) -> float:
        if self._queue or (self.allocator is not None and self.allocator.pending()):
            return -float("inf")
        if self.safety_off:
            return min(self._next_status, self._safety_next)
        return self._next_status

    def _notice_once(self, kind: str, text: str) -> None:
        """A notice the first time something of ``kind`` happens (the count goes on)."""
        if kind not in self._noted:
            self._noted.add(kind)
            self._notices.append(text)

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
        notices, self._notices = self._notices, []
        return notices

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
            self.safety_plan(),
            *(
                [f"warning: {self._safety_warning()}"]
                if self.ardupilot_nodes and not self.safety_off
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
        if self.safety_off:  # SafetyState: one single-frame transfer (1 byte and the tail)
            flows.append((1 / SAFETY_PERIOD_S, True, 2))
        if self.allocator is not None:
            from .alloc import ALLOCATION_ANSWER_FRAMES, ALLOCATION_ANSWERS_PER_S

            flows.append((ALLOCATION_ANSWERS_PER_S * ALLOCATION_ANSWER_FRAMES, True, 8))
        return flows

    def node_info_frames(self) -> int:
        """Frames of this node's GetNodeInfo answer: NodeStatus (7 bytes), software version
        (15), hardware version with an empty certificate (19), the name (tail array, no length
        byte), the transfer CRC; 7 bytes a frame."""
        return -(-(7 + 15 + 19 + len(self.options.name) + 2) // 7)

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
                answers = self._info_answers
                if len(answers) == answers.maxlen and now - answers[0] < 1.0:
                    self.counters["get_node_info_limited"] += 1
                    self._notice_once(
                        "get_node_info_limited",
                        f"DroneCAN node {received.source} asks GetNodeInfo faster than "
                        f"{GET_NODE_INFO_PER_S}/s: the requests beyond are not answered "
                        "(counted in get_node_info_limited)",
                    )
                    return False
                answers.append(now)
                self._queue += self._node_info_response(received, now)
                self.counters["get_node_info"] += 1
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
                    self._notice_once(
                        "allocation_rate",
                        "DroneCAN allocation: unknown unique ids ask for new node ids faster "
                        "than the allocator hands them out: refused (counted in "
                        "allocation_rate_limited); a stranger making up unique ids?",
                    )
                if self.allocator.limited != limited:
                    self._notice_once(
                        "allocation_limited",
                        "anonymous DroneCAN allocation requests come faster than the allocator "
                        "answers: the requests beyond are not answered (counted)",
                    )
                return answered
            return False
        if dtid == wire.DTID_ARRAY_COMMAND:
            # CAN does not echo a sender's own frames: one with the bridge's id is another's
            self._foreign_command(msg, source, now)
        if dtid == wire.DTID_SAFETY_STATE:
            self._foreign_safety(msg, source, now)
        if dtid == wire.DTID_NODE_STATUS and source == self.node_id:
            self.counters["node_id_conflict"] += 1
            if not self._conflict_noted:
                self._conflict_noted = True
                self._notices.append(
                    f"another DroneCAN node sends NodeStatus with the bridge's node id "
                    f"{self.node_id}: give one of them another id"
                )
        if self.allocator is not None and dtid == wire.DTID_NODE_STATUS:
            self.allocator.seen(source, now)
        return False

    def _foreign_command(self, msg: can.Message, source: int, now: float) -> None:
        """Another node's ArrayCommand: reported once per sender, saying whether it commands
        the bridge's actuators (two masters) or others (a second controller, maybe intended)."""
        self.counters["foreign_commands"] += 1
        if source == self.node_id:
            self.counters["own_id_commands"] += 1
        received = self._reassembler.push(msg, now)
        if received is None or source in self._masters_of_ours:
            return
        ours = {servo.options.actuator_id for servo in self.servos}
        theirs = sorted({int(c.actuator_id) for c in received.payload.commands})
        shared = [a for a in theirs if a in ours]
        if source in self.foreign_masters and not shared:
            return  # reported already; a sender that turns to the bridge's actuators is again
        if not self._may_report(source):
            return
        self.foreign_masters.add(source)
        if shared:
            self._masters_of_ours.add(source)
        if source == self.node_id:
            self._notices.append(
                f"another DroneCAN node sends ArrayCommand with the bridge's own node id "
                f"{source} (CAN does not echo the bridge's frames), for actuators "
                f"{', '.join(map(str, theirs))}"
                + (f", the bridge's {', '.join(map(str, shared))}" if shared else "")
                + ": a spoofed or misconfigured sender (counted in own_id_commands)"
            )
        elif shared:
            self._notices.append(
                f"DroneCAN node {source} also sends ArrayCommand for actuators "
                f"{', '.join(map(str, shared))} (the bridge's): two masters command these "
                "servos (an autopilot?); give them one master"
            )
        else:
            self._notices.append(
                f"DroneCAN node {source} also sends ArrayCommand on this bus, for actuators "
                f"{', '.join(map(str, theirs))} (not the bridge's)"
            )

    def _may_report(self, source: int) -> bool:
        """True while another sender may still be reported by name (:data:`SENDERS_REPORTED`
        distinct nodes; one already reported always may); beyond, counted and said once."""
        reported = self.foreign_masters | self.safety_senders
        if source in reported or len(reported) < SENDERS_REPORTED:
            return True
        self.counters["senders_not_reported"] += 1
        self._notice_once(
            "senders_not_reported",
            f"more than {SENDERS_REPORTED} other DroneCAN nodes send ArrayCommand or "
            "SafetyState on this bus: the others are counted (senders_not_reported), not "
            "reported one by one (a stranger making up node ids?)",
        )
        return False

    def _foreign_safety(self, msg: can.Message, source: int, now: float) -> None:
        """Another node's ``ardupilot.indication.SafetyState``: an ArduPilot peripheral obeys
        the last one it hears, so a flight controller (or a stranger) broadcasting it on this
        bus turns the outputs on or off whatever the bridge's plan; reported once per sender,
        every one counted (``foreign_safety_state``)."""
        self.counters["foreign_safety_state"] += 1
        received = self._reassembler.push(msg, now)
        if received is None or received.dtid != wire.DTID_SAFETY_STATE:
            return
        if source in self.safety_senders or not self._may_report(source):
            return
        self.safety_senders.add(source)
        state = "SAFETY_OFF" if int(received.payload.status) == wire.SAFETY_OFF else "SAFETY_ON"
        who = (
            f"another DroneCAN node sends SafetyState with the bridge's own node id {source}"
            if source == self.node_id
            else f"DroneCAN node {source} also broadcasts SafetyState"
        )
        plan = (
            "the bridge's SAFETY_OFF and its SafetyState fight"
            if self.safety_off
            else "the bridge sends none (safety_state: none)"
        )
        self._notices.append(
            f"{who} ({state}): ArduPilot peripherals obey the last one heard, so their outputs "
            f"follow that node, not the bridge's plan ({plan}); only one node may own the "
            "safety state of the bus (a flight controller's CAN driver sends it every 500 ms)"
        )

    def _node_info_response(self, request: wire.Received, now: float) -> list[can.Message]:
        info = wire.lib().uavcan.protocol.GetNodeInfo.Response()
        info.status = self.status_payload(now)
        info.software_version.major, info.software_version.minor = self.software_version
        info.hardware_version.unique_id.from_bytes(self.unique_id)
        info.name = self.options.name
        return wire.encode_service(
            info,
            source=self.node_id,
            destination=request.source,
            transfer_id=request.transfer_id,
            request=False,
            priority=request.priority,  # a response keeps its request's priority
        )
