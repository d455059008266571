"""Damiao DM-J series (DM-J4310-2EC and siblings): MIT mode and position-velocity mode.

Wire facts (standard 11-bit ids, 8-byte payloads, 1 Mbit/s). Sources: Damiao's DM-J4310-2EC
manual V1.0 (2022-10-14: feedback frame, MIT control frame, position-velocity control frame, the
fault codes, the protections) and Damiao's own example drivers (dmBots motor-control-routine:
the special frames, the register protocol on 0x7FF, the register numbers):

* MIT command on the motor's CAN id: the MIT packing (:mod:`.mit`) with the motor's P/V/T
  ranges (set on the motor; here per-servo options) and kp 0..500, kd 0..5;
* position-velocity command on ``0x100 + id``: float32 position (rad) then float32 velocity
  limit (rad/s), little-endian;
* special frames on the CAN id: ``FF x7 FC`` enable, ``FD`` disable, ``FE`` set zero,
  ``FB`` clear error;
* registers through id ``0x7FF``: ``[id lo, id hi, 0x33 read | 0x55 write | 0xAA store, RID,
  value u32/float32 LE]``, answered on the master id with the same four-byte head; ``0xCC`` in
  byte 2 asks for a feedback frame (the poll used here). Registers used: 9 TIMEOUT (the motor
  leaves the enabled state when no CAN frame arrives for this long), 10 CTRL_MODE (1 MIT,
  2 position-velocity). Writes go to RAM only: this profile never stores (0xAA), so the motor's
  flash is never worn by a restart;
* every command and poll is answered on the **master id** (default 0, shared by every Damiao
  motor on the bus) with ``[ERR << 4 | ID, POS 16, VEL 12, T 12, T_MOS, T_Rotor]``, position,
  velocity and torque mapped with the same P/V/T ranges. ``ERR`` (the status): 0 disabled,
  1 enabled, 8 over-voltage, 9 under-voltage, A over-current, B MOSFET over-temperature,
  C rotor over-temperature, D communication lost, E overload. Byte 0 carries only the low four
  bits of the id, so two motors that share a master id must differ in those bits (``check``
  reports the overlap).

The TIMEOUT register counts 50 microseconds per unit (the register table of the independent
``damiao-motor`` driver; Damiao's manual names the register but not its unit), so
``comm_timeout_ms`` is written as ``ms * 20``.

Range policy: an angle outside the motor's position range (``+-p_max_rad``, the range its
feedback can express) raises ``ValueError`` before anything is built; speed limits saturate at
``v_max_rad_s``; MIT mode has no speed limit (the gains shape the motion), so ``max_speed_dps``
is validated and otherwise ignored there.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Hashable
from typing import ClassVar, Literal

import can
from pydantic import Field

from .. import mit
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

REGISTER_ID = 0x7FF
POSITION_VELOCITY_BASE = 0x100
REG_READ, REG_WRITE, REG_STORE, REG_REFRESH = 0x33, 0x55, 0xAA, 0xCC
RID_TIMEOUT = 9
RID_CTRL_MODE = 10
CTRL_MODE_MIT, CTRL_MODE_POSITION_VELOCITY = 1, 2
TIMEOUT_UNITS_PER_MS = 20
"""TIMEOUT register counts of 50 us in one millisecond."""

STATUS_DISABLED = 0x0
STATUS_ENABLED = 0x1
STATUS_COMMUNICATION_LOST = 0xD
STATUS_FAULTS: dict[int, Fault] = {
    0x8: Fault.OVER_VOLTAGE,
    0x9: Fault.LOW_VOLTAGE,
    0xA: Fault.OVER_CURRENT,
    0xB: Fault.OVER_TEMPERATURE,  # MOSFET over-temperature
    0xC: Fault.OVER_TEMPERATURE,  # rotor (coil) over-temperature
    0xD: Fault.COMMUNICATION_LOST,
    0xE: Fault.OVER_CURRENT,  # "overload": the drive's sustained-current (I2t) protection
}
"""Every documented fault status and its named fault; 0 and 1 are states, not faults, and any
other value decodes as ``Fault.OTHER``."""


def fault_from_status(status: int) -> Fault:
    """The named fault of a feedback status nibble (never "no fault" for an unknown code)."""
    if status in (STATUS_DISABLED, STATUS_ENABLED):
        return NO_FAULT
    return STATUS_FAULTS.get(status, Fault.OTHER)


class DamiaoOptions(mit.MitOptions):
    """Per-servo ``options:`` of a Damiao DM-J motor. Defaults are a DM-J4310-2EC's (PMAX
    12.5 rad, VMAX 30 rad/s, TMAX 10 N m, torque constant 0.945 N m/A)."""

    mode: Literal["mit", "position-velocity"] = Field(
        "mit", description="control mode, written to CTRL_MODE at start-up"
    )
    comm_timeout_ms: int = Field(
        200,
        ge=1,
        le=60_000,
        description="the motor's own CAN timeout (TIMEOUT register): it disables itself after "
        "this long without a frame",
    )
    default_speed_dps: float = Field(
        360.0, gt=0, le=100_000, description="position-velocity mode speed limit, deg/s"
    )


class DamiaoDM(ServoProfile):
    """Damiao DM-J motor; polled with the 0x7FF refresh request, answers on the master id."""

    STOP_BEHAVIOUR = "disables its motor past its TIMEOUT register (status: communication lost)"

    name = "damiao-dm"
    replies_per_command = 1
    replies_per_request = 1
    replies_per_lifecycle = 1
    """Every register write and special frame is answered on the master id."""
    min_id, max_id = 1, 0x7F
    Options: ClassVar[type[ProfileOptions]] = DamiaoOptions
    options: DamiaoOptions
    telemetry = "polled"

    def __init__(self, can_id: int, options: ProfileOptions | None = None, **overrides: object):
        super().__init__(can_id, options, **overrides)
        o = self.options
        self.ranges = o.ranges()
        self.max_angle_deg = math.degrees(o.p_max_rad)
        self.min_angle_deg = -self.max_angle_deg
        self.max_speed_dps = math.degrees(o.v_max_rad_s)
        self.resolution_deg = math.degrees(mit.step(self.ranges.position_rad, mit.POSITION_BITS))
        self._startup_due = False
        """The latest feedback said the motor is disabled or timed out: enable it again."""

    # -- frames the bridge sends -------------------------------------------------------------

    @property
    def command_id(self) -> int:
        if self.options.mode == "mit":
            return self.can_id
        return POSITION_VELOCITY_BASE + self.can_id

    def _frame(self, arbitration_id: int, data: bytes) -> can.Message:
        return can.Message(arbitration_id=arbitration_id, is_extended_id=False, data=data)

    def comm_timeout_s(self) -> float:
        """The TIMEOUT register start-up writes: the motor disables itself past it."""
        return self.options.comm_timeout_ms / 1000

    def position_command(self, angle_deg: float, max_speed_dps: float | None = None) -> can.Message:
        self._check_angle(angle_deg)
        speed = self._speed_limit(max_speed_dps, self.options.default_speed_dps)
        position = math.radians(angle_deg)
        if self.options.mode == "mit":
            command = mit.MitCommand(position, 0.0, self.options.kp, self.options.kd, 0.0)
            return self._frame(self.can_id, mit.pack_command(command, self.ranges))
        # a zero limit would hold the motor where it is: the smallest limit moves it at all
        velocity = max(math.radians(speed), 1e-3)
        return self._frame(self.command_id, struct.pack("<ff", position, velocity))

    def register_frame(self, operation: int, rid: int, value: bytes = b"\0\0\0\0") -> can.Message:
        """A register read, write or store (or the 0xCC refresh) for this motor on 0x7FF."""
        head = struct.pack("<HBB", self.can_id, operation, rid)
        return self._frame(REGISTER_ID, head + value)

    def telemetry_requests(self) -> list[can.Message]:
        return [self.register_frame(REG_REFRESH, 0)]

    def _special(self, code: bytes) -> can.Message:
        return self._frame(self.can_id, code)

    def startup_frames(self) -> list[can.Message]:
        """Mode and communication timeout (RAM registers), clear a latched fault, enable."""
        self._startup_due = False
        mode = CTRL_MODE_MIT if self.options.mode == "mit" else CTRL_MODE_POSITION_VELOCITY
        timeout = self.options.comm_timeout_ms * TIMEOUT_UNITS_PER_MS
        return [
            self.register_frame(REG_WRITE, RID_CTRL_MODE, struct.pack("<I", mode)),
            self.register_frame(REG_WRITE, RID_TIMEOUT, struct.pack("<I", timeout)),
            self._special(mit.CLEAR_ERROR),
            self._special(mit.ENTER_MOTOR_MODE),
        ]

    def needs_startup(self) -> bool:
        return self._startup_due

    def release_frames(self) -> list[can.Message]:
        """Disable: torque off, the motor turns freely."""
        return [self._special(mit.EXIT_MOTOR_MODE)]

    def shutdown_frames(self) -> list[can.Message]:
        return [self._special(mit.EXIT_MOTOR_MODE)]

    def set_zero_frame(self) -> can.Message:
        """Make the present position the zero (not sent by the bridge on its own)."""
        return self._special(mit.SET_ZERO)

    @classmethod
    def sim_device(cls, motor: SimMotor, can_id: int, options: ProfileOptions) -> SimDevice:
        """The simulated motor (built-in simulation, ``mavservo sim``)."""
        return simulated_device(cls, motor, can_id, options)

    def identifiers(self) -> tuple[FrameId, ...]:
        """Commands (and in MIT mode the special frames) on the CAN id, position-velocity
        commands on 0x100 + id, register frames on 0x7FF naming the motor in bytes 0-1 (shared
        by every Damiao motor of the bus), replies on the master id naming it in byte 0's low
        four bits."""
        ids = [FrameId(self.command_id, False, "to_servo", "command")]
        if self.command_id != self.can_id:
            ids.append(FrameId(self.can_id, False, "to_servo", "lifecycle"))
        ids += [
            FrameId(
                REGISTER_ID,
                False,
                "to_servo",
                "request",
                first_byte=(self.can_id & 0xFF, 0xFF),
                shared=True,
            ),
            FrameId(
                self.options.master_id,
                False,
                "from_servo",
                "reply",
                first_byte=(self.can_id & 0x0F, 0x0F),
            ),
        ]
        return tuple(ids)

    # -- frames the motor sends --------------------------------------------------------------

    def _is_register_reply(self, data: bytes) -> bool:
        return (
            data[0] == self.can_id & 0xFF
            and data[1] == self.can_id >> 8
            and data[2] in (REG_READ, REG_WRITE, REG_STORE)
        )

    def is_reply(self, msg: can.Message) -> bool:
        """A frame on the master id naming this motor: a feedback frame whose byte 0 carries
        this id's low four bits, or a register answer whose bytes 0-1 carry the whole id."""
        if (
            msg.is_extended_id
            or msg.is_remote_frame
            or msg.arbitration_id != self.options.master_id
            or len(msg.data) != 8
        ):
            return False
        data = bytes(msg.data)
        return data[0] & 0x0F == self.can_id & 0x0F or self._is_register_reply(data)

    def exchange_key(self, msg: can.Message) -> Hashable | None:
        """``("register", rid)`` for a register read, write or store and its answer;
        ``"feedback"`` for every other frame: commands, polls and special frames are all
        answered with a feedback frame.

        Two kinds, not None: the register frames go on 0x7FF, the lowest priority, so on the
        bus a clear-error or enable queued after them overtakes them, and its feedback would
        otherwise be credited to the register write (and the echo, coming later, to nothing).
        """
        data = bytes(msg.data)
        to_registers = msg.arbitration_id == REGISTER_ID and len(data) == 8
        if to_registers and data[2] != REG_REFRESH:
            return ("register", data[3])
        on_master_id = msg.arbitration_id == self.options.master_id and len(data) == 8
        if on_master_id and self._is_register_reply(data):
            return ("register", data[3])
        return "feedback"

    def decode(self, msg: can.Message, timestamp: float) -> ServoState | None:
        if not self.is_reply(msg):
            return None
        data = bytes(msg.data)
        if self._is_register_reply(data):
            # proof of life, nothing to read: the state stays, stamped now
            return self._merge(timestamp)
        status = data[0] >> 4
        # the latest feedback decides: the answer to a clear-error still says "disabled",
        # the answer to the enable that follows it no longer does
        self._startup_due = status in (STATUS_DISABLED, STATUS_COMMUNICATION_LOST)
        reply = mit.unpack_reply(data, self.ranges)
        return self._merge(
            timestamp,
            position_deg=math.degrees(reply.position_rad),
            velocity_dps=math.degrees(reply.velocity_rad_s),
            current_a=reply.torque_nm / self.options.torque_constant_nm_per_a,
            temperature_c=float(max(data[6], data[7])),
            faults=fault_from_status(status),
        )
