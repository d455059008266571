"""A simulated Robstride RS00..RS06 motor, written from Robstride's user manuals (RS00..RS06 "User
Manual 260428": chapter 4 private protocol, chapter 6 MIT protocol) and RobStride's sample
program for the MIT fault report (sources: ``docs/profiles.md``), not from the ``robstride``
profile: it imports nothing of it.

What the motor does, as those sources state it:

* it powers up in reset mode (torque off), active reporting off, run mode 0 (operation
  control), no CAN timeout; it answers only its protocol's frames addressed to it;
* private protocol (extended ids ``type << 24 | data << 8 | target``): 3 enable (run mode),
  4 stop (``data[0] = 1`` also clears faults), 6 set zero (``data[0] = 1``), 0x12 parameter
  write ``[index u16 LE, 0, 0, value LE]`` (run_mode 0x7005, loc_ref 0x7016 float rad,
  limit_spd 0x7017 float rad/s, EPScan_time 0x7026: 1 = 10 ms, +5 ms per count, canTimeout
  0x7028: 20000 = 1 s), 0x18 active reporting (``data[6]`` 1 on); each answered with a
  feedback frame (type 2; a report is type 0x18): id ``type << 24 | mode << 22 | fault bits
  << 16 | motor id << 8 | host id`` (mode 0 reset, 2 run; fault bits 16 under-voltage,
  17 over-current, 18 over-temperature, 19 encoder, 20 overload, 21 uncalibrated), data
  angle u16 over +-4 pi rad, velocity and torque u16 over the model's ranges, temperature u16
  x 10, big-endian; it moves in run mode, position mode (CSP, run_mode 5) on loc_ref writes at
  limit_spd;
* MIT protocol (standard ids): ``FF x7 FC`` enable, ``FD`` stop, ``FE`` zero, ``FF x7 FB``
  clear faults, ``FF x6 01 F9`` active reporting on, MIT commands on the motor id, parameter
  writes on ``0x400 | id`` (echoed); it answers on the host id ``[id, position 16, velocity
  12, torque 12, temperature u16 x 10]`` over the model's MIT ranges, or, while faulted, a
  fault report ``[id, fault word u16 LE, 0 x5]`` (bit 0 over-temperature, 1 driver,
  2 under-voltage, 3 encoder, 7 uncalibrated, 14 overload);
* a fault stops it (reset mode) and shows until a stop with the clear flag (private) or a
  clear-faults frame (MIT) once the condition is gone; its CAN timeout stops it with reports
  going on.
"""

from __future__ import annotations

import math
import struct

import can

from ..base import Fault, ProfileOptions, SimMotor
from ..mit_sim import SPECIAL, DriveRanges, command_setpoints, feedback_body

_FEEDBACK, _ENABLE, _STOP, _ZERO, _WRITE, _REPORT = 0x02, 0x03, 0x04, 0x06, 0x12, 0x18
_RUN_MODE, _LOC_REF, _LIMIT_SPD, _EPSCAN, _CAN_TIMEOUT = 0x7005, 0x7016, 0x7017, 0x7026, 0x7028
_CSP = 5
_RESET, _RUN = 0, 2
_MIT_PARAMS = 0x400
_MIT_ENABLE, _MIT_STOP, _MIT_ZERO, _MIT_CLEAR = 0xFC, 0xFD, 0xFE, 0xFB
_MIT_REPORT_ON = b"\xff" * 6 + b"\x01\xf9"
_ANGLE_RANGE = 4 * math.pi

_MODELS = {  # V_MAX rad/s, T_MAX N m, KP_MAX, KD_MAX, torque constant N m/Arms
    "RS00": (33.0, 14.0, 500.0, 5.0, 1.48),
    "RS01": (44.0, 17.0, 500.0, 5.0, 1.22),
    "RS02": (44.0, 17.0, 500.0, 5.0, 1.22),
    "RS03": (20.0, 60.0, 5000.0, 100.0, 2.36),
    "RS04": (15.0, 120.0, 5000.0, 100.0, 2.1),
    "RS05": (50.0, 5.5, 500.0, 5.0, 0.94),
    "RS06": (50.0, 36.0, 5000.0, 100.0, 1.09),
}
"""The manuals' per-model ranges (example code V_MAX, T_MAX, KP_MAX, KD_MAX) and torque
constants (specification tables)."""
_MIT_P_MAX = 12.57
"""P_MAX of every model's MIT chapter."""

_ID_FAULT_BIT = (
    (Fault.LOW_VOLTAGE, 16),
    (Fault.OVER_CURRENT, 17),
    (Fault.OVER_TEMPERATURE, 18),
    (Fault.ENCODER, 19),
    (Fault.STALL, 20),
    (Fault.UNCALIBRATED, 21),
)
_MIT_FAULT_BIT = (
    (Fault.OVER_TEMPERATURE, 0),
    (Fault.DRIVER, 1),
    (Fault.LOW_VOLTAGE, 2),
    (Fault.ENCODER, 3),
    (Fault.UNCALIBRATED, 7),
    (Fault.STALL, 14),
)


def _u16(value: float, limit: float) -> int:
    """A reading on a u16 over ``-limit..limit`` (saturated, nearest count)."""
    value = 0.0 if value != value else min(limit, max(-limit, value))
    return min(0xFFFF, int((value + limit) * 0xFFFF / (2 * limit) + 0.5))


class RsMotorDevice:
    """One Robstride motor on a :class:`SimMotor` (module docstring)."""

    pushes = True

    def __init__(self, motor: SimMotor, can_id: int, options: ProfileOptions) -> None:
        setup = options.model_dump()
        self.motor = motor
        self.can_id = can_id
        self.host_id = int(setup.get("host_id", 0xFD))
        self.private = setup.get("protocol", "private") == "private"
        v_max, t_max, kp_max, kd_max, nm_per_amp = _MODELS[str(setup.get("model", "RS01"))]
        self.v_max, self.t_max, self.nm_per_amp = v_max, t_max, nm_per_amp
        p_max = setup.get("mit_position_max_rad") or _MIT_P_MAX
        self.mit_ranges = DriveRanges(float(p_max), v_max, t_max, kp_max, kd_max)
        self.params: dict[int, float] = {_RUN_MODE: 0, _EPSCAN: 1, _CAN_TIMEOUT: 0, _LIMIT_SPD: 2.0}
        self.reporting = False
        self.reported_at: float | None = None
        self.heard_at: float | None = None
        self.latched = Fault(0)
        motor.enabled = False  # reset mode at power-up

    # -- what it hears ---------------------------------------------------------------------

    def accepts(self, msg: can.Message) -> bool:
        if msg.is_remote_frame or len(msg.data) != 8:
            return False
        if self.private:
            comm_type = msg.arbitration_id >> 24 & 0x1F
            return (
                msg.is_extended_id
                and msg.arbitration_id & 0xFF == self.can_id
                and comm_type in (_ENABLE, _STOP, _ZERO, _WRITE, _REPORT)
            )
        return not msg.is_extended_id and msg.arbitration_id in (
            self.can_id,
            _MIT_PARAMS | self.can_id,
        )

    def handle(self, msg: can.Message, now: float) -> list[can.Message]:
        self.tick(now)
        self.heard_at = now
        data = bytes(msg.data)
        if not self.private:
            return self._mit(msg.arbitration_id, data, now)
        comm_type = msg.arbitration_id >> 24 & 0x1F
        if comm_type == _ENABLE:
            if not self.latched and not self.motor.active_faults:
                self.motor.enable(now)
        elif comm_type == _STOP:
            self.motor.disable(now)
            if data[0] == 1:
                self.latched = Fault(0)
        elif comm_type == _ZERO and data[0] == 1:
            self.motor.set_zero(now)
        elif comm_type == _WRITE:
            self._write(data, now)
        elif comm_type == _REPORT:
            self.reporting = data[6] == 1
            return [self.feedback(_REPORT)]
        return [self.feedback(_FEEDBACK)]

    def _write(self, data: bytes, now: float) -> None:
        index = int.from_bytes(data[0:2], "little")
        if index == _RUN_MODE:
            if not self.motor.enabled:  # modes change only while stopped
                self.params[index] = data[4]
        elif index == _EPSCAN:
            self.params[index] = int.from_bytes(data[4:6], "little")
        elif index == _CAN_TIMEOUT:
            self.params[index] = int.from_bytes(data[4:8], "little")
        elif index in (_LOC_REF, _LIMIT_SPD):
            (value,) = struct.unpack("<f", data[4:8])
            if not math.isfinite(value):
                return
            self.params[index] = value
            if index == _LOC_REF and self.params[_RUN_MODE] == _CSP and self._driving():
                speed = math.degrees(abs(self.params[_LIMIT_SPD]))
                self.motor.command_position(math.degrees(value), max(speed, 1e-3), now)

    def _mit(self, arbitration_id: int, data: bytes, now: float) -> list[can.Message]:
        if arbitration_id != self.can_id:  # a parameter write: applied and echoed
            index = int.from_bytes(data[0:2], "little")
            if index == _EPSCAN:
                self.params[index] = int.from_bytes(data[4:6], "little")
            elif index == _CAN_TIMEOUT:
                self.params[index] = int.from_bytes(data[4:8], "little")
            return [can.Message(arbitration_id=arbitration_id, is_extended_id=False, data=data)]
        if data[:7] == SPECIAL and data[7] == _MIT_ENABLE:
            if not self.latched and not self.motor.active_faults:
                self.motor.enable(now)
        elif data[:7] == SPECIAL and data[7] == _MIT_STOP:
            self.motor.disable(now)
        elif data[:7] == SPECIAL and data[7] == _MIT_ZERO:
            self.motor.set_zero(now)
        elif data[:7] == SPECIAL and data[7] == _MIT_CLEAR:
            self.latched = Fault(0)
        elif data == _MIT_REPORT_ON:
            self.reporting = True
        elif data[:6] == b"\xff" * 6:
            pass  # other special frames (modes, ids, protocol): not simulated
        elif self._driving():
            position_rad = command_setpoints(data, self.mit_ranges)[0]
            self.motor.command_position(math.degrees(position_rad), None, now)
        return [self.feedback(_FEEDBACK)]

    def _driving(self) -> bool:
        return self.motor.enabled and not self.motor.active_faults

    # -- its own timers and reports --------------------------------------------------------

    def tick(self, now: float) -> None:
        faults = self.motor.active_faults
        if faults:
            self.latched |= faults
            if self.motor.enabled:
                self.motor.disable(now)
        timeout_s = self.params[_CAN_TIMEOUT] / 20 / 1000
        quiet = self.heard_at is not None and now - self.heard_at > timeout_s
        if self.motor.enabled and timeout_s > 0 and quiet:
            self.motor.disable(now)

    def status(self, now: float) -> list[can.Message]:
        self.tick(now)
        if not self.reporting:
            return []
        period_s = (10 + 5 * (max(1, int(self.params[_EPSCAN])) - 1)) / 1000
        if self.reported_at is not None and now - self.reported_at < period_s * 0.999:
            return []
        self.reported_at = now
        return [self.feedback(_REPORT)]

    def feedback(self, comm_type: int) -> can.Message:
        motor = self.motor
        torque = motor.measured_current_a() * self.nm_per_amp
        temperature = max(0, min(0xFFFF, round(motor.temperature_c * 10)))
        faults = self.latched | motor.active_faults
        if not self.private:
            if faults:
                word = sum(1 << bit for fault, bit in _MIT_FAULT_BIT if fault in faults)
                data = bytes([self.can_id]) + word.to_bytes(2, "little") + bytes(5)
            else:
                data = feedback_body(
                    self.can_id,
                    math.radians(motor.position_deg),
                    math.radians(motor.velocity_dps),
                    torque,
                    self.mit_ranges,
                ) + temperature.to_bytes(2, "big")
            return can.Message(arbitration_id=self.host_id, is_extended_id=False, data=data)
        mode = _RUN if motor.enabled else _RESET
        bits = sum(1 << bit for fault, bit in _ID_FAULT_BIT if fault in faults)
        arbitration_id = comm_type << 24 | mode << 22 | bits | self.can_id << 8 | self.host_id
        data = (
            _u16(math.radians(motor.position_deg), _ANGLE_RANGE).to_bytes(2, "big")
            + _u16(math.radians(motor.velocity_dps), self.v_max).to_bytes(2, "big")
            + _u16(torque, self.t_max).to_bytes(2, "big")
            + temperature.to_bytes(2, "big")
        )
        return can.Message(arbitration_id=arbitration_id, is_extended_id=True, data=data)
