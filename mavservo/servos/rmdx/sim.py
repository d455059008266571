"""A simulated MyActuator RMD-X servo (protocol V4), written from MyActuator's "Servo Motor
Control Protocol" V4.2 (2024.05; sources: ``docs/profiles.md``), not from the ``rmd-x``
profile: it imports nothing of it.

What the device does, as the document states it (requests on ``0x140 + id``, replies on
``0x240 + id``, 8 data bytes, little-endian):

* ``A4`` (absolute position, speed limit u16 dps, angle i32 0.01 deg) moves the motor, running
  it again after a shutdown; ``9C`` and the ``A4`` reply carry temperature (1 degC), iq
  (0.01 A), speed (1 dps) and the angle in whole degrees (i16);
* ``92`` answers the multi-turn angle, i32 0.01 deg in bytes 4..7; ``9A`` temperature, the
  brake state (byte 3: 1 released, 0 locked), voltage (0.1 V, bytes 4..5) and the error word
  (bytes 6..7);
* ``80`` (motor shutdown) turns the motor off; ``B3`` sets the communication-loss time (ms,
  bytes 4..7): silent that long, the motor turns itself off; both echoed;
* ``B5`` (2.32, motor model reading) answers the model in seven ASCII bytes (1..7), and ``B2``
  (2.29, system software version date read) the date as the decimal YYYYMMDD in bytes 4..7
  (bytes 1..3 zero); the simulated servo gives the document's examples, ``X8S2V10`` and
  20220206; reads, they change nothing;
* a model with a holding brake (the servo's ``brake`` option) starts with the brake locked:
  ``77`` releases it, ``78`` locks it (both echoed); a locked brake holds the output, so a
  position command does not move it.
"""

from __future__ import annotations

import can

from ..base import Fault, ProfileOptions, SimMotor

_REQUEST_BASE, _REPLY_BASE = 0x140, 0x240
_SHUTDOWN, _BRAKE_RELEASE, _BRAKE_LOCK, _COMM_LOSS = 0x80, 0x77, 0x78, 0xB3
_ABSOLUTE_POSITION, _READ_STATUS_2 = 0xA4, 0x9C
_READ_MULTI_TURN, _READ_STATUS_1 = 0x92, 0x9A
_READ_SOFTWARE_DATE, _READ_MODEL = 0xB2, 0xB5

_ERROR_WORD = (
    (Fault.STALL, 0x0002),
    (Fault.LOW_VOLTAGE, 0x0004),
    (Fault.OVER_VOLTAGE, 0x0008),
    (Fault.OVER_CURRENT, 0x0010),
    (Fault.POWER, 0x0040),
    (Fault.OVERSPEED, 0x0100),
    (Fault.OVER_TEMPERATURE, 0x1000),
    (Fault.ENCODER, 0x2000),
)
"""9A error word: 0x0002 stall, 0x0004 low voltage, 0x0008 over-voltage, 0x0010 over-current,
0x0040 power overrun, 0x0100 speeding, 0x1000 over-temperature, 0x2000 encoder calibration."""


def _saturated(value: float, low: int, high: int) -> int:
    whole = int(value + 0.5) if value >= 0 else -int(-value + 0.5)
    return min(high, max(low, whole))


class RmdXV4Device:
    """One RMD-X V4 servo on a :class:`SimMotor` (module docstring)."""

    pushes = False
    model = b"X8S2V10"
    """The model the servo names (V4.2, 2.32.4's example: RMD-X8 S2 V10), 7 ASCII bytes."""
    software_date = 20220206
    """The software version date (V4.2, 2.29.4's example: 6 February 2022)."""

    def __init__(self, motor: SimMotor, can_id: int, options: ProfileOptions) -> None:
        setup = options.model_dump()
        self.motor = motor
        self.request_id = _REQUEST_BASE + can_id
        self.reply_id = _REPLY_BASE + can_id
        self.brake_locked = bool(setup.get("brake", False))
        """A brake model powers up with its brake locked (no brake: never locked)."""
        self.comm_loss_s = 0.0
        self.heard_at: float | None = None

    def accepts(self, msg: can.Message) -> bool:
        return (
            not msg.is_extended_id
            and not msg.is_remote_frame
            and msg.arbitration_id == self.request_id
            and len(msg.data) == 8
        )

    def tick(self, now: float) -> None:
        silent_for = None if self.heard_at is None else now - self.heard_at
        timed_out = silent_for is not None and 0 < self.comm_loss_s < silent_for
        if timed_out and self.motor.enabled:
            self.motor.disable(now)

    def status(self, now: float) -> list[can.Message]:
        return []

    def handle(self, msg: can.Message, now: float) -> list[can.Message]:
        self.tick(now)
        self.heard_at = now
        data = bytes(msg.data)
        command = data[0]
        motor = self.motor
        if command == _ABSOLUTE_POSITION:
            speed = int.from_bytes(data[2:4], "little")
            angle = int.from_bytes(data[4:8], "little", signed=True) / 100
            if not motor.enabled:
                motor.enable(now)
            if self.brake_locked:  # the brake holds the output where it is
                motor.command_position(motor.position_deg, None, now)
            else:
                motor.command_position(angle, float(speed), now)
            return [self._status_2(command)]
        if command == _SHUTDOWN:
            motor.disable(now)
            return [self._reply(data)]
        if command in (_BRAKE_RELEASE, _BRAKE_LOCK):
            self.brake_locked = command == _BRAKE_LOCK
            if self.brake_locked:
                motor.command_position(motor.position_deg, None, now)
            return [self._reply(data)]
        if command == _COMM_LOSS:
            self.comm_loss_s = int.from_bytes(data[4:8], "little") / 1000
            return [self._reply(data)]
        if command == _READ_STATUS_2:
            return [self._status_2(command)]
        if command == _READ_MULTI_TURN:
            angle = _saturated(motor.position_deg * 100, -(2**31), 2**31 - 1)
            return [
                self._reply(bytes([command, 0, 0, 0]) + angle.to_bytes(4, "little", signed=True))
            ]
        if command == _READ_MODEL:
            return [self._reply(bytes([command]) + self.model[:7].ljust(7, b" "))]
        if command == _READ_SOFTWARE_DATE:
            return [
                self._reply(bytes([command, 0, 0, 0]) + self.software_date.to_bytes(4, "little"))
            ]
        if command == _READ_STATUS_1:
            error = sum(bit for fault, bit in _ERROR_WORD if fault in motor.active_faults)
            body = bytes([command])
            body += _saturated(motor.temperature_c, -128, 127).to_bytes(1, "little", signed=True)
            body += bytes([0, 0 if self.brake_locked else 1])
            body += _saturated(motor.voltage_v * 10, 0, 0xFFFF).to_bytes(2, "little")
            body += error.to_bytes(2, "little")
            return [self._reply(body)]
        return []

    def _status_2(self, command: int) -> can.Message:
        motor = self.motor
        body = bytes([command])
        body += _saturated(motor.temperature_c, -128, 127).to_bytes(1, "little", signed=True)
        body += _saturated(motor.measured_current_a() * 100, -32768, 32767).to_bytes(
            2, "little", signed=True
        )
        body += _saturated(motor.velocity_dps, -32768, 32767).to_bytes(2, "little", signed=True)
        body += _saturated(motor.position_deg, -32768, 32767).to_bytes(2, "little", signed=True)
        return self._reply(body)

    def _reply(self, payload: bytes) -> can.Message:
        return can.Message(arbitration_id=self.reply_id, is_extended_id=False, data=payload)
