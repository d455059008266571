"""MyActuator RMD-X servos with protocol V4.x firmware.

Older MyActuator firmware and LK-Tech motors (:mod:`.lk`) answer on the request id in another
layout (raw iq counts, an encoder count instead of degrees, another 9A): this profile does not
decode them.

Wire facts (standard 11-bit IDs, little-endian, 8-byte payloads, one reply per request):

* requests go to ``0x140 + id``; V4 firmware replies on ``0x240 + id``;
* ``A4`` absolute position: ``[A4, 00, max speed u16 dps, angle i32 0.01 deg]``;
* ``9C`` read status 2; replies to A4 and 9C:
  ``[cmd, temperature i8 degC, iq i16 0.01 A, speed i16 dps, angle i16 whole degrees]``;
* ``92`` multi-turn angle: ``angle i32 0.01 deg`` in bytes 4..7 (the only fine position);
* ``9A`` status 1: ``[9A, temperature i8, 00, brake u8, voltage u16 0.1 V, error u16]``;
* ``80`` motor off (V4 "motor shutdown": output off, running state cleared; the next closed-loop
  command runs it again), echoed in the reply; the release and shutdown frame;
* ``B3`` (V4) communication-loss protection: ``time u32 ms`` in bytes 4..7, echoed; when no frame
  arrives for that long the servo turns its motor off by itself; 0 disables it;
* ``77`` brake release, ``78`` brake lock (V4, models with a holding brake), echoed: such a
  model does not move while its brake holds, and the brake locks when it powers off.

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

CMD_MOTOR_OFF = 0x80
CMD_BRAKE_RELEASE = 0x77
CMD_BRAKE_LOCK = 0x78
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


class RmdXOptions(ProfileOptions):
    """Per-servo options of the RMD-X profile."""

    default_speed_dps: float = Field(
        360.0, gt=0, le=65535, description="speed limit of a command that names none (deg/s)"
    )
    fault_poll_every: int | None = Field(
        10, ge=1, le=1000, description="every Nth poll reads 9A (faults, voltage); null: never"
    )
    multi_turn_poll_every: int | None = Field(
        None, ge=1, le=1000, description="every Nth poll reads 92 (0.01-deg angle); null: never"
    )
    comm_timeout_ms: int = Field(
        1000,
        ge=0,
        le=60_000,
        description="the servo turns its motor off after this long without a frame (0: never)",
    )
    brake: bool = Field(
        False,
        description="the model has a holding brake: 0x77 releases it at start-up (before the "
        "first command), 0x78 locks it on release and shutdown",
    )


RmdOptions = RmdXOptions
"""The former name (the LK options now live in :mod:`.lk`)."""


class RmdX(ServoProfile):
    """RMD-X V4: replies on ``0x240 + id``.

    Options (:class:`RmdXOptions`): ``fault_poll_every``: every Nth telemetry poll asks for 9A
    (faults, voltage) instead of 9C, so faults surface without doubling the bus load;
    ``multi_turn_poll_every`` does the same for 92 (a 0.01-deg position instead of whole
    degrees), None disables either; ``comm_timeout_ms`` goes to the servo at start-up (0xB3).
    """

    STOP_BEHAVIOUR = "holds its last target (no timeout of its own before V4 firmware)"

    Options: ClassVar[type[ProfileOptions]] = RmdXOptions
    options: RmdXOptions

    name = "rmd-x"
    resolution_deg = 1.0
    min_id, max_id = 1, 32
    min_angle_deg = -_I32_MAX / 100
    max_angle_deg = _I32_MAX / 100
    max_speed_dps = 65535.0
    reply_base = REPLY_BASE_V4
    replies_per_lifecycle = 1
    """0x80, 0xB3, 0x77 and 0x78 are echoed."""

    def __init__(self, can_id: int, options: ProfileOptions | None = None, **overrides: object):
        super().__init__(can_id, options, **overrides)
        self.default_speed_dps = self.options.default_speed_dps
        self.fault_poll_every = self.options.fault_poll_every
        self.multi_turn_poll_every = self.options.multi_turn_poll_every
        self.polls = 0
        """Telemetry polls sent so far (:meth:`poll_sent`); drives the 9A / 92 interleaving."""

    def stop_behaviour(self) -> str:
        """With ``comm_timeout_ms`` (written at start-up, 0xB3) its value: a stop line that
        names the setting but not its value left the crew to look it up (issue 37). Not a
        :class:`~mavservo.servos.base.CommTimeout`: firmware before V4 ignores 0xB3."""
        timeout_ms = self.options.comm_timeout_ms
        if not timeout_ms:
            return self.STOP_BEHAVIOUR
        return (
            f"holds its last target; motor off {timeout_ms / 1000:g} s after the last frame "
            "(comm_timeout_ms; firmware before V4 holds on)"
        )

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
        """The servo's own communication-loss timeout (0xB3), so it turns its motor off by
        itself when the companion dies; with a holding brake, then brake release (0x77): the
        V4 manual's brake model does not move while its brake holds."""
        timeout_ms = self.options.comm_timeout_ms
        frames = [self._request(struct.pack("<BBBBI", CMD_COMM_TIMEOUT, 0, 0, 0, timeout_ms))]
        if self.options.brake:
            frames.append(self._request(bytes([CMD_BRAKE_RELEASE]) + bytes(7)))
        return frames

    def release_frames(self) -> list[can.Message]:
        """Motor off (0x80): torque free until the next position command; with a holding
        brake, then brake lock (0x78), so the load is held rather than dropped."""
        frames = [self._request(bytes([CMD_MOTOR_OFF, 0, 0, 0, 0, 0, 0, 0]))]
        if self.options.brake:
            frames.append(self._request(bytes([CMD_BRAKE_LOCK]) + bytes(7)))
        return frames

    def shutdown_frames(self) -> list[can.Message]:
        """With a holding brake: brake lock (0x78) when the bridge stops (the manual: the brake
        also locks when the servo powers off). Without: none."""
        if not self.options.brake:
            return []
        return [self._request(bytes([CMD_BRAKE_LOCK]) + bytes(7))]

    @classmethod
    def sim_device(cls, motor: SimMotor, can_id: int, options: ProfileOptions) -> SimDevice:
        return simulated_device(cls, motor, can_id, options)

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
        if command in (CMD_MOTOR_OFF, CMD_COMM_TIMEOUT, CMD_BRAKE_RELEASE, CMD_BRAKE_LOCK):
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
