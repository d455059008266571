"""A simulated ODrive axis (firmware 0.6, CANSimple), written from ODrive's CAN protocol
documentation and its published DBC (``odrive-cansimple-0.6.10.dbc``; sources:
``docs/profiles.md``), not from the ``odrive`` profile: it imports nothing of it.

What the axis does, as the documentation states it (ids ``node_id << 5 | command``, LE):

* it powers up IDLE (motor off) and moves only in CLOSED_LOOP_CONTROL (Set_Axis_State 0x07,
  state 8) with position control selected (Set_Controller_Mode 0x0B, control mode 3), at its
  velocity limit (input modes passthrough 1, pos-filter 3) or along a trapezoidal trajectory
  (trap-traj 5, Set_Traj_Vel_Limit 0x11, Set_Traj_Accel_Limits 0x12); Set_Input_Pos 0x0C
  carries float32 motor turns; Set_Limits 0x0F the velocity limit; Clear_Errors 0x18;
  RxSdo 0x04 writes (opcode 1) the watchdog endpoints the servo's options name;
* it answers nothing; it pushes Get_Encoder_Estimates 0x09 (float32 turns, turn/s), a
  Heartbeat 0x01 (axis error u32, axis state u8, procedure result u8, trajectory done u8) every
  ``heartbeat_ms`` and, when ``aux_rate_ms`` is set, Get_Iq 0x14, Get_Temperature 0x15 and
  Get_Bus_Voltage_Current 0x17;
* an error disarms it (IDLE, the error in the heartbeat, procedure result DISARMED when
  closed loop is refused); so does the watchdog (WATCHDOG_TIMER_EXPIRED) when no frame came
  for its timeout, until closed loop is requested again.
"""

from __future__ import annotations

import math
import struct

import can

from ..base import Fault, ProfileOptions, SimMotor

_HEARTBEAT, _RX_SDO, _SET_AXIS_STATE, _ENCODER_ESTIMATES = 0x01, 0x04, 0x07, 0x09
_SET_CONTROLLER_MODE, _SET_INPUT_POS, _SET_LIMITS = 0x0B, 0x0C, 0x0F
_SET_TRAJ_VEL_LIMIT, _SET_TRAJ_ACCEL_LIMITS = 0x11, 0x12
_GET_ERROR, _GET_IQ, _GET_TEMPERATURE, _GET_BUS = 0x03, 0x14, 0x15, 0x17
_CLEAR_ERRORS = 0x18
_CYCLIC = {_HEARTBEAT, _GET_ERROR, _ENCODER_ESTIMATES, _GET_IQ, _GET_TEMPERATURE, _GET_BUS}

_IDLE, _CLOSED_LOOP = 1, 8
_POSITION_CONTROL = 3
_PASSTHROUGH, _TRAP_TRAJ = 1, 5
_SUCCESS, _DISARMED = 0, 3

_CURRENT_LIMIT_VIOLATION = 0x1000
_MOTOR_OVER_TEMP = 0x2000
_DC_BUS_UNDER_VOLTAGE = 0x200
_WATCHDOG_TIMER_EXPIRED = 0x1000000
_ERROR_OF = (
    (Fault.OVER_CURRENT, _CURRENT_LIMIT_VIOLATION),
    (Fault.OVER_TEMPERATURE, _MOTOR_OVER_TEMP),
    (Fault.LOW_VOLTAGE, _DC_BUS_UNDER_VOLTAGE),
)
"""ODrive.Error bits the simulated motor's conditions raise."""


class OdriveAxisDevice:
    """One ODrive axis on a :class:`SimMotor` (module docstring)."""

    pushes = True

    def __init__(self, motor: SimMotor, can_id: int, options: ProfileOptions) -> None:
        setup = options.model_dump()
        self.motor = motor
        self.node_id = can_id
        self.turns_per_rev = float(setup.get("motor_turns_per_rev", 1.0))
        self.heartbeat_s = int(setup.get("heartbeat_ms", 100)) / 1000
        self.aux_s = int(setup.get("aux_rate_ms", 0)) / 1000
        self.watchdog_endpoints = (
            setup.get("watchdog_timeout_endpoint"),
            setup.get("enable_watchdog_endpoint"),
        )
        self.state = _IDLE
        self.control_mode = _POSITION_CONTROL
        self.input_mode = _PASSTHROUGH
        self.velocity_limit = float(setup.get("velocity_limit_turns_s", 2.0))
        self.traj_velocity = self.velocity_limit
        self.traj_accel = float(setup.get("traj_accel_turns_s2", 1.0))
        self.disarm_reason = 0
        self.procedure_result = _SUCCESS
        self.watchdog_s = float(setup.get("watchdog_timeout_s", 0.0))
        self.watchdog_on = self.watchdog_s > 0
        self.fed_at: float | None = None
        self.next_heartbeat: float | None = None
        self.next_aux: float | None = None
        self.trajectory_done = True
        motor.enabled = False  # IDLE at power-up

    def _degrees(self, turns: float) -> float:
        return turns * 360.0 / self.turns_per_rev

    def _turns(self, degrees: float) -> float:
        return degrees * self.turns_per_rev / 360.0

    def _errors(self) -> int:
        return sum(bit for fault, bit in _ERROR_OF if fault in self.motor.active_faults)

    def accepts(self, msg: can.Message) -> bool:
        return (
            not msg.is_extended_id
            and not msg.is_remote_frame
            and msg.arbitration_id >> 5 == self.node_id
            and msg.arbitration_id & 0x1F not in _CYCLIC
        )

    def handle(self, msg: can.Message, now: float) -> list[can.Message]:
        self.tick(now)
        self.fed_at = now  # any frame to the node feeds the watchdog
        data = bytes(msg.data)
        command = msg.arbitration_id & 0x1F
        if command == _SET_AXIS_STATE and len(data) >= 4:
            self._request(int.from_bytes(data[0:4], "little"), now)
        elif command == _SET_INPUT_POS and len(data) >= 8:
            self._move(struct.unpack_from("<f", data)[0], now)
        elif command == _SET_CONTROLLER_MODE and len(data) >= 8:
            self.control_mode = int.from_bytes(data[0:4], "little")
            self.input_mode = int.from_bytes(data[4:8], "little")
        elif command == _SET_LIMITS and len(data) >= 8:
            self.velocity_limit = _positive(data, self.velocity_limit)
        elif command == _SET_TRAJ_VEL_LIMIT and len(data) >= 4:
            self.traj_velocity = _positive(data, self.traj_velocity)
        elif command == _SET_TRAJ_ACCEL_LIMITS and len(data) >= 8:
            self.traj_accel = _positive(data, self.traj_accel)
        elif command == _CLEAR_ERRORS:
            self.disarm_reason = 0
            self.procedure_result = _SUCCESS
        elif command == _RX_SDO and len(data) >= 8 and data[0] == 1:
            self._write(int.from_bytes(data[1:3], "little"), data[4:8])
        return []

    def _write(self, endpoint: int, value: bytes) -> None:
        timeout_endpoint, enable_endpoint = self.watchdog_endpoints
        if endpoint == timeout_endpoint:
            (timeout,) = struct.unpack("<f", value)
            if math.isfinite(timeout) and timeout >= 0:
                self.watchdog_s = timeout
        elif endpoint == enable_endpoint:
            self.watchdog_on = value[0] != 0

    def _request(self, state: int, now: float) -> None:
        if state == _IDLE:
            self._disarm(0, now)
        elif state == _CLOSED_LOOP:
            errors = self._errors()
            if errors:
                self.disarm_reason |= errors
                self.procedure_result = _DISARMED
                return
            self.disarm_reason = 0
            self.procedure_result = _SUCCESS
            self.state = _CLOSED_LOOP
            self.motor.enable(now)

    def _move(self, turns: float, now: float) -> None:
        armed = self.state == _CLOSED_LOOP and self.control_mode == _POSITION_CONTROL
        if not armed or not math.isfinite(turns):
            return
        if self.input_mode == _TRAP_TRAJ:
            speed = self._degrees(min(self.traj_velocity, self.velocity_limit))
            accel = self._degrees(self.traj_accel)
            self.motor.command_position(self._degrees(turns), speed, now, accel)
        else:
            self.motor.command_position(
                self._degrees(turns), self._degrees(self.velocity_limit), now
            )
        self.trajectory_done = False

    def _disarm(self, reason: int, now: float) -> None:
        self.disarm_reason |= reason
        self.state = _IDLE
        self.motor.disable(now)

    def tick(self, now: float) -> None:
        if self.state != _CLOSED_LOOP:
            return
        errors = self._errors()
        if errors:
            self._disarm(errors, now)
            return
        if self.watchdog_on and self.watchdog_s > 0 and self.fed_at is not None:
            expiry = self.fed_at + self.watchdog_s
            if now > expiry:
                self._disarm(_WATCHDOG_TIMER_EXPIRED, expiry)

    def status(self, now: float) -> list[can.Message]:
        self.tick(now)
        motor = self.motor
        frames = [
            self._push(
                _ENCODER_ESTIMATES,
                struct.pack(
                    "<ff", self._turns(motor.position_deg), self._turns(motor.velocity_dps)
                ),
            )
        ]
        if self.next_heartbeat is None or now >= self.next_heartbeat - 1e-9:
            self.next_heartbeat = now + self.heartbeat_s
            frames.append(self._push(_HEARTBEAT, self.heartbeat()))
        if self.aux_s and (self.next_aux is None or now >= self.next_aux - 1e-9):
            self.next_aux = now + self.aux_s
            temperature = motor.temperature_c
            frames += [
                self._push(_GET_IQ, struct.pack("<ff", 0.0, motor.measured_current_a())),
                self._push(_GET_TEMPERATURE, struct.pack("<ff", temperature, temperature)),
                self._push(_GET_BUS, struct.pack("<ff", motor.voltage_v, 0.0)),
            ]
        return frames

    def heartbeat(self) -> bytes:
        if self.state == _CLOSED_LOOP and abs(self.motor.velocity_dps) < 1e-3:
            self.trajectory_done = True
        error = self._errors() | self.disarm_reason
        return error.to_bytes(4, "little") + bytes(
            [self.state, self.procedure_result, int(self.trajectory_done), 0]
        )

    def _push(self, command: int, data: bytes) -> can.Message:
        return can.Message(
            arbitration_id=self.node_id << 5 | command, is_extended_id=False, data=data
        )


def _positive(data: bytes, old: float) -> float:
    (value,) = struct.unpack_from("<f", data)
    return value if math.isfinite(value) and value > 0 else old
