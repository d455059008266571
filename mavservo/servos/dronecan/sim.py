"""The simulated DroneCAN actuator node (built-in simulation, ``mavservo sim``), made with the
``dronecan`` package and written from the DroneCAN specification, never from the profile's code
(issue 27): it imports nothing of the ``dronecan`` profile or its ``wire`` module (import-linter
contract ``simulators-apart-from-profiles``), so a framing or field mistake of the profile is
not repeated here. The package encodes and decodes every transfer (tail byte, toggle, transfer
CRC: the specification's transport layer, "CAN bus transport layer"); this module reads the
frame ids (29-bit: priority, data type id, service bit, source node id, the specification's
"CAN ID" tables) and reassembles frames by (id, transfer id) itself.

One :class:`DroneCanDevice` per simulated servo (one actuator); the devices of servos that share
a node id share one :class:`SimNode` (:func:`link_devices`): one NodeStatus, one uptime, one
safety state and one command timeout for all the node's outputs, as on a board with several
outputs. A node takes its actuators' entries from every ``ArrayCommand`` on the bus
(reassembling multi-frame transfers, so a bad CRC or a lost frame loses the command as on a real
node), reports ``uavcan.equipment.actuator.Status`` for its actuator at its status rate (a
two-frame transfer) and ``uavcan.protocol.NodeStatus`` once a second, its health WARNING while a
motor reports a fault. Silencing the simulated servos of a node (``faults: {silent: true}``)
silences the node.

The node's firmware is the servo's ``options.firmware``:

* ``generic`` / ``px4`` (a Hitec, Volz style servo): acts on POSITION (radians), UNITLESS and
  PWM over the options' range, holds its last command, reports its motor's position.
* ``ardupilot``: what ArduPilot's peripheral firmware does with an actuator output (AP_Periph,
  ``Tools/AP_Periph/can.cpp`` ``handle_act_command`` and ``rc_out.cpp``, read for behaviour):
  outputs are off (safety on) until ``ardupilot.indication.SafetyState`` says SAFETY_OFF (255;
  any other value turns safety on again); only UNITLESS (a norm, -1..1) and PWM (us, rounded)
  commands are acted on, anything else is dropped without a word; actuator ``n`` drives output
  ``n`` (ids from 1: 0 is no output); 200 ms without a valid command for any actuator
  (``SRV_CMD_TIME_OUT``, one timeout for the node) zeroes every output it was commanded on (the
  servo goes limp), and a PWM 0 command does it for one output; while commanded, a Status for
  each commanded actuator at most every 100 ms with ``position = radians(norm * 45)``, force and
  speed 0 (its simulation convention), whatever the real output does. The attached servo turns
  the norm into an angle over the options' range (its real travel).

The node answers ``uavcan.protocol.GetNodeInfo`` (DSDL ``uavcan/protocol/1.GetNodeInfo.uavcan``)
addressed to it: its NodeStatus, software and hardware version 1.0, a unique id and a name
(:data:`NODE_NAMES`), back to the asker with the request's transfer id and priority (the
specification's service rules); a request from its own id (a squatter) is not answered.

A servo with ``options.unique_id`` starts without a node id, as such a node does: it sends only
anonymous ``dynamic_node_id.Allocation`` requests (its unique id in three parts, the next part
as soon as the allocator echoes the previous ones, a new first part every second), ignores
commands, and takes the id the allocator hands out.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import can
import dronecan

from ..base import NO_FAULT, ProfileOptions, SimMotor

# --- from the DSDL definitions the dronecan package ships (data type ids are theirs) -----------
_ACTUATOR = dronecan.uavcan.equipment.actuator
_ARRAY_COMMAND = _ACTUATOR.ArrayCommand.default_dtid  # uavcan.equipment.actuator.ArrayCommand
_STATUS = _ACTUATOR.Status.default_dtid  # uavcan.equipment.actuator.Status
_NODE_STATUS = dronecan.uavcan.protocol.NodeStatus.default_dtid  # uavcan.protocol.NodeStatus
_SAFETY_STATE = dronecan.ardupilot.indication.SafetyState.default_dtid
_ALLOCATION = dronecan.uavcan.protocol.dynamic_node_id.Allocation.default_dtid
_GET_NODE_INFO = dronecan.uavcan.protocol.GetNodeInfo.default_dtid  # a service: its own id space
# uavcan.equipment.actuator.Command.command_type constants
_UNITLESS, _POSITION, _PWM = 0, 1, 4
_SAFETY_OFF = 255  # ardupilot.indication.SafetyState.STATUS_SAFETY_OFF
_POWER_RATING_UNKNOWN = 127  # uavcan.equipment.actuator.Status.POWER_RATING_PCT_UNKNOWN
_HEALTH_OK, _HEALTH_WARNING, _MODE_OPERATIONAL = 0, 1, 0  # uavcan.protocol.NodeStatus
# transfer priorities (the specification's 0..31, lower is more urgent)
_PRIORITY_MEDIUM, _PRIORITY_LOW = 16, 24
NODE_STATUS_PERIOD_S = 1.0
"""uavcan.protocol.NodeStatus: ``MAX_BROADCASTING_PERIOD_MS`` is 1000."""
_TRANSFER_TIMEOUT_S = 1.0
"""A transfer whose next frame does not come within this is dropped (its frames forgotten)."""
_MAX_PENDING = 64
_MAX_FRAMES = 64

#: What a simulated node says of itself to ``uavcan.protocol.GetNodeInfo`` (its response
#: section: NodeStatus, software and hardware version, unique id, name). AP_Periph's name is
#: its ``CAN_APP_NODE_NAME`` default (``Tools/AP_Periph/AP_Periph.cpp``); the others are this
#: simulation's own reversed domain name, so a doctor's report never mistakes one for a product.
NODE_NAMES = {"ardupilot": "org.ardupilot.ap_periph"}
GENERIC_NODE_NAME = "org.mavservo.sim.actuator"
SOFTWARE_VERSION = (1, 0)
HARDWARE_VERSION = (1, 0)

# --- AP_Periph (``Tools/AP_Periph``), read for behaviour -------------------------------------
ARDUPILOT_STATUS_PERIOD_S = 0.1
"""AP_Periph's actuator Status period while commanded (10 Hz)."""
ARDUPILOT_COMMAND_TIMEOUT_S = 0.2
"""AP_Periph's ``SRV_CMD_TIME_OUT``: outputs zeroed 200 ms after the last valid command."""
ARDUPILOT_STATUS_DEG = 45.0
"""AP_Periph reports an output's norm as ``position = radians(norm * 45)``."""


def _is_message(msg: can.Message) -> bool:
    """A message frame: 29-bit id, service-not-message bit (bit 7) clear."""
    return bool(msg.is_extended_id) and not msg.is_remote_frame and not msg.arbitration_id & 0x80


def _is_request_to(msg: can.Message, node_id: int | None, service: int) -> bool:
    """A service request frame (29-bit id, bit 7 service, bit 15 request) of data type
    ``service`` (bits 16..23) addressed to ``node_id`` (bits 8..14): the specification's
    "CAN ID" table for service frames."""
    ident = int(msg.arbitration_id)
    return (
        bool(msg.is_extended_id)
        and not msg.is_remote_frame
        and node_id is not None
        and bool(ident & 0x80)
        and bool(ident & 0x8000)
        and (ident >> 8) & 0x7F == node_id
        and (ident >> 16) & 0xFF == service
        and 1 <= ident & 0x7F <= 127
        and ident & 0x7F != node_id  # its own id as the asker: another node squatting it
    )


def _source(msg: can.Message) -> int:
    return int(msg.arbitration_id & 0x7F)


def _message_type(msg: can.Message) -> int:
    """Bits 8..23 of a message frame; an anonymous one (source 0) carries only bits 8..9."""
    if _source(msg) == 0:
        return (msg.arbitration_id >> 8) & 0x3
    return (msg.arbitration_id >> 8) & 0xFFFF


def _frames(transfer: Any) -> list[can.Message]:
    return [
        can.Message(arbitration_id=frame.message_id, is_extended_id=True, data=bytes(frame.bytes))
        for frame in transfer.to_frames()
    ]


def _broadcast(payload: Any, source: int, transfer_id: int, priority: int) -> list[can.Message]:
    """A message transfer of ``payload`` from node ``source`` (0: anonymous), by the package."""
    transfer = dronecan.transport.Transfer(
        transfer_id=transfer_id & 0x1F,
        source_node_id=source,
        payload=payload,
        transfer_priority=priority,
    )
    return _frames(transfer)


class Received(NamedTuple):
    """A whole transfer a node received: its data type id and payload, and for a service
    request whom to answer (the response goes back with the request's transfer id and
    priority: the specification's "service invocation" rules)."""

    dtid: int
    payload: Any
    service: bool
    source: int
    transfer_id: int
    priority: int


class _Transfers:
    """Frames in, decoded payloads out: a node's receive side. Frames are collected by (CAN id,
    transfer id) from a start-of-transfer frame to an end-of-transfer frame (the tail byte);
    the package checks toggles and the transfer CRC and unpacks. A transfer that does not
    decode is dropped, counted in :attr:`dropped`, as a node drops it."""

    def __init__(self) -> None:
        self._pending: dict[tuple[int, int], tuple[float, list[bytes]]] = {}
        self.dropped = 0

    def push(self, msg: can.Message, now: float) -> Received | None:
        """The transfer ``msg`` completes, when it decodes."""
        data = bytes(msg.data)
        if not data:
            return None
        for key in [k for k, (t, _) in self._pending.items() if now - t > _TRANSFER_TIMEOUT_S]:
            del self._pending[key]
        tail = data[-1]
        key = (int(msg.arbitration_id), tail & 0x1F)
        if tail & 0x80:  # start of transfer
            frames = [data]
            self._pending.pop(key, None)
        else:
            pending = self._pending.pop(key, None)
            if pending is None:
                return None  # no start: nothing to add it to
            frames = pending[1] + [data]
        if not tail & 0x40:  # not the end yet
            if len(frames) < _MAX_FRAMES and len(self._pending) < _MAX_PENDING:
                self._pending[key] = (now, frames)
            else:
                self.dropped += 1
            return None
        transfer = dronecan.transport.Transfer()
        try:
            transfer.from_frames(
                [dronecan.transport.Frame(msg.arbitration_id, frame) for frame in frames]
            )
        except Exception:  # a hostile payload may trip anything in the package's decoder
            self.dropped += 1
            return None
        return Received(
            int(transfer.data_type_id),
            transfer.payload,
            bool(transfer.service_not_message),
            int(transfer.source_node_id),
            int(transfer.transfer_id),
            int(transfer.transfer_priority),
        )


class SimNode:
    """What the actuators of one simulated node share (module docstring)."""

    def __init__(self, firmware: str) -> None:
        self.firmware = firmware
        self.members: list[DroneCanDevice] = []
        self.start: float | None = None
        self.next_node_status = -math.inf
        self.transfer_ids: Counter[int] = Counter()
        self.safety_off = firmware != "ardupilot"
        """ArduPilot: outputs off until SAFETY_OFF; other firmware has no safety state."""
        self.last_command: float | None = None
        """ArduPilot: the last ArrayCommand with a command it acts on (its output timeout)."""
        self.transfers = _Transfers()
        self._handled: tuple[can.Message, float] | None = None
        """The last frame reassembled and its time, the frame itself kept (not its ``id()``,
        which a new frame may reuse once the old one is gone)."""

    def tid(self, dtid: int) -> int:
        tid = self.transfer_ids[dtid] & 0x1F
        self.transfer_ids[dtid] = tid + 1
        return tid

    def node_status(self, node_id: int, now: float) -> list[can.Message]:
        """The node's NodeStatus when one is due (whichever member asks first sends it)."""
        if now < self.next_node_status:
            return []
        if self.start is None:
            self.start = now
        self.next_node_status = now + NODE_STATUS_PERIOD_S
        faulty = any(m.motor.active_faults != NO_FAULT for m in self.members)
        status = dronecan.uavcan.protocol.NodeStatus(
            uptime_sec=max(0, min(0xFFFFFFFF, int(now - self.start))),
            health=_HEALTH_WARNING if faulty else _HEALTH_OK,
            mode=_MODE_OPERATIONAL,
            sub_mode=0,
            vendor_specific_status_code=0,
        )
        return _broadcast(status, node_id, self.tid(_NODE_STATUS), _PRIORITY_LOW)

    def node_info(self, node_id: int, request: Received, now: float) -> list[can.Message]:
        """The response to a GetNodeInfo request: who the node is (module constants; the
        unique id its first member's configured one, else derived from the node id)."""
        if self.start is None:
            self.start = now
        response = dronecan.uavcan.protocol.GetNodeInfo.Response(
            name=NODE_NAMES.get(self.firmware, GENERIC_NODE_NAME)
        )
        response.status.uptime_sec = max(0, min(0xFFFFFFFF, int(now - self.start)))
        faulty = any(m.motor.active_faults != NO_FAULT for m in self.members)
        response.status.health = _HEALTH_WARNING if faulty else _HEALTH_OK
        response.status.mode = _MODE_OPERATIONAL
        response.software_version.major, response.software_version.minor = SOFTWARE_VERSION
        response.hardware_version.major, response.hardware_version.minor = HARDWARE_VERSION
        unique = self.members[0].unique_id or b"mavservo-sim" + node_id.to_bytes(4, "big")
        response.hardware_version.unique_id = list(unique[:16].ljust(16, b"\0"))
        transfer = dronecan.transport.Transfer(
            transfer_id=request.transfer_id,
            source_node_id=node_id,
            dest_node_id=request.source,
            payload=response,
            transfer_priority=request.priority,
            service_not_message=True,
            request_not_response=False,
        )
        return _frames(transfer)

    def receive(self, msg: can.Message, now: float) -> Received | None:
        """Reassemble a frame once for the whole node (each member is handed the same frame)."""
        if self._handled is not None and self._handled[0] is msg and self._handled[1] == now:
            return None
        self._handled = (msg, now)
        return self.transfers.push(msg, now)

    def timed_out(self, now: float) -> bool:
        """ArduPilot: no valid command for ``SRV_CMD_TIME_OUT``: its outputs are zeroed."""
        return (
            self.firmware == "ardupilot"
            and self.last_command is not None
            and now - self.last_command >= ARDUPILOT_COMMAND_TIMEOUT_S
        )


def link_devices(devices: Sequence[object]) -> None:
    """Devices of servos on one node id share that node (static ids; a servo that asks for
    an id by allocation is a node of its own)."""
    nodes: dict[int, SimNode] = {}
    for device in devices:
        if not isinstance(device, DroneCanDevice) or device.unique_id is not None:
            continue
        assert device.node_id is not None
        node = nodes.get(device.node_id)
        if node is None:
            nodes[device.node_id] = device.node
            continue
        node.members.append(device)
        device.node = node


@dataclass(frozen=True)
class NodeSettings:
    """The servo's options as this node reads them (its configuration, ``model_dump()``)."""

    firmware: str
    actuator_id: int
    unique_id: str | None
    unitless_min_deg: float
    unitless_max_deg: float
    pwm_min_us: float
    pwm_max_us: float

    @classmethod
    def of(cls, options: ProfileOptions) -> NodeSettings:
        values = options.model_dump()
        return cls(
            firmware=str(values["firmware"]),
            actuator_id=int(values["actuator_id"]),
            unique_id=values.get("unique_id"),
            unitless_min_deg=float(values["unitless_min_deg"]),
            unitless_max_deg=float(values["unitless_max_deg"]),
            pwm_min_us=float(values["pwm_min_us"]),
            pwm_max_us=float(values["pwm_max_us"]),
        )


class DroneCanDevice:
    """One actuator of a simulated node, on a :class:`SimMotor` (module docstring)."""

    pushes = True

    def __init__(self, motor: SimMotor, node_id: int, options: ProfileOptions) -> None:
        self.motor = motor
        self.options = NodeSettings.of(options)
        self.unique_id = bytes.fromhex(self.options.unique_id) if self.options.unique_id else None
        self.node_id: int | None = None if self.unique_id else node_id
        self._next_request = -math.inf
        self.node = SimNode(self.options.firmware)
        self.node.members.append(self)
        self._allocation_transfers = _Transfers()
        self.commands_seen = 0
        self.norm: float | None = None
        """ArduPilot: the output's last commanded norm (-1..1), None: never commanded."""
        self.output_on = False
        """ArduPilot: the output drives the servo (commanded, safety off, not timed out)."""
        self.pulse_off = False
        """ArduPilot: the last command was PWM 0 (the output sends no pulse: the servo is limp
        until a command with a pulse comes)."""
        self._reported_at = -math.inf
        self._commanded_since_report = False

    @property
    def ardupilot(self) -> bool:
        return self.options.firmware == "ardupilot"

    def accepts(self, msg: can.Message) -> bool:
        if self.answers(msg):
            return True
        if not _is_message(msg) or _source(msg) in (0, self.node_id):
            return False
        if not self.node_id:
            return _message_type(msg) == _ALLOCATION
        return _message_type(msg) in (_ARRAY_COMMAND, _SAFETY_STATE)

    def answers(self, msg: can.Message) -> bool:
        """A GetNodeInfo request to this node (a service frame: :meth:`accepts` takes
        messages only)."""
        return _is_request_to(msg, self.node_id, _GET_NODE_INFO)

    def handle(self, msg: can.Message, now: float) -> list[can.Message]:
        if not self.node_id:
            received = self._allocation_transfers.push(msg, now)
            if received is not None and received[0] == _ALLOCATION:
                return self._allocation_answer(received[1])
            return []
        received = self.node.receive(msg, now)
        if received is not None and received.service:
            if received.dtid == _GET_NODE_INFO and self.answers(msg):
                return self.node.node_info(self.node_id, received, now)
            return []
        if received is not None:
            for member in self.node.members:
                member._take(received[0], received[1], now)
        return []

    def _take(self, dtid: int, payload: Any, now: float) -> None:
        """A whole transfer the node received, for this member's actuator."""
        if dtid == _SAFETY_STATE:
            self.node.safety_off = int(payload.status) == _SAFETY_OFF
            self._drive(now)
            return
        if dtid != _ARRAY_COMMAND:
            return
        for command in payload.commands:
            kind, value = int(command.command_type), float(command.command_value)
            if self.ardupilot and kind in (_UNITLESS, _PWM):
                self.node.last_command = now  # any command it acts on feeds the timeout
            if int(command.actuator_id) != self.options.actuator_id:
                continue
            if self.ardupilot:
                self._ardupilot_command(kind, value, now)
                continue
            angle = self._angle(kind, value)
            if angle is not None:
                self.commands_seen += 1
                self.motor.command_position(angle, None, now)

    def _angle(self, command_type: int, value: float) -> float | None:
        """A generic servo: its command as an angle over the options' range."""
        if not math.isfinite(value):
            return None
        if command_type == _POSITION:
            return math.degrees(value)
        if command_type == _UNITLESS:
            return self._norm_angle(max(-1.0, min(1.0, value)))
        if command_type == _PWM:
            return self._norm_angle(self._pwm_norm(value))
        return None  # force, speed: not a position servo's business

    def _norm_angle(self, norm: float) -> float:
        o = self.options
        return o.unitless_min_deg + (norm + 1.0) / 2.0 * (o.unitless_max_deg - o.unitless_min_deg)

    def _pwm_norm(self, pulse_us: float) -> float:
        """A pulse as the -1..1 of the output's range, trim in the middle (ArduPilot's
        ``SERVOn_MIN/TRIM/MAX``, here ``pwm_min_us``/``pwm_max_us``)."""
        o = self.options
        trim = (o.pwm_min_us + o.pwm_max_us) / 2.0
        half = (o.pwm_max_us - o.pwm_min_us) / 2.0
        return max(-1.0, min(1.0, (pulse_us - trim) / half))

    def _ardupilot_command(self, kind: int, value: float, now: float) -> None:
        if self.options.actuator_id == 0 or not math.isfinite(value):
            return  # output 1 << (0 - 1): none
        if kind == _UNITLESS:
            self.norm = max(-1.0, min(1.0, value))
        elif kind == _PWM:
            pulse = int(value + 0.5)
            self.pulse_off = pulse <= 0  # PWM 0: no pulse (what the board's timeout writes)
            if not self.pulse_off:
                self.norm = self._pwm_norm(float(pulse))
        else:
            return
        if kind == _UNITLESS:
            self.pulse_off = False
        self.commands_seen += 1
        self._commanded_since_report = True
        self._drive(now)

    def _drive(self, now: float) -> None:
        """ArduPilot: the output drives the servo only when commanded, with safety off and
        within the command timeout; otherwise PWM 0: the servo goes limp."""
        if not self.ardupilot or self.norm is None:
            return
        on = self.node.safety_off and not self.node.timed_out(now) and not self.pulse_off
        if on:
            if not self.output_on:
                self.motor.enable(now)
            self.motor.command_position(self._norm_angle(self.norm), None, now)
        elif self.output_on:
            self.motor.disable(now)
        self.output_on = on

    def _tid(self, dtid: int) -> int:
        return self.node.tid(dtid)

    def _allocation_request(self, part: bytes, first: bool) -> list[can.Message]:
        assert self.unique_id is not None
        allocation = dronecan.uavcan.protocol.dynamic_node_id.Allocation()
        allocation.node_id = 0  # no preference
        allocation.first_part_of_unique_id = first
        allocation.unique_id.from_bytes(part)
        discriminator = int.from_bytes(self.unique_id[:2], "little")
        transfer = dronecan.transport.Transfer(
            transfer_id=self._tid(_ALLOCATION) & 0x1F,
            source_node_id=0,
            payload=allocation,
            transfer_priority=_PRIORITY_LOW,
            discriminator=discriminator & 0x3FFF,
        )
        return _frames(transfer)

    def _allocation_answer(self, answer: Any) -> list[can.Message]:
        """The allocator echoed part of a unique id, or handed out an id."""
        if self.node_id is not None or self.unique_id is None:
            return []
        echoed = bytes(answer.unique_id.to_bytes())
        if not echoed or not self.unique_id.startswith(echoed):
            return []  # another node's exchange
        node_id = int(answer.node_id)
        if len(echoed) == len(self.unique_id):
            if node_id:
                self.node_id = node_id
            return []
        return self._allocation_request(self.unique_id[len(echoed) : len(echoed) + 6], False)

    def status(self, now: float) -> list[can.Message]:
        if self.node_id is None:
            if now < self._next_request or self.unique_id is None:
                return []
            self._next_request = now + 1.0
            return self._allocation_request(self.unique_id[:6], True)
        self._drive(now)  # the output timeout runs on the node's own clock
        out = self._actuator_status(now)
        return out + self.node.node_status(self.node_id, now)

    def _actuator_status(self, now: float) -> list[can.Message]:
        assert self.node_id is not None
        if self.ardupilot:
            # only while commanded, at most every 100 ms, the norm x 45 deg
            if not self._commanded_since_report or self.norm is None:
                return []
            if now - self._reported_at < ARDUPILOT_STATUS_PERIOD_S - 1e-9:
                return []
            self._reported_at, self._commanded_since_report = now, False
            payload = _ACTUATOR.Status(
                actuator_id=self.options.actuator_id,
                position=math.radians(self.norm * ARDUPILOT_STATUS_DEG),
                force=0.0,
                speed=0.0,
                power_rating_pct=_POWER_RATING_UNKNOWN,
            )
            priority = _PRIORITY_LOW
        else:
            motor = self.motor
            payload = _ACTUATOR.Status(
                actuator_id=self.options.actuator_id,
                position=math.radians(motor.position_deg),
                force=math.nan,
                speed=math.radians(motor.velocity_dps),
                power_rating_pct=_POWER_RATING_UNKNOWN,
            )
            priority = _PRIORITY_MEDIUM
        return _broadcast(payload, self.node_id, self._tid(_STATUS), priority)

    def tick(self, now: float) -> None:
        return None
