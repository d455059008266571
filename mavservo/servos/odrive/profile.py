"""ODrive (firmware 0.6: ODrive Pro, S1, Micro) over CANSimple.

Wire facts, from ODrive's CAN protocol documentation and its published DBC file
(``odrive-cansimple-0.6.10.dbc``, which the tests read with cantools), and the error and state
enums of ODrive's own ``odrive`` package (0.6.11):

* standard 11-bit ids, ``node_id << 5 | command``; all multi-byte values little-endian;
* the node takes every frame of its block (its receive filter masks the five command bits), so
  ``identifiers()`` claims the whole block and ``check`` reports anything else sent into it;
* host to ODrive: 0x04 RxSdo ``[opcode u8 (1 write), endpoint id u16, reserved u8, value]``,
  0x07 Set_Axis_State ``[state u32]`` (1 idle, 8 closed loop), 0x0B Set_Controller_Mode
  ``[control mode u32 (3 position), input mode u32 (1 passthrough, 3 pos filter, 5 trap traj)]``,
  0x0C Set_Input_Pos ``[position float32 turns, vel_ff int16 x 0.001 turn/s, torque_ff int16
  x 0.001 N m]``, 0x0F Set_Limits ``[velocity limit float32 turn/s, current limit float32 A]``,
  0x11 Set_Traj_Vel_Limit, 0x12 Set_Traj_Accel_Limits ``[accel, decel float32 turn/s^2]``,
  0x18 Clear_Errors ``[identify u8]``; none of them is answered;
* ODrive to host, cyclic (no request): 0x01 Heartbeat ``[axis error u32, axis state u8,
  procedure result u8, trajectory done (bit 0) u8, reserved]`` every ``heartbeat_msg_rate_ms``
  (default 100 ms) and 0x09 Get_Encoder_Estimates ``[position float32 turns, velocity float32
  turn/s]`` every ``encoder_msg_rate_ms`` (default 10 ms); when their rates are set on the
  ODrive, 0x03 Get_Error ``[active errors u32, disarm reason u32]``, 0x14 Get_Iq ``[setpoint,
  measured float32 A]``, 0x15 Get_Temperature ``[FET, motor float32 degC]``, 0x17
  Get_Bus_Voltage_Current ``[float32 V, float32 A]``: all decoded here when they come;
* the heartbeat's axis error is ``active_errors | disarm_reason`` (bit flags, mapped to
  :class:`Fault` by :data:`ERROR_FAULTS`; an unknown bit is ``Fault.OTHER``). Any error disarms
  the axis: it goes to IDLE and stays there until told to enter closed loop again;
* the watchdog (``axis.config.enable_watchdog``, ``axis.config.watchdog_timeout`` in seconds)
  disarms the axis with WATCHDOG_TIMER_EXPIRED when it was not fed for that long. Every
  Set_Input_Pos the command slot sends (new set point or keep-alive refresh) feeds it (ODrive's
  open 0.5 firmware feeds it on any CANSimple frame to the node; the simulation does the same),
  so the refresh interval must stay well inside the timeout.

The watchdog is set at start-up through RxSdo writes when the endpoint ids of those two
parameters are given (``watchdog_timeout_endpoint``, ``enable_watchdog_endpoint``): ODrive
numbers its parameters per firmware version and board in ``flat_endpoints.json`` (published with
each firmware release), so no id is guessed here: a wrong one would write some other parameter.
Without them the ODrive keeps the watchdog configured with odrivetool, and
``watchdog_timeout_s`` tells the simulation what it is.

Firmware 0.5 (ODrive v3.6) is a different protocol on the same ids (its heartbeat carries
motor/encoder/controller flags and its axis error bits mean other things): not this profile.
Node 63 (0x3F) is the "unaddressed" id of firmware 0.6, so nodes are 0..62.

Life cycle: start-up sends the watchdog writes (if configured), Clear_Errors, position control
with the input mode, the limits (and the trajectory limits in trap-traj mode), then closed loop.
A heartbeat that shows the axis IDLE afterwards (an error or the watchdog disarmed it) makes
``needs_startup()`` true, so the scheduler sends the start-up again (at most once a second).
Release and shutdown: Set_Axis_State IDLE (motor off, it turns freely).

Units: the wire carries motor turns; ``motor_turns_per_rev`` (the gear ratio between motor and
output) converts to output degrees. Positions outside the servo's own range
(``min_position_deg``..``max_position_deg``) raise ``ValueError`` before anything is built (the
bridge answers DENIED). The speed limit is the axis' velocity limit sent at start-up (the
position frame carries a velocity feed-forward, not a limit), so a per-command
``max_speed_dps`` is validated and otherwise ignored.
"""

from __future__ import annotations

import math
import struct
from typing import ClassVar, Literal

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
from ..sim_registry import simulated_device

NODE_MASK = 0x7E0
"""The id bits that name the node (the upper six of eleven)."""

CMD_HEARTBEAT = 0x01
CMD_GET_ERROR = 0x03
CMD_RX_SDO = 0x04
CMD_SET_AXIS_STATE = 0x07
CMD_ENCODER_ESTIMATES = 0x09
CMD_SET_CONTROLLER_MODE = 0x0B
CMD_SET_INPUT_POS = 0x0C
CMD_SET_LIMITS = 0x0F
CMD_SET_TRAJ_VEL_LIMIT = 0x11
CMD_SET_TRAJ_ACCEL_LIMITS = 0x12
CMD_GET_IQ = 0x14
CMD_GET_TEMPERATURE = 0x15
CMD_GET_BUS_VOLTAGE_CURRENT = 0x17
CMD_CLEAR_ERRORS = 0x18

PUSHES = (
    CMD_HEARTBEAT,
    CMD_GET_ERROR,
    CMD_ENCODER_ESTIMATES,
    CMD_GET_IQ,
    CMD_GET_TEMPERATURE,
    CMD_GET_BUS_VOLTAGE_CURRENT,
)
"""Cyclic messages the ODrive sends on its own, all 8 bytes."""
PUSH_LEN = 8

STATE_UNDEFINED = 0
STATE_IDLE = 1
STATE_CLOSED_LOOP = 8
CONTROL_MODE_POSITION = 3
INPUT_MODES: dict[str, int] = {"passthrough": 1, "pos-filter": 3, "trap-traj": 5}
SDO_WRITE = 1
PROCEDURE_SUCCESS = 0
PROCEDURE_DISARMED = 3
PROCEDURE_NOT_CALIBRATED = 14
FF_SCALE = 1000
"""Set_Input_Pos feed-forward fields count 0.001 turn/s and 0.001 N m (the default scales)."""

# ODrive.Error (firmware 0.6), the heartbeat's axis error bits
INITIALIZING = 0x1
SYSTEM_LEVEL = 0x2
TIMING_ERROR = 0x4
MISSING_ESTIMATE = 0x8
BAD_CONFIG = 0x10
DRV_FAULT = 0x20
MISSING_INPUT = 0x40
DC_BUS_OVER_VOLTAGE = 0x100
DC_BUS_UNDER_VOLTAGE = 0x200
DC_BUS_OVER_CURRENT = 0x400
DC_BUS_OVER_REGEN_CURRENT = 0x800
CURRENT_LIMIT_VIOLATION = 0x1000
MOTOR_OVER_TEMP = 0x2000
INVERTER_OVER_TEMP = 0x4000
VELOCITY_LIMIT_VIOLATION = 0x8000
POSITION_LIMIT_VIOLATION = 0x10000
REQUESTED_CURRENT_TOO_HIGH = 0x20000
WATCHDOG_TIMER_EXPIRED = 0x1000000
ESTOP_REQUESTED = 0x2000000
SPINOUT_DETECTED = 0x4000000
BRAKE_RESISTOR_DISARMED = 0x8000000
THERMISTOR_DISCONNECTED = 0x10000000
CALIBRATION_ERROR = 0x40000000

ERROR_FAULTS: dict[int, Fault] = {
    INITIALIZING: Fault.OTHER,
    SYSTEM_LEVEL: Fault.OTHER,
    TIMING_ERROR: Fault.OTHER,
    MISSING_ESTIMATE: Fault.ENCODER,
    BAD_CONFIG: Fault.OTHER,
    DRV_FAULT: Fault.DRIVER,
    MISSING_INPUT: Fault.OTHER,
    DC_BUS_OVER_VOLTAGE: Fault.OVER_VOLTAGE,
    DC_BUS_UNDER_VOLTAGE: Fault.LOW_VOLTAGE,
    DC_BUS_OVER_CURRENT: Fault.OVER_CURRENT,
    DC_BUS_OVER_REGEN_CURRENT: Fault.POWER,
    CURRENT_LIMIT_VIOLATION: Fault.OVER_CURRENT,
    MOTOR_OVER_TEMP: Fault.OVER_TEMPERATURE,
    INVERTER_OVER_TEMP: Fault.OVER_TEMPERATURE,
    VELOCITY_LIMIT_VIOLATION: Fault.OVERSPEED,
    POSITION_LIMIT_VIOLATION: Fault.OTHER,
    REQUESTED_CURRENT_TOO_HIGH: Fault.OVER_CURRENT,
    WATCHDOG_TIMER_EXPIRED: Fault.COMMUNICATION_LOST,
    ESTOP_REQUESTED: Fault.OTHER,
    SPINOUT_DETECTED: Fault.ENCODER,  # the commutation and the encoder disagree
    BRAKE_RESISTOR_DISARMED: Fault.POWER,
    THERMISTOR_DISCONNECTED: Fault.OTHER,
    CALIBRATION_ERROR: Fault.UNCALIBRATED,
}
"""Every documented axis error bit and its named fault; any other bit is ``Fault.OTHER``."""


def fault_from_error(error: int) -> Fault:
    """The named faults of an axis error word (never "no fault" for an unknown bit)."""
    faults = NO_FAULT
    rest = error
    for bit, fault in ERROR_FAULTS.items():
        if error & bit:
            faults |= fault
            rest &= ~bit
    if rest:
        faults |= Fault.OTHER
    return faults


def arbitration_id(node_id: int, command: int) -> int:
    return node_id << 5 | command


def _frame(node_id: int, command: int, data: bytes) -> can.Message:
    """A frame of the DBC's length: 8 bytes (values zero-padded), Clear_Errors 1."""
    length = 1 if command == CMD_CLEAR_ERRORS else 8
    return can.Message(
        arbitration_id=arbitration_id(node_id, command),
        is_extended_id=False,
        data=data.ljust(length, b"\0"),
    )


def _float32(value: float) -> float | None:
    """A decoded float32 field, or None for NaN and infinities (a hostile or broken frame)."""
    return value if math.isfinite(value) else None


class ODriveOptions(ProfileOptions):
    """Per-servo ``options:`` of an ODrive axis (defaults: direct drive, +-180 deg)."""

    input_mode: Literal["passthrough", "pos-filter", "trap-traj"] = Field(
        "passthrough",
        description="how the axis follows a new position (Set_Controller_Mode at start-up)",
    )
    motor_turns_per_rev: float = Field(
        1.0,
        ge=0.001,
        le=1000,
        description="motor turns per output revolution (gear ratio, 0.001..1000: far below, "
        "a position in turns underflows float32 and every command would be 0)",
    )
    min_position_deg: float = Field(
        -180.0, ge=-36_000, le=36_000, description="lowest output position accepted, deg"
    )
    max_position_deg: float = Field(
        180.0, ge=-36_000, le=36_000, description="highest output position accepted, deg"
    )
    velocity_limit_turns_s: float = Field(
        2.0, gt=0, le=1000, description="Set_Limits velocity limit, motor turns/s"
    )
    current_limit_a: float = Field(10.0, gt=0, le=500, description="Set_Limits current limit, A")
    traj_accel_turns_s2: float = Field(
        10.0,
        gt=0,
        le=100_000,
        description="trap-traj acceleration and deceleration, motor turns/s^2",
    )
    watchdog_timeout_s: float = Field(
        0.5,
        ge=0,
        le=60,
        description="the axis watchdog: it disarms after this long without a frame (0: off)",
    )
    watchdog_timeout_endpoint: int | None = Field(
        None,
        ge=0,
        le=0xFFFF,
        description="flat_endpoints.json id of axis0.config.watchdog_timeout for your firmware "
        "(null: not written, the ODrive keeps its own setting)",
    )
    enable_watchdog_endpoint: int | None = Field(
        None,
        ge=0,
        le=0xFFFF,
        description="flat_endpoints.json id of axis0.config.enable_watchdog (with the above)",
    )
    heartbeat_ms: int = Field(
        100, ge=1, le=10_000, description="the ODrive's heartbeat_msg_rate_ms (bus budget, sim)"
    )
    aux_rate_ms: int = Field(
        0,
        ge=0,
        le=10_000,
        description="the ODrive's iq, temperature and bus voltage message rate (0: not sent)",
    )

    @model_validator(mode="after")
    def _consistent(self) -> ODriveOptions:
        if not self.min_position_deg < self.max_position_deg:
            raise ValueError("min_position_deg must be below max_position_deg")
        if not self.min_position_deg <= 0 <= self.max_position_deg:
            # the bus-load budget sizes a command at 0 deg; an axis' range holds its zero
            raise ValueError("the range min_position_deg..max_position_deg must contain 0")
        if (self.watchdog_timeout_endpoint is None) != (self.enable_watchdog_endpoint is None):
            raise ValueError(
                "watchdog_timeout_endpoint and enable_watchdog_endpoint go together "
                "(both ids from your firmware's flat_endpoints.json, or neither)"
            )
        if (
            self.watchdog_timeout_endpoint is not None
            and self.watchdog_timeout_endpoint == self.enable_watchdog_endpoint
        ):
            raise ValueError("watchdog_timeout_endpoint and enable_watchdog_endpoint must differ")
        return self

    def turns(self, angle_deg: float) -> float:
        """Output degrees as motor turns."""
        return angle_deg / 360.0 * self.motor_turns_per_rev

    def degrees(self, turns: float) -> float:
        """Motor turns as output degrees."""
        return turns * 360.0 / self.motor_turns_per_rev


class ODrive(ServoProfile):
    """One ODrive axis (CANSimple node); pushes its state, takes position set points."""

    STOP_BEHAVIOUR = "holds its last target until its axis watchdog, when set, disarms the axis"

    name = "odrive"
    telemetry = "pushed"
    replies_per_command = 0
    replies_per_request = 0
    replies_per_lifecycle = 0
    """CANSimple answers none of the frames this profile sends."""
    min_id, max_id = 0, 62
    Options: ClassVar[type[ProfileOptions]] = ODriveOptions
    options: ODriveOptions

    def __init__(self, can_id: int, options: ProfileOptions | None = None, **overrides: object):
        super().__init__(can_id, options, **overrides)
        o = self.options
        self.min_angle_deg = o.min_position_deg
        self.max_angle_deg = o.max_position_deg
        self.max_speed_dps = o.degrees(o.velocity_limit_turns_s)
        # the coarsest float32 step over the range, in output degrees
        widest = max(abs(o.turns(o.min_position_deg)), abs(o.turns(o.max_position_deg)))
        self.resolution_deg = o.degrees(2.0 ** (math.frexp(widest)[1] - 24))
        self.axis_state: int | None = None
        """The axis state of the latest heartbeat (None before one came)."""
        self.axis_error = 0
        self.procedure_result: int | None = None
        self.trajectory_done = False
        self._startup_due = False

    # -- frames the bridge sends -------------------------------------------------------------

    def _frame(self, command: int, data: bytes) -> can.Message:
        return _frame(self.can_id, command, data)

    def position_command(self, angle_deg: float, max_speed_dps: float | None = None) -> can.Message:
        self._check_angle(angle_deg)
        self._speed_limit(max_speed_dps, 0.0)  # validated; the limit is the axis' own
        position = self.options.turns(angle_deg)
        return self._frame(CMD_SET_INPUT_POS, struct.pack("<fhh", position, 0, 0))

    def telemetry_requests(self) -> list[can.Message]:
        return []

    def sdo_write(self, endpoint: int, fmt: str, value: float | bool) -> can.Message:
        """An RxSdo write of one parameter (value padded to the frame's 8 bytes)."""
        body = struct.pack("<BHB" + fmt, SDO_WRITE, endpoint, 0, value)
        return self._frame(CMD_RX_SDO, body)

    def set_axis_state_frame(self, state: int) -> can.Message:
        return self._frame(CMD_SET_AXIS_STATE, struct.pack("<I", state))

    def startup_frames(self) -> list[can.Message]:
        """Watchdog (if its endpoint ids are known), clear errors, position control, limits,
        closed loop."""
        self._startup_due = False
        o = self.options
        frames = []
        timeout_id, enable_id = o.watchdog_timeout_endpoint, o.enable_watchdog_endpoint
        if timeout_id is not None and enable_id is not None:
            if o.watchdog_timeout_s > 0:
                frames.append(self.sdo_write(timeout_id, "f", o.watchdog_timeout_s))
            frames.append(self.sdo_write(enable_id, "?", o.watchdog_timeout_s > 0))
        frames += [
            self._frame(CMD_CLEAR_ERRORS, b"\0"),
            self._frame(
                CMD_SET_CONTROLLER_MODE,
                struct.pack("<II", CONTROL_MODE_POSITION, INPUT_MODES[o.input_mode]),
            ),
            self._frame(
                CMD_SET_LIMITS, struct.pack("<ff", o.velocity_limit_turns_s, o.current_limit_a)
            ),
        ]
        if o.input_mode == "trap-traj":
            frames += [
                self._frame(CMD_SET_TRAJ_VEL_LIMIT, struct.pack("<f", o.velocity_limit_turns_s)),
                self._frame(
                    CMD_SET_TRAJ_ACCEL_LIMITS,
                    struct.pack("<ff", o.traj_accel_turns_s2, o.traj_accel_turns_s2),
                ),
            ]
        frames.append(self.set_axis_state_frame(STATE_CLOSED_LOOP))
        return frames

    def needs_startup(self) -> bool:
        return self._startup_due

    def release_frames(self) -> list[can.Message]:
        """IDLE: the motor is off and turns freely."""
        return [self.set_axis_state_frame(STATE_IDLE)]

    def shutdown_frames(self) -> list[can.Message]:
        return [self.set_axis_state_frame(STATE_IDLE)]

    def comm_timeout_s(self) -> float | None:
        """The axis watchdog (``watchdog_timeout_s``; 0: off): it disarms the axis past it."""
        return self.options.watchdog_timeout_s or None

    def unsolicited_hz(self) -> float:
        """The heartbeat, and the iq, temperature and bus messages when their rate is set."""
        hz = 1000.0 / self.options.heartbeat_ms
        if self.options.aux_rate_ms:
            hz += 3 * 1000.0 / self.options.aux_rate_ms
        return hz

    @classmethod
    def sim_device(cls, motor: SimMotor, can_id: int, options: ProfileOptions) -> SimDevice:
        """The simulated ODrive (built-in simulation, ``mavservo sim``)."""
        return simulated_device(cls, motor, can_id, options)

    def identifiers(self) -> tuple[FrameId, ...]:
        """Each frame sent and pushed, then the node's whole block: the ODrive takes any frame
        whose upper six id bits are its node id."""
        base = arbitration_id(self.can_id, 0)
        commands = {
            CMD_SET_INPUT_POS: "command",
            CMD_SET_AXIS_STATE: "lifecycle",
            CMD_SET_CONTROLLER_MODE: "lifecycle",
            CMD_SET_LIMITS: "lifecycle",
            CMD_CLEAR_ERRORS: "lifecycle",
        }
        if self.options.enable_watchdog_endpoint is not None:
            commands[CMD_RX_SDO] = "lifecycle"
        if self.options.input_mode == "trap-traj":
            commands[CMD_SET_TRAJ_VEL_LIMIT] = "lifecycle"
            commands[CMD_SET_TRAJ_ACCEL_LIMITS] = "lifecycle"
        ids = [FrameId(base | cmd, False, "to_servo", purpose) for cmd, purpose in commands.items()]
        ids += [FrameId(base | cmd, False, "from_servo", "push") for cmd in PUSHES]
        ids.append(FrameId(base, False, "to_servo", "node block", id_mask=NODE_MASK))
        return tuple(ids)

    # -- frames the ODrive sends -------------------------------------------------------------

    def is_reply(self, msg: can.Message) -> bool:
        return (
            not msg.is_extended_id
            and not msg.is_remote_frame
            and msg.arbitration_id >> 5 == self.can_id
            and msg.arbitration_id & 0x1F in PUSHES
            and len(msg.data) == PUSH_LEN
        )

    def decode(self, msg: can.Message, timestamp: float) -> ServoState | None:
        if not self.is_reply(msg):
            return None
        data = bytes(msg.data)
        command = msg.arbitration_id & 0x1F
        if command == CMD_HEARTBEAT:
            return self._heartbeat(data, timestamp)
        if command == CMD_GET_ERROR:
            active, disarm_reason = struct.unpack("<II", data)
            return self._merge(timestamp, faults=self._faults(active | disarm_reason))
        first, second = struct.unpack("<ff", data)
        if command == CMD_ENCODER_ESTIMATES:
            position, velocity = _float32(first), _float32(second)
            return self._merge(
                timestamp,
                position_deg=None if position is None else self.options.degrees(position),
                velocity_dps=None if velocity is None else self.options.degrees(velocity),
            )
        if command == CMD_GET_IQ:
            return self._merge(timestamp, current_a=_float32(second))
        if command == CMD_GET_TEMPERATURE:
            readings = [t for t in (_float32(first), _float32(second)) if t is not None]
            return self._merge(timestamp, temperature_c=max(readings) if readings else None)
        return self._merge(timestamp, voltage_v=_float32(first))  # bus voltage and current

    def _faults(self, error: int) -> Fault:
        faults = fault_from_error(error)
        if self.procedure_result == PROCEDURE_NOT_CALIBRATED:
            faults |= Fault.UNCALIBRATED
        return faults

    def _heartbeat(self, data: bytes, timestamp: float) -> ServoState:
        error, state, result, flags = struct.unpack_from("<IBBB", data)
        self.axis_error = error
        self.axis_state = state
        self.procedure_result = result
        self.trajectory_done = bool(flags & 1)
        # idle after a start-up: an error or the watchdog disarmed it. Only IDLE: a calibration
        # or homing the ODrive runs by itself must not be cut short by a closed-loop request.
        self._startup_due = state == STATE_IDLE
        return self._merge(timestamp, faults=self._faults(error))
