"""MyActuator RMD-X (protocol V4.x) and the LK-Tech / older-firmware variant.

Wire facts (standard 11-bit IDs, little-endian, 8-byte payloads, one reply per request):

* requests go to ``0x140 + id``; V4 firmware replies on ``0x240 + id``, LK-Tech and older RMD
  firmware reply on ``0x140 + id`` (the only difference between the two profiles here);
* ``A4`` absolute position: ``[A4, 00, max speed u16 dps, angle i32 0.01 deg]``;
* ``9C`` read status 2; replies to A4 and 9C:
  ``[cmd, temperature i8 degC, iq i16 0.01 A, speed i16 dps, angle i16 whole degrees]``;
* ``92`` multi-turn angle: ``angle i32 0.01 deg`` in bytes 4..7 (the only fine position);
* ``9A`` status 1: ``[9A, temperature i8, 00, brake u8, voltage u16 0.1 V, error u16]``;
* ``80`` motor off (V4 "motor shutdown": output off, running state cleared; the next closed-loop
  command runs it again), echoed in the reply; the release and shutdown frame;
* ``B3`` (V4) communication-loss protection: ``time u32 ms`` in bytes 4..7, echoed; when no frame
  arrives for that long the servo turns its motor off by itself; 0 disables it. LK-Tech has no
  such command, so the ``lk`` profile sends none.

Range policy: an angle that is not finite or does not fit the i32 0.01-deg field raises
``ValueError``; a speed limit saturates at the u16 field maximum (65535 dps) and is never sent
as 0 (which the servo would read as "no motion").
"""

from __future__ import annotations

import math
import struct
from typing import ClassVar

import can
from pydantic import Field

from .base import (
    NO_FAULT,
    Fault,
    FrameId,
    ProfileOptions,
    ServoProfile,
    ServoState,
    SimDevice,
    SimMotor,
    clamp_int,
)

CMD_MOTOR_OFF = 0x80
CMD_COMM_TIMEOUT = 0xB3
CMD_POSITION = 0xA4
CMD_STATUS_2 = 0x9C
CMD_MULTI_TURN_ANGLE = 0x92
CMD_STATUS_1 = 0x9A

REQUEST_BASE = 0x140
REPLY_BASE_V4 = 0x240

ERROR_BITS: dict[int, Fault] = {
    0x0002: Fault.STALL,
    0x0004: Fault.LOW_VOLTAGE,
    0x0008: Fault.OVER_VOLTAGE,
    0x0010: Fault.OVER_CURRENT,
    0x0040: Fault.POWER,
    0x0100: Fault.OVERSPEED,
    0x1000: Fault.OVER_TEMPERATURE,
    0x2000: Fault.ENCODER,
}
"""9A error word bits as documented; any other set bit decodes as ``Fault.OTHER``."""

_I32_MAX = 2**31 - 1


def faults_from_error_word(word: int) -> Fault:
    """Named faults for a 9A error word; unknown bits are reported, not dropped."""
    faults = NO_FAULT
    for bit, fault in ERROR_BITS.items():
        if word & bit:
            faults |= fault
            word &= ~bit
    return faults | Fault.OTHER if word else faults


def error_word_from_faults(faults: Fault) -> int:
    """Inverse of :func:`faults_from_error_word` for the named bits (used by the simulator)."""
    return sum(bit for bit, fault in ERROR_BITS.items() if fault in faults)


class RmdOptions(ProfileOptions):
    """Per-servo options of the RMD-X and LK profiles."""

    default_speed_dps: float = Field(
        360.0, gt=0, le=65535, description="speed limit of a command that names none (deg/s)"
    )
    fault_poll_every: int | None = Field(
        10, ge=1, le=1000, description="every Nth poll reads 9A (faults, voltage); null: never"
    )
    multi_turn_poll_every: int | None = Field(
        None, ge=1, le=1000, description="every Nth poll reads 92 (0.01-deg angle); null: never"
    )


class RmdXOptions(RmdOptions):
    """RMD-X V4 adds the servo's own communication-loss timeout (0xB3)."""

    comm_timeout_ms: int = Field(
        1000,
        ge=0,
        le=60_000,
        description="the servo turns its motor off after this long without a frame (0: never)",
    )


class RmdX(ServoProfile):
    """RMD-X V4: replies on ``0x240 + id``.

    Options (:class:`RmdXOptions`): ``fault_poll_every``: every Nth telemetry poll asks for 9A
    (faults, voltage) instead of 9C, so faults surface without doubling the bus load;
    ``multi_turn_poll_every`` does the same for 92 (a 0.01-deg position instead of whole
    degrees), None disables either; ``comm_timeout_ms`` goes to the servo at start-up (0xB3).
    """

    STOP_BEHAVIOUR = (
        "holds its last target; with comm_timeout_ms set (0xB3, V4 firmware) it turns its motor "
        "off that long after the last frame"
    )

    Options: ClassVar[type[ProfileOptions]] = RmdXOptions
    options: RmdOptions

    name = "rmd-x"
    resolution_deg = 1.0
    min_id, max_id = 1, 32
    min_angle_deg = -_I32_MAX / 100
    max_angle_deg = _I32_MAX / 100
    max_speed_dps = 65535.0
    reply_base = REPLY_BASE_V4
    replies_per_lifecycle = 1
    """0x80 and 0xB3 are echoed."""

    has_comm_timeout = True
    """V4 firmware has 0xB3; LK-Tech does not."""

    def __init__(self, can_id: int, options: ProfileOptions | None = None, **overrides: object):
        super().__init__(can_id, options, **overrides)
        self.default_speed_dps = self.options.default_speed_dps
        self.fault_poll_every = self.options.fault_poll_every
        self.multi_turn_poll_every = self.options.multi_turn_poll_every
        self.polls = 0
        """Telemetry polls sent so far (:meth:`poll_sent`); drives the 9A / 92 interleaving."""

    @property
    def request_id(self) -> int:
        return REQUEST_BASE + self.can_id

    @property
    def reply_id(self) -> int:
        return self.reply_base + self.can_id

    def _request(self, payload: bytes) -> can.Message:
        return can.Message(arbitration_id=self.request_id, is_extended_id=False, data=payload)

    def identifiers(self) -> tuple[FrameId, ...]:
        """Requests, commands and lifecycle frames on 0x140 + id; replies on the reply id."""
        return (
            FrameId(self.request_id, False, "to_servo", "command"),
            FrameId(self.reply_id, False, "from_servo", "reply"),
        )

    def startup_frames(self) -> list[can.Message]:
        """V4: the servo's own communication-loss timeout (0xB3), so it turns its motor off by
        itself when the companion dies."""
        if not self.has_comm_timeout:
            return []
        timeout_ms = getattr(self.options, "comm_timeout_ms", 0)
        return [self._request(struct.pack("<BBBBI", CMD_COMM_TIMEOUT, 0, 0, 0, timeout_ms))]

    def release_frames(self) -> list[can.Message]:
        """Motor off (0x80): torque free until the next position command."""
        return [self._request(bytes([CMD_MOTOR_OFF, 0, 0, 0, 0, 0, 0, 0]))]

    @classmethod
    def sim_device(cls, motor: SimMotor, can_id: int, options: ProfileOptions) -> SimDevice:
        return RmdDevice(
            motor, REQUEST_BASE + can_id, cls.reply_base + can_id, cls.has_comm_timeout
        )

    def position_command(self, angle_deg: float, max_speed_dps: float | None = None) -> can.Message:
        self._check_angle(angle_deg)
        speed = self._speed_limit(max_speed_dps, self.default_speed_dps)
        speed_field = max(1, round(speed)) if speed > 0 else 0
        angle_field = max(-_I32_MAX, min(_I32_MAX, round(angle_deg * 100)))
        return self._request(struct.pack("<BBHi", CMD_POSITION, 0, speed_field, angle_field))

    def telemetry_requests(self) -> list[can.Message]:
        poll = self.polls + 1  # the poll these frames are for; counted when it is sent
        if self.fault_poll_every and poll % self.fault_poll_every == 0:
            command = CMD_STATUS_1
        elif self.multi_turn_poll_every and poll % self.multi_turn_poll_every == 0:
            command = CMD_MULTI_TURN_ANGLE
        else:
            command = CMD_STATUS_2
        return [self._request(bytes([command, 0, 0, 0, 0, 0, 0, 0]))]

    def poll_sent(self) -> None:
        self.polls += 1

    def is_reply(self, msg: can.Message) -> bool:
        return (
            not msg.is_extended_id
            and not msg.is_remote_frame
            and msg.arbitration_id == self.reply_id
            and len(msg.data) == 8
        )

    def exchange_key(self, msg: can.Message) -> int | None:
        """The command byte: every reply echoes the command byte of the request it answers."""
        return msg.data[0] if msg.data else None

    def decode(self, msg: can.Message, timestamp: float) -> ServoState | None:
        if not self.is_reply(msg):
            return None
        data = bytes(msg.data)
        command = data[0]
        if command in (CMD_POSITION, CMD_STATUS_2):
            _, temp, iq, speed, angle = struct.unpack("<BbhhH", data)
            angle = angle - 0x10000 if angle >= 0x8000 else angle
            return self._merge(
                timestamp,
                position_deg=self._coarse_position(float(angle)),
                velocity_dps=float(speed),
                current_a=iq / 100,
                temperature_c=float(temp),
            )
        if command == CMD_MULTI_TURN_ANGLE:
            (angle,) = struct.unpack_from("<i", data, 4)
            return self._merge(timestamp, position_deg=angle / 100)
        if command in (CMD_MOTOR_OFF, CMD_COMM_TIMEOUT):
            return self._merge(timestamp)  # an echo: alive, nothing new to report
        if command == CMD_STATUS_1:
            _, temp, _, _, voltage, error = struct.unpack("<BbBBHH", data)
            return self._merge(
                timestamp,
                temperature_c=float(temp),
                voltage_v=voltage / 10,
                faults=faults_from_error_word(error),
            )
        return None

    def _coarse_position(self, whole_degrees: float) -> float:
        """Keep a finer earlier reading (from 92) while the whole-degree one agrees with it.

        Without this, interleaving 92 and 9C polls would make the position jump between 0.01
        and 1 degree resolution on every poll.
        """
        last = self.last_state
        if (
            last is not None
            and not math.isnan(last.position_deg)
            and abs(last.position_deg - whole_degrees) <= 0.5
        ):
            return last.position_deg
        return whole_degrees


class LkTech(RmdX):
    """LK-Tech and older RMD firmware: same payloads, reply on the request ID ``0x140 + id``,
    no communication-loss timeout command.

    Because request and reply share an ID, a loopback echo of our own request would look like
    a reply; only use loopback adapter mode with this profile for testing the adapter itself.
    """

    name = "lk"
    Options = RmdOptions
    reply_base = REQUEST_BASE
    has_comm_timeout = False


def _round_half_up(value: float) -> int:
    return math.floor(value + 0.5)


class RmdDevice:
    """Device side of RMD-X V4 (replies on 0x240 + id) and LK / old firmware (0x140 + id).

    0x80 turns the motor off (a released motor does not move); a position command runs it
    again. With a communication-loss timeout set (0xB3, V4 only), a servo that hears nothing
    for that long turns its motor off by itself.
    """

    pushes = False

    def __init__(
        self, motor: SimMotor, request_id: int, reply_id: int, has_comm_timeout: bool
    ) -> None:
        self.motor = motor
        self.request_id = request_id
        self.reply_id = reply_id
        self.has_comm_timeout = has_comm_timeout
        self.comm_timeout_s = 0.0
        self.last_frame_at: float | None = None

    def accepts(self, msg: can.Message) -> bool:
        return (
            not msg.is_extended_id and msg.arbitration_id == self.request_id and len(msg.data) == 8
        )

    def tick(self, now: float) -> None:
        if (
            self.comm_timeout_s > 0
            and self.last_frame_at is not None
            and now - self.last_frame_at > self.comm_timeout_s
            and self.motor.enabled
        ):
            self.motor.disable(now)

    def handle(self, msg: can.Message, now: float) -> list[can.Message]:
        self.tick(now)
        self.last_frame_at = now
        data = bytes(msg.data)
        command = data[0]
        motor = self.motor
        if command == CMD_POSITION:
            _, _, speed, angle = struct.unpack("<BBHi", data)
            if not motor.enabled:
                motor.enable(now)
            motor.command_position(angle / 100, float(speed), now)
            return [self._status_2(command)]
        if command == CMD_MOTOR_OFF:
            motor.disable(now)
            return [self._reply(data)]
        if command == CMD_COMM_TIMEOUT and self.has_comm_timeout:
            (timeout_ms,) = struct.unpack_from("<I", data, 4)
            self.comm_timeout_s = timeout_ms / 1000
            return [self._reply(data)]
        if command == CMD_STATUS_2:
            return [self._status_2(command)]
        if command == CMD_MULTI_TURN_ANGLE:
            angle = clamp_int(round(motor.position_deg * 100), -(2**31), 2**31 - 1)
            return [self._reply(struct.pack("<BBBBi", command, 0, 0, 0, angle))]
        if command == CMD_STATUS_1:
            return [self._status_1(command)]
        return []

    def status(self, now: float) -> list[can.Message]:
        return []

    def _status_1(self, command: int) -> can.Message:
        motor = self.motor
        return self._reply(
            struct.pack(
                "<BbBBHH",
                command,
                clamp_int(round(motor.temperature_c), -128, 127),
                0,
                0,
                clamp_int(round(motor.voltage_v * 10), 0, 0xFFFF),
                error_word_from_faults(motor.active_faults),
            )
        )

    def _status_2(self, command: int) -> can.Message:
        motor = self.motor
        return self._reply(
            struct.pack(
                "<Bbhhh",
                command,
                clamp_int(round(motor.temperature_c), -128, 127),
                clamp_int(round(motor.measured_current_a() * 100), -32768, 32767),
                clamp_int(round(motor.velocity_dps), -32768, 32767),
                clamp_int(_round_half_up(motor.position_deg), -32768, 32767),
            )
        )

    def _reply(self, payload: bytes) -> can.Message:
        return can.Message(arbitration_id=self.reply_id, is_extended_id=False, data=payload)
