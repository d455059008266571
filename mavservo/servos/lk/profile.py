"""LK-Tech (Lingkong) MF / MG / MS motors over CAN: the bridge's side.

LK's CAN protocol shares the request frame and the position command with MyActuator RMD-X V4
(:mod:`.rmdx`), but not the replies; sources and what is not supported: ``docs/profiles.md``.

Wire facts (LK-TECH "MF/MH/MG/MS motor CAN protocol", single-motor commands; standard 11-bit
ids, little-endian, 8-byte payloads, the reply on the request id ``0x140 + id``):

* ``A4`` multi-turn position with speed limit: ``[A4, 00, max speed u16 1 dps, angle i32
  0.01 deg]``; its reply, like ``9C`` (status 2) and every closed-loop reply:
  ``[cmd, temperature i8 1 degC, iq i16, speed i16 1 dps, encoder u16]`` where iq is a raw
  count in -2048..2048 (MF: 33/4096 A per count, MG: 66/4096 A; MS models put their output
  power -1000..1000 there instead, no current) and the encoder is the single-turn count of the
  model's encoder (14 bits: 0..16383, 15: 0..32767, 16: 0..65535 for one turn);
* ``92`` multi-turn angle: a signed 56-bit value in bytes 1..7, 0.01 deg;
* ``9A`` status 1 (and the reply to ``9B`` clear errors), two layouts by firmware
  (:class:`LkOptions` ``status_1``): ``bus``: ``[9A, temperature i8, voltage u16 0.01 V,
  bus current i16 0.01 A, motor state u8 (0x00 on, 0x10 off), error u8]``; ``legacy``:
  ``[9A, temperature i8, 00, voltage u16 0.1 V, 00, 00, error u8]`` (bits 0 and 3 only);
* ``80`` motor off (clears the running state and the last command), ``81`` stop, ``88`` motor
  on (run): each echoed. After ``80`` the motor answers but does not move until ``88``, so
  the start-up frame is ``88`` (before the first command, after a release and after a 9A that
  reports the motor off).

No communication-loss timeout command exists (RMD-X's ``B3`` is V4 only): a ``release``
failsafe is the bridge's own.
"""

from __future__ import annotations

import math
import struct
from typing import ClassVar, Literal

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
CMD_MOTOR_STOP = 0x81
CMD_MOTOR_RUN = 0x88
CMD_POSITION = 0xA4
CMD_STATUS_2 = 0x9C
CMD_STATUS_1 = 0x9A
CMD_CLEAR_ERRORS = 0x9B
CMD_MULTI_TURN_ANGLE = 0x92

REQUEST_BASE = 0x140
"""Requests and replies share ``0x140 + id``."""

IQ_FULL_SCALE_A: dict[str, float | None] = {"MF": 16.5, "MG": 33.0, "MS": None}
"""Current at iq = 2048 per model line (MF 33/4096 A per count, MG 66/4096 A); MS models
report output power in that field, not a current (None)."""
IQ_FULL_SCALE_COUNT = 2048

MOTOR_STATE_OFF = 0x10
"""9A ``bus`` layout, byte 6: 0x00 the motor is on, 0x10 it is off."""

ERROR_BITS: dict[int, Fault] = {
    0x01: Fault.LOW_VOLTAGE,
    0x02: Fault.OVER_VOLTAGE,
    0x04: Fault.OVER_TEMPERATURE,  # driver temperature
    0x08: Fault.OVER_TEMPERATURE,  # motor temperature
    0x10: Fault.OVER_CURRENT,
    0x20: Fault.DRIVER,  # short circuit
    0x40: Fault.STALL,
    0x80: Fault.COMMUNICATION_LOST,  # input signal (control) timeout
}
"""9A error byte, ``bus`` layout: every bit named."""

LEGACY_ERROR_BITS: dict[int, Fault] = {0x01: Fault.LOW_VOLTAGE, 0x08: Fault.OVER_TEMPERATURE}
"""9A error byte, ``legacy`` layout: bit 0 voltage, bit 3 temperature; others are OTHER."""

_I32_MAX = 2**31 - 1
_I56_SIGN = 1 << 55


def faults_from_error_byte(byte: int, table: dict[int, Fault]) -> Fault:
    """Named faults of a 9A error byte; bits the table does not know are ``Fault.OTHER``."""
    faults = NO_FAULT
    for bit, fault in table.items():
        if byte & bit:
            faults |= fault
            byte &= ~bit
    return faults | Fault.OTHER if byte else faults


class LkOptions(ProfileOptions):
    """Per-servo options of the LK profile: what the model is, and how often to read what."""

    model: Literal["MF", "MG", "MS"] = Field(
        "MF", description="model line: the iq scale (MF 16.5 A, MG 33 A full scale; MS: none)"
    )
    encoder_bits: int = Field(
        14, ge=14, le=16, description="bits of the encoder count in closed-loop replies (one turn)"
    )
    gear_ratio: float = Field(
        1.0,
        ge=1.0,
        le=100.0,
        description="reduction between the rotor, whose single-turn encoder count the replies "
        "carry, and the output (1: direct drive; i-series models: their ratio)",
    )
    status_1: Literal["bus", "legacy"] = Field(
        "bus",
        description="9A layout: bus (voltage 0.01 V, current, motor state) or legacy "
        "(voltage 0.1 V in bytes 3..4; the English V2.35 table)",
    )
    clear_errors_on_start: bool = Field(
        False,
        description="send 0x9B (clear error flags) before motor on at start-up, so an error "
        "whose cause is gone no longer blocks the motor (off: a latched error stays visible)",
    )
    default_speed_dps: float = Field(
        360.0, gt=0, le=65535, description="speed limit of a command that names none (deg/s)"
    )
    fault_poll_every: int | None = Field(
        10, ge=1, le=1000, description="every Nth poll reads 9A (faults, voltage); null: never"
    )
    multi_turn_poll_every: int | None = Field(
        5,
        ge=1,
        le=1000,
        description="every Nth poll (and the first) reads 92, the absolute multi-turn angle "
        "the single-turn encoder count is unwrapped against; null: never",
    )


class LkTech(ServoProfile):
    """LK-Tech MF / MG / MS (module docstring); replies on the request id ``0x140 + id``.

    Position: 92 gives the absolute multi-turn angle (0.01 deg), read at the first poll and
    every ``multi_turn_poll_every``; between, the rotor's single-turn encoder count of 9C / A4
    replies is unwrapped to the turn nearest the last known position (through ``gear_ratio``
    on a geared model), so the position is right as long as the output moves less than half a
    rotor turn between two replies. Because request and reply share
    an id, a loopback echo of our own request would look like a reply: use loopback adapter
    mode with this profile only to test the adapter itself.
    """

    Options: ClassVar[type[ProfileOptions]] = LkOptions
    options: LkOptions

    name = "lk"
    min_id, max_id = 1, 32
    min_angle_deg = -_I32_MAX / 100
    max_angle_deg = _I32_MAX / 100
    max_speed_dps = 65535.0
    replies_per_lifecycle = 1
    """0x88 and 0x80 are echoed."""

    def __init__(self, can_id: int, options: ProfileOptions | None = None, **overrides: object):
        super().__init__(can_id, options, **overrides)
        self.resolution_deg = 360.0 / (1 << self.options.encoder_bits) / self.options.gear_ratio
        full_scale = IQ_FULL_SCALE_A[self.options.model]
        self.amps_per_count = None if full_scale is None else full_scale / IQ_FULL_SCALE_COUNT
        self.polls = 0
        """Telemetry polls sent so far (:meth:`poll_sent`); drives the 9A / 92 interleaving."""
        self.motor_off: bool | None = None
        """The last 9A's motor state (``bus`` layout): True off, False on, None not known."""

    @property
    def request_id(self) -> int:
        return REQUEST_BASE + self.can_id

    def _request(self, command: int, rest: bytes = bytes(7)) -> can.Message:
        return can.Message(
            arbitration_id=self.request_id, is_extended_id=False, data=bytes([command]) + rest
        )

    def identifiers(self) -> tuple[FrameId, ...]:
        return (
            FrameId(self.request_id, False, "to_servo", "command"),
            FrameId(self.request_id, False, "from_servo", "reply"),
        )

    def startup_frames(self) -> list[can.Message]:
        """Motor on (0x88): an LK motor turned off (0x80, a release or shutdown) answers but
        does not move until it hears it; harmless on a motor that is on. With
        ``clear_errors_on_start``, clear error flags (0x9B) first."""
        clear = [self._request(CMD_CLEAR_ERRORS)] if self.options.clear_errors_on_start else []
        return [*clear, self._request(CMD_MOTOR_RUN)]

    def needs_startup(self) -> bool:
        """A 9A said the motor is off (power-cycled into off, another host's 0x80)."""
        return bool(self.motor_off)

    def release_frames(self) -> list[can.Message]:
        """Motor off (0x80): torque free until 0x88 and the next command."""
        return [self._request(CMD_MOTOR_OFF)]

    @classmethod
    def sim_device(cls, motor: SimMotor, can_id: int, options: ProfileOptions) -> SimDevice:
        return simulated_device(cls, motor, can_id, options)

    def position_command(self, angle_deg: float, max_speed_dps: float | None = None) -> can.Message:
        self._check_angle(angle_deg)
        speed = self._speed_limit(max_speed_dps, self.options.default_speed_dps)
        speed_field = max(1, round(speed)) if speed > 0 else 0
        angle_field = max(-_I32_MAX, min(_I32_MAX, round(angle_deg * 100)))
        return self._request(CMD_POSITION, struct.pack("<BHi", 0, speed_field, angle_field))

    def telemetry_requests(self) -> list[can.Message]:
        poll = self.polls + 1  # the poll these frames are for; counted when it is sent
        fault_every = self.options.fault_poll_every
        turn_every = self.options.multi_turn_poll_every
        if turn_every and poll == 1:
            command = CMD_MULTI_TURN_ANGLE  # the absolute angle before any unwrapping
        elif fault_every and poll % fault_every == 0:
            command = CMD_STATUS_1  # before the angle: faults must not starve
        elif turn_every and poll % turn_every == 0:
            command = CMD_MULTI_TURN_ANGLE
        else:
            command = CMD_STATUS_2
        return [self._request(command)]

    def poll_sent(self) -> None:
        self.polls += 1

    def is_reply(self, msg: can.Message) -> bool:
        return (
            not msg.is_extended_id
            and not msg.is_remote_frame
            and msg.arbitration_id == self.request_id
            and len(msg.data) == 8
        )

    def exchange_key(self, msg: can.Message) -> int | None:
        """The command byte: every reply echoes the command byte of the request it answers
        (9B answers with 9B and the 9A layout)."""
        return msg.data[0] if msg.data else None

    def decode(self, msg: can.Message, timestamp: float) -> ServoState | None:
        if not self.is_reply(msg):
            return None
        data = bytes(msg.data)
        command = data[0]
        if command in (CMD_POSITION, CMD_STATUS_2):
            _, temp, iq, speed, encoder = struct.unpack("<BbhhH", data)
            return self._merge(
                timestamp,
                position_deg=self._unwrap(encoder),
                velocity_dps=float(speed),
                current_a=None if self.amps_per_count is None else iq * self.amps_per_count,
                temperature_c=float(temp),
            )
        if command == CMD_MULTI_TURN_ANGLE:
            raw = int.from_bytes(data[1:8], "little")
            angle = raw - (1 << 56) if raw & _I56_SIGN else raw
            return self._merge(timestamp, position_deg=angle / 100)
        if command in (CMD_STATUS_1, CMD_CLEAR_ERRORS):
            return self._status_1(data, timestamp)
        if command in (CMD_MOTOR_OFF, CMD_MOTOR_STOP, CMD_MOTOR_RUN):
            if command == CMD_MOTOR_RUN:
                self.motor_off = False
            return self._merge(timestamp)  # an echo: alive, nothing new to report
        return None

    def _status_1(self, data: bytes, timestamp: float) -> ServoState:
        temp = struct.unpack_from("<b", data, 1)[0]
        if self.options.status_1 == "legacy":
            (voltage,) = struct.unpack_from("<H", data, 3)
            return self._merge(
                timestamp,
                temperature_c=float(temp),
                voltage_v=voltage / 10,
                faults=faults_from_error_byte(data[7], LEGACY_ERROR_BITS),
            )
        voltage, _current, state, error = struct.unpack_from("<HhBB", data, 2)
        self.motor_off = state == MOTOR_STATE_OFF
        return self._merge(
            timestamp,
            temperature_c=float(temp),
            voltage_v=voltage / 100,
            faults=faults_from_error_byte(error, ERROR_BITS),
        )

    def _unwrap(self, encoder: int) -> float:
        """The rotor's single-turn encoder count as the output angle nearest the last known
        position (the first reading without one: the rotor turn nearest 0)."""
        turn = 1 << self.options.encoder_bits
        gear = self.options.gear_ratio
        rotor = (encoder % turn) * 360.0 / turn
        last = self.last_state.position_deg if self.last_state is not None else math.nan
        reference = 0.0 if math.isnan(last) else last * gear  # in rotor degrees
        return (rotor + 360.0 * round((reference - rotor) / 360.0)) / gear
