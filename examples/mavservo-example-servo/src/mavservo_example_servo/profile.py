"""``example-dm``: a toy servo family shaped like Damiao's position-velocity mode.

It exists to show the mavservo profile contract (``docs/profiles.md``) end to end from outside
mavservo's tree; it is not a driver for real Damiao motors (their register numbers and reply
details differ). Wire layout (standard 11-bit ids):

* ``id``: lifecycle, ``FF FF FF FF FF FF FF FC`` enable, ``... FD`` disable (motor off);
* ``0x100 + id``: position command, ``float32 position rad, float32 speed limit rad/s`` (LE);
* ``0x7FF`` (shared by every servo of the family): ``[id lo, id hi, CC, 0...]`` asks for a
  status reply, ``[id lo, id hi, 55, 09, timeout u32 ms]`` sets the servo's own
  communication-loss timeout;
* replies on the master id (an option): ``[status << 4 | id & 0xF, position u16, speed u12,
  torque u12, driver degC, rotor degC]``, each a linear map of ``[-max, max]``; status 0
  disabled, 1 enabled, 8 over-voltage, 9 under-voltage, A over-current, B/C over-temperature,
  D communication lost (the servo's own timeout expired: it disabled itself).
"""

from __future__ import annotations

import math
import struct

import can
from pydantic import Field

from mavservo.servos import Fault, FrameId, ProfileOptions, ServoProfile, ServoState
from mavservo.servos.base import NO_FAULT, SimDevice, SimMotor, clamp_int

ENABLE = bytes([0xFF] * 7 + [0xFC])
DISABLE = bytes([0xFF] * 7 + [0xFD])
COMMAND_BASE = 0x100
SHARED_ID = 0x7FF
ASK_STATUS = 0xCC
WRITE_REGISTER = 0x55
TIMEOUT_REGISTER = 0x09

STATUS_DISABLED, STATUS_ENABLED, STATUS_COMM_LOST = 0x0, 0x1, 0xD
STATUS_FAULTS = {
    0x8: Fault.OVER_VOLTAGE,
    0x9: Fault.LOW_VOLTAGE,
    0xA: Fault.OVER_CURRENT,
    0xB: Fault.OVER_TEMPERATURE,
    0xC: Fault.OVER_TEMPERATURE,
    0xE: Fault.OTHER,
}


class ExampleDmOptions(ProfileOptions):
    """Per-servo options: where replies come from, the ranges of the reply fields, the timeout."""

    master_id: int = Field(0x10, ge=0, le=0x7FF, description="CAN id the servo replies on")
    p_max_rad: float = Field(12.5, gt=0, le=100, description="position range +- (rad)")
    v_max_rad_s: float = Field(30.0, gt=0, le=500, description="speed range +- (rad/s)")
    t_max_nm: float = Field(10.0, gt=0, le=500, description="torque range +- (N m)")
    comm_timeout_ms: int = Field(
        1000, ge=0, le=60_000, description="the servo disables itself after this silence (0: never)"
    )


def _to_unsigned(value: float, limit: float, bits: int) -> int:
    top = (1 << bits) - 1
    return clamp_int(round((value + limit) / (2 * limit) * top), 0, top)


def _from_unsigned(field: int, limit: float, bits: int) -> float:
    return field / ((1 << bits) - 1) * 2 * limit - limit


class ExampleDm(ServoProfile):
    """The toy family: polled, with enable / motor-off lifecycle frames and its own timeout."""

    name = "example-dm"
    Options = ExampleDmOptions
    options: ExampleDmOptions
    telemetry = "polled"
    min_id, max_id = 1, 0x7F
    resolution_deg = 0.03  # one step of the u16 position over +-12.5 rad
    replies_per_command = 1
    replies_per_request = 1
    replies_per_lifecycle = 1

    def __init__(self, can_id: int, options: ProfileOptions | None = None, **overrides: object):
        super().__init__(can_id, options, **overrides)
        limit_deg = math.degrees(self.options.p_max_rad)
        self.min_angle_deg, self.max_angle_deg = -limit_deg, limit_deg
        self.max_speed_dps = math.degrees(self.options.v_max_rad_s)
        self.status = STATUS_DISABLED

    def identifiers(self) -> tuple[FrameId, ...]:
        mine = (self.can_id & 0xFF, 0xFF)
        return (
            FrameId(self.can_id, False, "to_servo", "lifecycle"),
            FrameId(COMMAND_BASE + self.can_id, False, "to_servo", "command"),
            FrameId(SHARED_ID, False, "to_servo", "request", first_byte=mine, shared=True),
            FrameId(
                self.options.master_id,
                False,
                "from_servo",
                "reply",
                first_byte=(self.can_id & 0x0F, 0x0F),
            ),
        )

    def position_command(self, angle_deg: float, max_speed_dps: float | None = None) -> can.Message:
        self._check_angle(angle_deg)
        speed = self._speed_limit(max_speed_dps, self.max_speed_dps)
        payload = struct.pack("<ff", math.radians(angle_deg), math.radians(speed))
        return self._frame(COMMAND_BASE + self.can_id, payload)

    def telemetry_requests(self) -> list[can.Message]:
        return [self._frame(SHARED_ID, self._shared_prefix(ASK_STATUS) + bytes(5))]

    def startup_frames(self) -> list[can.Message]:
        timeout = struct.pack("<BI", TIMEOUT_REGISTER, self.options.comm_timeout_ms)
        return [
            self._frame(SHARED_ID, self._shared_prefix(WRITE_REGISTER) + timeout),
            self._frame(self.can_id, ENABLE),
        ]

    def needs_startup(self) -> bool:
        """A reply said the servo is disabled, or disabled itself on its own timeout."""
        return self.last_state is not None and self.status in (STATUS_DISABLED, STATUS_COMM_LOST)

    def release_frames(self) -> list[can.Message]:
        return [self._frame(self.can_id, DISABLE)]

    def shutdown_frames(self) -> list[can.Message]:
        return [self._frame(self.can_id, DISABLE)]

    def is_reply(self, msg: can.Message) -> bool:
        return (
            not msg.is_extended_id
            and not msg.is_remote_frame
            and msg.arbitration_id == self.options.master_id
            and len(msg.data) == 8
            and msg.data[0] & 0x0F == self.can_id & 0x0F
        )

    def decode(self, msg: can.Message, timestamp: float) -> ServoState | None:
        if not self.is_reply(msg):
            return None
        data = bytes(msg.data)
        self.status = data[0] >> 4
        position = _from_unsigned(data[1] << 8 | data[2], self.options.p_max_rad, 16)
        speed = _from_unsigned(data[3] << 4 | data[4] >> 4, self.options.v_max_rad_s, 12)
        torque = _from_unsigned((data[4] & 0x0F) << 8 | data[5], self.options.t_max_nm, 12)
        return self._merge(
            timestamp,
            position_deg=math.degrees(position),
            velocity_dps=math.degrees(speed),
            current_a=torque,  # the toy reports torque; a real profile converts with Kt
            temperature_c=float(max(data[6], data[7])),
            faults=STATUS_FAULTS.get(self.status, NO_FAULT),
        )

    @classmethod
    def sim_device(cls, motor: SimMotor, can_id: int, options: ProfileOptions) -> SimDevice:
        assert isinstance(options, ExampleDmOptions)
        return ExampleDmDevice(motor, can_id, options)

    def _shared_prefix(self, command: int) -> bytes:
        return bytes([self.can_id & 0xFF, self.can_id >> 8, command])

    @staticmethod
    def _frame(arbitration_id: int, payload: bytes) -> can.Message:
        return can.Message(arbitration_id=arbitration_id, is_extended_id=False, data=payload)


class ExampleDmDevice:
    """The simulated servo: starts disabled (a real one powers up so), obeys commands only when
    enabled, and disables itself when its own communication timeout expires."""

    pushes = False

    def __init__(self, motor: SimMotor, can_id: int, options: ExampleDmOptions) -> None:
        self.motor = motor
        self.can_id = can_id
        self.options = options
        self.timeout_s = 0.0
        self.last_frame_at: float | None = None
        self.comm_lost = False
        motor.enabled = False

    def accepts(self, msg: can.Message) -> bool:
        if msg.is_extended_id or len(msg.data) != 8:
            return False
        if msg.arbitration_id in (self.can_id, COMMAND_BASE + self.can_id):
            return True
        data = bytes(msg.data)
        return msg.arbitration_id == SHARED_ID and data[:2] == bytes(
            [self.can_id & 0xFF, self.can_id >> 8]
        )

    def tick(self, now: float) -> None:
        if (
            self.timeout_s
            and self.last_frame_at is not None
            and now - self.last_frame_at > self.timeout_s
            and self.motor.enabled
        ):
            self.motor.disable(now)
            self.comm_lost = True

    def handle(self, msg: can.Message, now: float) -> list[can.Message]:
        self.tick(now)
        self.last_frame_at = now
        data = bytes(msg.data)
        if msg.arbitration_id == self.can_id:
            if data == ENABLE:
                self.motor.enable(now)
                self.comm_lost = False
            elif data == DISABLE:
                self.motor.disable(now)
            else:
                return []
        elif msg.arbitration_id == COMMAND_BASE + self.can_id:
            position, speed = struct.unpack("<ff", data)
            if self.motor.enabled:
                self.motor.command_position(math.degrees(position), math.degrees(speed), now)
        elif data[2] == WRITE_REGISTER and data[3] == TIMEOUT_REGISTER:
            self.timeout_s = struct.unpack_from("<I", data, 4)[0] / 1000
        elif data[2] != ASK_STATUS:
            return []
        return self.status(now)

    def status(self, now: float) -> list[can.Message]:
        motor, options = self.motor, self.options
        if self.comm_lost:
            status = STATUS_COMM_LOST
        else:
            status = STATUS_ENABLED if motor.enabled else STATUS_DISABLED
        position = _to_unsigned(math.radians(motor.position_deg), options.p_max_rad, 16)
        speed = _to_unsigned(math.radians(motor.velocity_dps), options.v_max_rad_s, 12)
        torque = _to_unsigned(motor.measured_current_a(), options.t_max_nm, 12)
        temperature = clamp_int(round(motor.temperature_c), 0, 255)
        payload = bytes(
            [
                status << 4 | (self.can_id & 0x0F),
                position >> 8,
                position & 0xFF,
                speed >> 4,
                (speed & 0x0F) << 4 | torque >> 8,
                torque & 0xFF,
                temperature,
                temperature,
            ]
        )
        return [can.Message(arbitration_id=options.master_id, is_extended_id=False, data=payload)]
