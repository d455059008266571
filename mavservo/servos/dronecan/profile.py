"""DroneCAN actuators: single-actuator servos (Hitec, Volz, HiMark, MKS...) and nodes with
several outputs (ArduPilot's peripheral firmware, AP_Periph), one profile per actuator.

Wire facts (DroneCAN specification, DSDL ``uavcan.equipment.actuator``; serialization and
framing by the ``dronecan`` package through :mod:`.dronecan_wire`):

* commands: ``uavcan.equipment.actuator.ArrayCommand`` (1010), a broadcast of up to 15
  ``(actuator_id, command_type, float16 value)``; the servos of one bus share it, so the
  bridge's node on that bus (:mod:`.dronecan_node`) packs every command of a slot into one
  transfer (several past 15) instead of one frame per servo; it is their keep-alive too;
* feedback: ``uavcan.equipment.actuator.Status`` (1011: position rad, force, speed rad/s),
  Volz ``com.volz.servo.ActuatorStatus`` (20020: position rad, current 0.025 A, voltage 0.2 V,
  motor temperature +50 degC), HiMark ``com.himark.servo.ServoInfo`` (2019: position 0.01 deg,
  voltage 0.01 V, current 0.01 A, motor temperature 0.2 degC - 40, an error status); each is
  matched to this servo by source node id and actuator id (the status of a sibling, another
  configured servo on the node, is the sibling's; of an actuator nobody configured on the node,
  counted as ``other_actuator``, not a state: the node is set to another id);
* liveness: ``uavcan.protocol.NodeStatus`` (341), 1 Hz from every node; silent for about 3 s a
  node is gone (:attr:`DroneCanServo.heartbeat_period_s` makes the scheduler's silence limit
  ``offline_after_missed`` heartbeats). Its health and mode become faults: a health other
  than OK, or a mode other than operational or initialization, is :attr:`Fault.OTHER`. Its
  uptime only goes up: one that went back (a restart, or a second node on the id) is counted
  (``uptime_backwards``, a rejected frame) and is no sign of life. A NodeStatus answers no
  command (:meth:`DroneCanServo.is_liveness_only`): anyone can send one with the node's id.

The servo id (``can_id``) is the servo's node id, 1..127. ``actuator_id`` is the number on the
wire, as the servo is configured: **ArduPilot numbers actuators from 1** (``SERVOn`` with a
DroneCAN function goes out as actuator ``n``), **PX4 from 0** (its first output is actuator 0),
so a servo set up for one autopilot keeps that autopilot's number here; ``options.firmware``
names the convention (``check`` warns about actuator 0 unless it is PX4's). Several servos may
share a node id, each on its own actuator id (the bus node refuses one actuator id twice): they
share the node's pushes (their identifiers are ``shared``), each takes its own.

Command types: ``position`` sends radians (``COMMAND_TYPE_POSITION``); ``unitless`` maps
``[unitless_min_deg, unitless_max_deg]`` onto ``[-1, 1]`` (``COMMAND_TYPE_UNITLESS``), for
servos that take only a normalised command; ``pwm`` maps the same range onto
``[pwm_min_us, pwm_max_us]`` (``COMMAND_TYPE_PWM``, whole microseconds); angles outside that
range are refused (COMMAND_ACK DENIED), never clamped. ArduPilot peripherals act on UNITLESS and
PWM only and report ``norm x 45 deg`` (``firmware: ardupilot`` presets the range to +-45 deg;
over another range the reported norm is read back through that range).

Received frames are reassembled per servo (a Status transfer is two frames); a frame that
starts or continues a transfer decodes to the last known state and does not complete a report
(:meth:`DroneCanServo.completes_report`: the scheduler waits for the transfer's last frame), a
transfer that does not reassemble (CRC, toggle, unknown type, truncation) decodes to None,
counted by reason in :attr:`DroneCanServo.errors`.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any, ClassVar, Literal

import can
from pydantic import Field, model_validator

from ..base import (
    NO_FAULT,
    Fault,
    FrameId,
    ProfileOptions,
    ServoProfile,
    ServoState,
    SimDevice,
    SimMotor,
)
from ..sim_registry import link_simulated_devices, simulated_device
from . import wire
from .node import BridgeNode, NodeOptions

_DTID_MASK = 0xFFFF << 8
_FEEDBACK = (
    wire.DTID_NODE_STATUS,
    wire.DTID_ACTUATOR_STATUS,
    wire.DTID_VOLZ_STATUS,
    wire.DTID_HIMARK_INFO,
)
_FEEDBACK_SET = frozenset(_FEEDBACK)
_COMMANDS_REMEMBERED = 16
"""Recent command frames a profile can name the command of (setpoints waiting for a slot)."""
PLACEHOLDER_BRIDGE_ID = 127
"""Source id of a command frame built before the bus node adopted the servo (``check``)."""


Firmware = Literal["generic", "ardupilot", "px4"]
ARDUPILOT_UNITLESS_DEG = 45.0
"""ArduPilot's convention for a unitless command (AP_Periph, ``Tools/AP_Periph/rc_out.cpp``,
``sim_update_actuator``): the Status it reports carries ``position = radians(norm * 45)``, so
a command of 1.0 reads back as 45 deg; the ``ardupilot`` preset maps +-45 deg onto +-1."""
ARDUPILOT_COMMAND_TIMEOUT_S = 0.2
"""AP_Periph's ``SRV_CMD_TIME_OUT`` default (ms 200): with no valid ArrayCommand for this long
it writes PWM 0 on every output it was commanded on (``rc_out.cpp``, ``rcout_update``)."""


class DroneCanOptions(ProfileOptions):
    """Per-servo ``options:`` of a DroneCAN actuator."""

    firmware: Firmware = Field(
        "generic",
        description="the node's firmware convention: ardupilot (AP_Periph: actuator ids from 1, "
        "acts on unitless and pwm only, outputs off until SafetyState SAFETY_OFF, zeroed "
        "200 ms after the last command, Status position = norm x 45 deg), px4 (ids from 0), "
        "generic (a single-actuator servo: Hitec, Volz, HiMark...)",
    )
    actuator_id: int = Field(
        1,
        ge=0,
        le=255,
        description="actuator id on the wire as the servo is configured (ArduPilot numbers "
        "from 1, PX4 from 0)",
    )
    command: Literal["position", "unitless", "pwm"] = Field(
        "position",
        description="POSITION in radians, UNITLESS [-1, 1] over the range below, or PWM "
        "[pwm_min_us, pwm_max_us] over the range below",
    )
    unitless_min_deg: float = Field(
        -90.0,
        ge=-3600,
        le=3600,
        description="angle sent as -1 in unitless mode (pwm_min_us in pwm mode); firmware "
        "ardupilot: -45 unless set",
    )
    unitless_max_deg: float = Field(
        90.0,
        ge=-3600,
        le=3600,
        description="angle sent as +1 in unitless mode (pwm_max_us in pwm mode); firmware "
        "ardupilot: 45 unless set",
    )
    pwm_min_us: int = Field(
        1000, ge=500, le=2500, description="pulse width sent for unitless_min_deg (pwm mode)"
    )
    pwm_max_us: int = Field(
        2000, ge=500, le=2500, description="pulse width sent for unitless_max_deg (pwm mode)"
    )

    unique_id: str | None = Field(
        None,
        pattern=r"^[0-9a-f]{32}$",
        description="the servo's 16-byte unique id (32 hex digits): it has no static node id "
        "and gets can_id from the bridge's allocator (node.dronecan.allocator: true)",
    )

    @model_validator(mode="before")
    @classmethod
    def _firmware_preset(cls, data: Any) -> Any:
        """``firmware: ardupilot`` brings ArduPilot's unitless scaling (+-45 deg) unless the
        range is given: with the generic +-90 every position would read back half."""
        if isinstance(data, dict) and data.get("firmware") == "ardupilot":
            data = dict(data)
            data.setdefault("unitless_min_deg", -ARDUPILOT_UNITLESS_DEG)
            data.setdefault("unitless_max_deg", ARDUPILOT_UNITLESS_DEG)
        return data

    @model_validator(mode="after")
    def _range_ordered(self) -> DroneCanOptions:
        if not self.unitless_min_deg < self.unitless_max_deg:
            raise ValueError("unitless_min_deg must be below unitless_max_deg")
        if not self.pwm_min_us < self.pwm_max_us:
            raise ValueError("pwm_min_us must be below pwm_max_us")
        if self.firmware == "ardupilot":
            if self.command == "position":
                raise ValueError(
                    "firmware ardupilot acts on unitless and pwm commands only (AP_Periph drops "
                    "a position command without a word): set command: unitless or pwm"
                )
            if self.actuator_id == 0:
                raise ValueError(
                    "firmware ardupilot numbers actuators from 1 (SERVOn -> actuator n): "
                    "actuator 0 is no output of the node"
                )
        return self


class DroneCanServo(ServoProfile):
    """A DroneCAN actuator node; commanded through its bus's ArrayCommand, reporting on its own."""

    name = "dronecan"
    telemetry = "pushed"
    replies_per_command = 0
    replies_per_request = 0
    min_id, max_id = 1, 127
    resolution_deg = 0.23
    """float16 in radians: a step of 2**-8 rad (0.22 deg) between 4 and 8 rad, finer below;
    position mode is held to +-360 deg (a servo's range, and where float16 still resolves it)."""
    min_angle_deg, max_angle_deg = -360.0, 360.0
    heartbeat_period_s: ClassVar[float] = wire.NODE_STATUS_PERIOD_S
    frames_per_push: ClassVar[int] = 2
    """A Status transfer is two frames (8 payload bytes and the tail byte)."""
    Options: ClassVar[type[ProfileOptions]] = DroneCanOptions
    options: DroneCanOptions

    def __init__(self, can_id: int, options: ProfileOptions | None = None, **overrides: Any):
        super().__init__(can_id, options, **overrides)
        o = self.options
        if o.command in ("unitless", "pwm"):
            self.min_angle_deg, self.max_angle_deg = o.unitless_min_deg, o.unitless_max_deg
        self.bridge_node_id = PLACEHOLDER_BRIDGE_ID
        """The source id of the command frames: set by the bus node that adopts the servo."""
        self._reassembler = wire.Reassembler(reuse_payloads=True)  # _apply is done with each
        self._payload: Any = None
        self._sent: dict[bytes, tuple[int, int, float]] = {}
        self._health_faults = NO_FAULT
        self._vendor_faults = NO_FAULT
        self.node_health: int | None = None
        self.node_mode: int | None = None
        self.node_uptime: int | None = None
        """The uptime of the latest NodeStatus (s): it only goes up while one node has this id."""
        self.node_actuators: frozenset[int] = frozenset({self.options.actuator_id})
        """Actuator ids of every configured servo on this node id (set by the bus node): a
        node with several outputs (an AP_Periph board) reports each of them, and a sibling's
        Status is the sibling's, not a stranger's."""
        self._skipping: set[tuple[int, int]] = set()
        """Transfers of a sibling's Status under way (see :meth:`_siblings_status`)."""
        self.node_heard_at: float | None = None
        """When the node's first NodeStatus came (None: not yet)."""
        self.node_last_heard: float | None = None
        """When the node's latest NodeStatus came (None: not yet)."""
        self.actuator_reported_at: float | None = None
        """When this actuator's last report (Status, vendor status) came (None: never)."""
        self.shutdown_hook: Callable[[], list[can.Message]] | None = None
        """Frames the bus node wants sent when the bridge stops (its SafetyState plan), set
        on one servo of the node; None: none."""

    @property
    def errors(self) -> Counter[str]:
        """Transfers from this servo's node that did not decode, by reason."""
        return self._reassembler.errors

    # ------------------------------------------------------------------------- commands
    def command_tuple(self, angle_deg: float) -> tuple[int, int, float]:
        """``(actuator_id, command_type, value)`` for ``angle_deg`` (validated)."""
        self._check_angle(angle_deg)
        o = self.options
        if o.command == "position":
            return o.actuator_id, wire.COMMAND_TYPE_POSITION, math.radians(angle_deg)
        fraction = (angle_deg - o.unitless_min_deg) / (o.unitless_max_deg - o.unitless_min_deg)
        fraction = max(0.0, min(1.0, fraction))  # rounding only: the angle was checked
        if o.command == "pwm":
            # microseconds: float16 carries whole numbers exactly up to 2048 and steps by 2
            # above (AP_Periph rounds ``command_value + 0.5`` to a whole us): the value sent is
            # the float16 nearest the whole pulse that stays within the channel's pulse range
            pulse = o.pwm_min_us + fraction * (o.pwm_max_us - o.pwm_min_us)
            on_wire = wire.float16_inside(float(round(pulse)), o.pwm_min_us, o.pwm_max_us)
            return o.actuator_id, wire.COMMAND_TYPE_PWM, on_wire
        return o.actuator_id, wire.COMMAND_TYPE_UNITLESS, 2.0 * fraction - 1.0

    def position_command(self, angle_deg: float, max_speed_dps: float | None = None) -> can.Message:
        """This servo's command alone as a one-command ArrayCommand (a single frame). The bus
        node packs the commands of one slot together and numbers the transfers; DroneCAN
        actuators take no speed limit, so ``max_speed_dps`` is only validated."""
        self._speed_limit(max_speed_dps, 0.0)
        command = self.command_tuple(angle_deg)
        if self._payload is None:
            self._payload = wire.array_command([command])
        else:  # one payload object, its value replaced: the package's objects are costly
            self._payload.commands[0].command_value = command[2]
        (frame,) = wire.encode_message(self._payload, self.bridge_node_id, 0)
        self._remember(frame, command)
        return frame

    def _remember(self, frame: can.Message, command: tuple[int, int, float]) -> None:
        """Keep ``command`` findable by its frame (:meth:`command_of`), the latest few only."""
        key = bytes(frame.data)
        if key not in self._sent and len(self._sent) >= _COMMANDS_REMEMBERED:
            self._sent.pop(next(iter(self._sent)))
        self._sent[key] = command

    def command_of(self, frame: can.Message) -> tuple[int, int, float] | None:
        """The ``(actuator_id, command_type, value)`` of one of this servo's recent command
        frames (the bus node packs it without decoding it again), None if not one of them."""
        return self._sent.get(bytes(frame.data))

    def telemetry_requests(self) -> list[can.Message]:
        return []

    def release_frames(self) -> list[can.Message]:
        """Motor off for an ArduPilot peripheral's output: PWM 0 for its actuator (what the
        board's own command timeout writes, ``rc_out.cpp``). Not commanding it is no release
        there: the board's timeout is one for the whole node, fed by any UNITLESS or PWM entry
        of any ArrayCommand (``can.cpp``, ``handle_act_command``), so while another servo of
        the bus is commanded the output keeps its last pulse. The bus node packs the frame
        with the slot's commands. Other DroneCAN servos: none (the specification has no
        release; they keep their last command, :meth:`stop_behaviour`)."""
        if self.options.firmware != "ardupilot":
            return []
        command = (self.options.actuator_id, wire.COMMAND_TYPE_PWM, 0.0)
        (frame,) = wire.encode_message(wire.array_command([command]), self.bridge_node_id, 0)
        self._remember(frame, command)
        return [frame]

    def shutdown_frames(self) -> list[can.Message]:
        """The bus node's SafetyState plan at stop (SAFETY_ON), carried by one of its servos."""
        return list(self.shutdown_hook()) if self.shutdown_hook is not None else []

    def config_warnings(self) -> list[str]:
        """Actuator id 0 is PX4's first output; an ArduPilot node computes ``1 << (id - 1)``
        for it (no output, or a wrong one): said unless the firmware is PX4."""
        o = self.options
        if o.actuator_id == 0 and o.firmware == "generic":
            return [
                "actuator_id 0: PX4 numbers actuators from 0, ArduPilot and most servo vendors "
                "from 1 (an ArduPilot node has no output 0); set firmware: px4 if the node "
                "runs PX4, else the id the servo is set to"
            ]
        return []

    def stop_behaviour(self) -> str:
        if self.options.firmware == "ardupilot":
            return (
                f"zeroes its PWM output {ARDUPILOT_COMMAND_TIMEOUT_S * 1000:g} ms after the last "
                "ArrayCommand on the bus, for any actuator (AP_Periph SRV_CMD_TIME_OUT): the "
                "servo goes limp; a release sends it PWM 0 (the board would keep its pulse "
                "while another servo is commanded)"
            )
        return (
            "keeps its last command (no timeout in the DroneCAN specification; Hitec and Volz "
            "servos hold, check the servo's manual for its own)"
        )

    def is_liveness_only(self, msg: can.Message) -> bool:
        """A NodeStatus says the node is alive; only the actuator's own report answers a
        command (anyone can send a NodeStatus with this node id)."""
        return (msg.arbitration_id >> 8) & 0xFFFF == wire.DTID_NODE_STATUS

    @classmethod
    def sim_device(cls, motor: SimMotor, can_id: int, options: ProfileOptions) -> SimDevice:
        return simulated_device(cls, motor, can_id, options)

    @classmethod
    def link_sim_devices(cls, devices: Sequence[SimDevice]) -> None:
        """Servos on one node id are one simulated node (see :mod:`.sim`, found by name)."""
        link_simulated_devices(cls, devices)

    NodeOptions: ClassVar[type[ProfileOptions]] = NodeOptions

    @classmethod
    def bus_node(
        cls,
        profiles: Sequence[ServoProfile],
        options: ProfileOptions | None,
        software_version: tuple[int, int],
        start: float,
        unique_id: bytes = bytes(16),
    ) -> BridgeNode:
        """The bridge's own DroneCAN node on a bus with these servos (see :mod:`.dronecan_node`)."""
        node_options = options if isinstance(options, NodeOptions) else NodeOptions()
        servos = [p for p in profiles if isinstance(p, DroneCanServo)]
        return BridgeNode(servos, node_options, software_version, start, unique_id)

    # ------------------------------------------------------------------------- feedback
    def identifiers(self) -> tuple[FrameId, ...]:
        """ArrayCommand (shared by the bus's DroneCAN servos; any source, any priority) out;
        NodeStatus, Status and the vendor status from this node id in, shared by the servos
        of one node (several actuators on one node id; the bus node refuses two servos on one
        actuator id)."""
        command = FrameId(
            wire.message_id(wire.DTID_ARRAY_COMMAND, 0, 0),
            True,
            "to_servo",
            "command",
            id_mask=_DTID_MASK | 0x80,
            shared=True,
        )
        pushes = tuple(
            FrameId(
                wire.message_id(dtid, self.can_id, 0),
                True,
                "from_servo",
                "push",
                id_mask=_DTID_MASK | 0xFF,
                shared=True,  # a node with several actuators: each servo takes its own
            )
            for dtid in _FEEDBACK
        )
        return (command, *pushes)

    def is_reply(self, msg: can.Message) -> bool:
        """A message frame from this node (the low byte is the service bit, clear, and the
        source id) of a feedback type: asked of every servo for every frame, so arithmetic
        only (``wire.is_message_frame`` and friends, inlined)."""
        arbitration_id = msg.arbitration_id
        return (
            arbitration_id & 0xFF == self.can_id
            and msg.is_extended_id
            and not msg.is_remote_frame
            and (arbitration_id >> 8) & 0xFFFF in _FEEDBACK_SET
        )

    def completes_report(self, msg: can.Message) -> bool:
        """Only the last frame of a transfer (end-of-transfer bit in the tail byte) is one."""
        return bool(msg.data) and bool(msg.data[-1] & 0x40)

    def decode(self, msg: can.Message, timestamp: float) -> ServoState | None:
        if not self.is_reply(msg) or self._siblings_status(msg):
            return None
        errors_before = sum(self._reassembler.errors.values())
        received = self._reassembler.push(msg, timestamp)
        if received is None:
            if sum(self._reassembler.errors.values()) != errors_before:
                return None
            return self._merge(timestamp)  # part of a transfer: alive, nothing new yet
        return self._apply(received, timestamp)

    def _siblings_status(self, msg: can.Message) -> bool:
        """True for a frame of a Status transfer of a sibling's actuator (another servo of
        this node): the sibling decodes it, this servo skips it without reassembling, so a
        node with N actuators costs one decode per transfer, not N. The actuator id is the
        first payload byte, after the two CRC bytes of a multi-frame transfer's first frame;
        the transfer's other frames follow by (id, transfer id)."""
        if len(self.node_actuators) < 2:
            return False
        data = msg.data
        if not data or (msg.arbitration_id >> 8) & 0xFFFF != wire.DTID_ACTUATOR_STATUS:
            return False
        tail = data[-1]
        key = (msg.arbitration_id, tail & 0x1F)
        if tail & 0x80:  # the first frame: whose actuator?
            self._skipping.discard(key)
            index = 2 if not tail & 0x40 else 0
            if len(data) <= index + 1:
                return False
            actuator = data[index]
            if actuator == self.options.actuator_id or actuator not in self.node_actuators:
                return False
            if not tail & 0x40:
                if len(self._skipping) >= 64:  # bounded: ids and transfer ids come off the wire
                    self._skipping.clear()
                self._skipping.add(key)
            return True
        if key in self._skipping:
            if tail & 0x40:
                self._skipping.discard(key)
            return True
        return False

    def _apply(self, rx: wire.Received, timestamp: float) -> ServoState | None:
        p = rx.payload
        actuator = self.options.actuator_id
        if rx.dtid == wire.DTID_NODE_STATUS:
            uptime, last = int(p.uptime_sec), self.node_uptime
            self.node_uptime = uptime
            if last is not None and uptime < last:
                # a restart (one NodeStatus), or two nodes on this id (a stranger speaking for
                # the servo: every other one): counted, and not a sign of life
                self._reassembler.errors["uptime_backwards"] += 1
                return None
            self.node_health, self.node_mode = int(p.health), int(p.mode)
            if self.node_heard_at is None:
                self.node_heard_at = timestamp
            self.node_last_heard = timestamp
            healthy = self.node_health == wire.HEALTH_OK
            running = self.node_mode in (wire.MODE_OPERATIONAL, wire.MODE_INITIALIZATION)
            self._health_faults = NO_FAULT if healthy and running else Fault.OTHER
            return self._merge(timestamp, faults=self._health_faults | self._vendor_faults)
        if rx.dtid == wire.DTID_ACTUATOR_STATUS:
            if int(p.actuator_id) != actuator:
                return self._other_actuator(int(p.actuator_id))
            self.actuator_reported_at = timestamp
            return self._merge(
                timestamp,
                position_deg=self._reported_angle(_degrees(p.position)),
                velocity_dps=_degrees(p.speed),
            )
        if rx.dtid == wire.DTID_VOLZ_STATUS:
            if int(p.actuator_id) != actuator:
                return self._other_actuator(int(p.actuator_id))
            self.actuator_reported_at = timestamp
            raw_temperature = int(p.motor_temperature)
            return self._merge(
                timestamp,
                position_deg=_degrees(p.actual_position),
                current_a=int(p.current) * 0.025,
                voltage_v=int(p.voltage) * 0.2,
                temperature_c=math.nan if raw_temperature == 255 else raw_temperature - 50.0,
            )
        if rx.dtid == wire.DTID_HIMARK_INFO:
            if int(p.servo_id) != actuator:
                return self._other_actuator(int(p.servo_id))
            self.actuator_reported_at = timestamp
            self._vendor_faults = NO_FAULT if int(p.error_status) == 0 else Fault.OTHER
            return self._merge(
                timestamp,
                position_deg=int(p.pos_sensor) * 0.01,
                current_a=int(p.current) * 0.01,
                voltage_v=int(p.voltage) * 0.01,
                temperature_c=int(p.motor_temp) * 0.2 - 40.0,
                faults=self._health_faults | self._vendor_faults,
            )
        return self._merge(timestamp)

    def _reported_angle(self, degrees: float) -> float:
        """A Status position as this servo's angle. ArduPilot's peripheral reports no
        measurement but its output's norm as ``norm x 45 deg`` (:data:`ARDUPILOT_UNITLESS_DEG`):
        over a range other than +-45 deg that number is no angle of the servo (a servo told
        60 deg over +-60 read back 45, and the health monitor called it 15 deg behind for
        good), so the norm goes back through the servo's own range, the angle it drives."""
        o = self.options
        if o.firmware != "ardupilot" or not math.isfinite(degrees):
            return degrees
        norm = degrees / ARDUPILOT_UNITLESS_DEG
        return o.unitless_min_deg + (norm + 1.0) / 2.0 * (o.unitless_max_deg - o.unitless_min_deg)

    def _other_actuator(self, actuator: int) -> ServoState | None:
        """A status of another actuator from this servo's node: a sibling's (another servo
        configured on this node id: its own, nothing to count), else the node is set to an
        actuator id the config does not name (it ignores the bridge's commands) or a stranger
        speaks for it: counted (``other_actuator``; the scheduler counts the frame rejected
        when no servo of the node takes it), not a state."""
        if actuator not in self.node_actuators:
            self._reassembler.errors["other_actuator"] += 1
        return None


def _degrees(value: Any) -> float:
    """A float16 field in radians as degrees (NaN, the DSDL's "unknown", stays NaN)."""
    number = float(value)
    return math.degrees(number) if math.isfinite(number) else math.nan
