"""A simulated LK-Tech MF / MG / MS motor, written from LK's CAN protocol document (sources:
``docs/profiles.md``), not from the ``lk`` profile: it imports nothing of it.

What the device does, as the document states it (single-motor commands, request and reply on
``0x140 + id``, 8 data bytes, little-endian):

* it powers up on (motor state 0x00); ``0x80`` (motor off) turns the motor off and forgets the
  last command: it still answers every frame, but a position command does not move it until
  ``0x88`` (motor on / run) came; ``0x81`` (stop) holds it where it is until ``0x88``;
  ``0x80``, ``0x81`` and ``0x88`` are echoed;
* ``A4`` (multi-turn position, speed limit) moves a running motor and answers, like ``9C``,
  with temperature, iq (a count of 33/4096 A on MF, 66/4096 A on MG, saturating at +-2048; MS
  models report output power there: this simulation reports 0), speed in dps and the
  single-turn encoder count of the model's encoder;
* ``92`` answers the multi-turn angle, 0.01 deg, as a signed 56-bit value in bytes 1..7;
* ``9A`` answers temperature, voltage, bus current, motor state and the error byte in the
  firmware's layout (the servo's ``status_1`` option); ``9B`` (clear errors) answers the same
  with its own command byte (an injected fault of the simulation stays until it is lifted).

Commands it does not simulate (torque, speed and single-turn position control, encoder and PID
writes) get no answer.
"""

from __future__ import annotations

import can

from ..base import Fault, ProfileOptions, SimMotor

REQUEST_ID_BASE = 0x140

_OFF, _STOP, _RUN = 0x80, 0x81, 0x88
_MOVE_MULTI_TURN_LIMITED = 0xA4
_READ_MULTI_TURN = 0x92
_READ_STATE_1, _CLEAR_ERRORS, _READ_STATE_2 = 0x9A, 0x9B, 0x9C

_AMPS_AT_2048 = {"MF": 16.5, "MG": 33.0}
"""MF: 33/4096 A per iq count, MG: 66/4096 A (the document's closed-loop reply notes)."""

_ERROR_BIT = (
    (Fault.LOW_VOLTAGE, 0x01),
    (Fault.OVER_VOLTAGE, 0x02),
    (Fault.OVER_TEMPERATURE, 0x08),
    (Fault.OVER_CURRENT, 0x10),
    (Fault.DRIVER, 0x20),
    (Fault.STALL, 0x40),
    (Fault.COMMUNICATION_LOST, 0x80),
)
"""Error byte of the current 9A layout: bit 0 low voltage, 1 high voltage, 2 driver
temperature, 3 motor temperature, 4 over-current, 5 short circuit, 6 stall, 7 input timeout."""


def _field(value: float, low: int, high: int) -> int:
    """A reading as the integer a field can hold (saturated, rounded half away from zero)."""
    whole = int(value + 0.5) if value >= 0 else -int(-value + 0.5)
    return min(high, max(low, whole))


class LkMotorDevice:
    """One LK motor on a :class:`SimMotor` (module docstring)."""

    pushes = False

    def __init__(self, motor: SimMotor, can_id: int, options: ProfileOptions) -> None:
        setup = options.model_dump()
        self.motor = motor
        self.frame_id = REQUEST_ID_BASE + can_id
        self.model: str = setup.get("model", "MF")
        self.counts_per_turn = 1 << int(setup.get("encoder_bits", 14))
        self.reduction = float(setup.get("gear_ratio", 1.0))
        """Rotor turns per output turn: the encoder sits on the rotor."""
        self.legacy_state_1 = setup.get("status_1", "bus") == "legacy"
        self.on = True
        """Motor state: on from power-up, off after 0x80 until 0x88."""
        self.stopped = False
        """After 0x81: holding, ignoring motion commands until 0x88."""

    def accepts(self, msg: can.Message) -> bool:
        return (
            not msg.is_extended_id
            and not msg.is_remote_frame
            and msg.arbitration_id == self.frame_id
            and len(msg.data) == 8
        )

    def tick(self, now: float) -> None:
        return None

    def status(self, now: float) -> list[can.Message]:
        return []

    def handle(self, msg: can.Message, now: float) -> list[can.Message]:
        data = bytes(msg.data)
        command = data[0]
        if command == _OFF:
            self.on = False
            self.stopped = False
            self.motor.disable(now)
            return [self._answer(data)]
        if command == _STOP:
            self.stopped = True
            self.motor.command_position(self.motor.position_deg, None, now)
            return [self._answer(data)]
        if command == _RUN:
            if not self.on:
                self.motor.enable(now)
            self.on = True
            self.stopped = False
            return [self._answer(data)]
        if command == _MOVE_MULTI_TURN_LIMITED:
            speed_dps = int.from_bytes(data[2:4], "little")
            target = int.from_bytes(data[4:8], "little", signed=True) / 100
            if self.on and not self.stopped:
                self.motor.command_position(target, float(speed_dps), now)
            return [self._state_2(command)]
        if command == _READ_STATE_2:
            return [self._state_2(command)]
        if command == _READ_MULTI_TURN:
            hundredths = _field(self.motor.position_deg * 100, -(2**55), 2**55 - 1)
            return [self._answer(bytes([command]) + hundredths.to_bytes(7, "little", signed=True))]
        if command in (_READ_STATE_1, _CLEAR_ERRORS):
            return [self._state_1(command)]
        return []

    def _state_1(self, command: int) -> can.Message:
        motor = self.motor
        temperature = _field(motor.temperature_c, -128, 127).to_bytes(1, "little", signed=True)
        error = 0
        for fault, bit in _ERROR_BIT:
            if fault in motor.active_faults:
                error |= bit
        if self.legacy_state_1:  # voltage 0.1 V in bytes 3..4; error bits 0 and 3 only
            volts = _field(motor.voltage_v * 10, 0, 0xFFFF).to_bytes(2, "little")
            body = temperature + b"\x00" + volts + b"\x00\x00" + bytes([error & 0x09])
        else:
            volts = _field(motor.voltage_v * 100, 0, 0xFFFF).to_bytes(2, "little")
            amps = _field(motor.measured_current_a() * 100, -32768, 32767)
            state = 0x00 if self.on else 0x10
            body = temperature + volts + amps.to_bytes(2, "little", signed=True)
            body += bytes([state, error])
        return self._answer(bytes([command]) + body)

    def _state_2(self, command: int) -> can.Message:
        motor = self.motor
        full_scale = _AMPS_AT_2048.get(self.model)
        iq = (
            0
            if full_scale is None
            else _field(motor.measured_current_a() * 2048 / full_scale, -2048, 2048)
        )
        turn = (motor.position_deg * self.reduction) % 360.0  # the rotor's angle
        count = _field(turn * self.counts_per_turn / 360.0, 0, self.counts_per_turn)
        body = (
            _field(motor.temperature_c, -128, 127).to_bytes(1, "little", signed=True)
            + iq.to_bytes(2, "little", signed=True)
            + _field(motor.velocity_dps, -32768, 32767).to_bytes(2, "little", signed=True)
            + (count % self.counts_per_turn).to_bytes(2, "little")
        )
        return self._answer(bytes([command]) + body)

    def _answer(self, payload: bytes) -> can.Message:
        return can.Message(arbitration_id=self.frame_id, is_extended_id=False, data=payload)
