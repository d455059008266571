"""A simulated Damiao DM-J motor (DM-J4310-2EC and siblings), written from Damiao's DM-J4310-2EC
manual V1.0 and Damiao's example drivers (sources: ``docs/profiles.md``), not from the
``damiao-dm`` profile: it imports nothing of it.

What the motor does, as those sources state it (standard ids, 8 data bytes):

* it powers up disabled, in MIT mode, with no communication timeout; ``FF x7 FC`` enables it,
  ``FD`` disables it, ``FE`` sets the zero, ``FB`` clears a latched error;
* MIT commands on its id, position-velocity commands (float32 rad, float32 rad/s, LE) on
  ``0x100 + id``: it moves only while enabled and only on the commands of its CTRL_MODE;
* registers on ``0x7FF``: ``[id lo, id hi, op, RID, value u32 LE]``, op 0x33 read, 0x55 write
  (echoed with the value), 0xCC asks for a feedback frame; RID 9 TIMEOUT (units of 50 us),
  RID 10 CTRL_MODE (1 MIT, 2 position-velocity);
* it answers every frame on the master id with ``[ERR << 4 | id & 0xF, position 16, velocity
  12, torque 12, T_MOS, T_Rotor]``; ERR 0 disabled, 1 enabled, 8 over-voltage, 9 under-voltage,
  A over-current, B MOSFET over-temperature, C rotor over-temperature, D communication lost,
  E overload. A fault disables it; silent for TIMEOUT it disables itself and reports D until
  FB, refusing to enable before.
"""

from __future__ import annotations

import math
import struct

import can

from ..base import Fault, ProfileOptions, SimMotor
from ..mit_sim import SPECIAL, command_setpoints, configured_ranges, feedback_body

_REGISTERS_ID = 0x7FF
_POSITION_VELOCITY = 0x100
_READ, _WRITE, _REFRESH = 0x33, 0x55, 0xCC
_TIMEOUT, _CTRL_MODE = 9, 10
_MIT, _POSITION_VELOCITY_MODE = 1, 2
_ENABLE, _DISABLE, _ZERO, _CLEAR = 0xFC, 0xFD, 0xFE, 0xFB
_DISABLED, _ENABLED, _COMM_LOST = 0x0, 0x1, 0xD
_ERR_CODE = (
    (Fault.OVER_VOLTAGE, 0x8),
    (Fault.LOW_VOLTAGE, 0x9),
    (Fault.OVER_CURRENT, 0xA),
    (Fault.OVER_TEMPERATURE, 0xB),
    (Fault.COMMUNICATION_LOST, 0xD),
)


class DmJMotorDevice:
    """One DM-J motor on a :class:`SimMotor` (module docstring)."""

    pushes = False

    def __init__(self, motor: SimMotor, can_id: int, options: ProfileOptions) -> None:
        setup = options.model_dump()
        self.motor = motor
        self.can_id = can_id
        self.master_id = int(setup.get("master_id", 0))
        self.ranges = configured_ranges(setup, v_max=30.0, t_max=10.0)
        self.nm_per_amp = float(setup.get("torque_constant_nm_per_a", 0.945))
        self.registers = {_CTRL_MODE: _MIT, _TIMEOUT: 0}
        self.communication_lost = False
        self.heard_at: float | None = None
        motor.enabled = False  # powers up disabled

    def accepts(self, msg: can.Message) -> bool:
        if msg.is_extended_id or msg.is_remote_frame or len(msg.data) != 8:
            return False
        if msg.arbitration_id == _REGISTERS_ID:
            return msg.data[0] | msg.data[1] << 8 == self.can_id
        return msg.arbitration_id in (self.can_id, _POSITION_VELOCITY + self.can_id)

    def handle(self, msg: can.Message, now: float) -> list[can.Message]:
        self.tick(now)
        self.heard_at = now
        data = bytes(msg.data)
        if msg.arbitration_id == _REGISTERS_ID:
            operation, rid = data[2], data[3]
            if operation == _REFRESH:
                return [self.feedback()]
            if operation == _WRITE:
                self.registers[rid] = int.from_bytes(data[4:8], "little")
            value = self.registers.get(rid, 0).to_bytes(4, "little")
            return [self._answer(data[:4] + value)]
        if data[:7] == SPECIAL and msg.arbitration_id == self.can_id:
            self._special(data[7], now)
        elif self.motor.enabled and not self.motor.active_faults:
            self._move(msg.arbitration_id, data, now)
        return [self.feedback()]

    def _special(self, code: int, now: float) -> None:
        if code == _ENABLE and not self.communication_lost and not self.motor.active_faults:
            self.motor.enable(now)
        elif code == _DISABLE:
            self.motor.disable(now)
        elif code == _ZERO:
            self.motor.set_zero(now)
        elif code == _CLEAR:
            self.communication_lost = False

    def _move(self, arbitration_id: int, data: bytes, now: float) -> None:
        mode = self.registers.get(_CTRL_MODE)
        if arbitration_id == self.can_id and mode == _MIT:
            position_rad = command_setpoints(data, self.ranges)[0]
            self.motor.command_position(math.degrees(position_rad), None, now)
        elif arbitration_id != self.can_id and mode == _POSITION_VELOCITY_MODE:
            position, velocity = struct.unpack("<ff", data)
            if math.isfinite(position) and math.isfinite(velocity) and velocity != 0:
                speed_dps = math.degrees(abs(velocity))
                self.motor.command_position(math.degrees(position), speed_dps, now)

    def status(self, now: float) -> list[can.Message]:
        return []

    def tick(self, now: float) -> None:
        if self.motor.enabled and self.motor.active_faults:
            self.motor.disable(now)
        timeout_s = self.registers.get(_TIMEOUT, 0) * 50e-6
        quiet = self.heard_at is not None and now - self.heard_at > timeout_s
        if self.motor.enabled and timeout_s > 0 and quiet:
            self.motor.disable(now)
            self.communication_lost = True

    def feedback(self) -> can.Message:
        motor = self.motor
        if self.communication_lost:
            err = _COMM_LOST
        else:
            active = motor.active_faults
            codes = [code for fault, code in _ERR_CODE if fault in active]
            err = codes[0] if codes else (_ENABLED if motor.enabled else _DISABLED)
        body = feedback_body(
            err << 4 | self.can_id & 0x0F,
            math.radians(motor.position_deg),
            math.radians(motor.velocity_dps),
            motor.measured_current_a() * self.nm_per_amp,
            self.ranges,
        )
        temperature = max(0, min(255, round(motor.temperature_c)))
        return self._answer(body + bytes([temperature, temperature]))

    def _answer(self, data: bytes) -> can.Message:
        return can.Message(arbitration_id=self.master_id, is_extended_id=False, data=data)
