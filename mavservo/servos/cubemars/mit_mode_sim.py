"""A simulated CubeMars AK module in MIT ("power") mode, written from CubeMars' "AK Series
Actuator Driver Manual" V1.0.8 section 5.3 (sources: ``docs/profiles.md``), not from the
``cubemars-ak-mit`` profile: it imports nothing of it.

What the driver does, as the manual states it (standard id = the driver id):

* it powers up out of motor control mode: MIT commands are ignored and not answered until
  ``FF x7 FC`` (enter motor control mode, answered with the state); ``FD`` exits (torque off),
  ``FE`` makes the present position zero and mutes the driver for about a second;
* in motor mode every command is answered on the master id (``0x00``) with ``[driver id,
  position 16, speed 12, current 12]`` (DLC 6, the manual's reply table) or, on drivers that
  add them (the servo's ``reply_bytes`` option), temperature and error code after it (DLC 8);
* with a CAN timeout set in R-Link (``comm_timeout_ms``) a driver that hears nothing for that
  long stops driving the motor but stays in motor mode.
"""

from __future__ import annotations

import math

import can

from ..base import Fault, ProfileOptions, SimMotor
from ..mit_sim import SPECIAL, command_setpoints, configured_ranges, feedback_body

_ENTER, _EXIT, _ZERO = 0xFC, 0xFD, 0xFE
_MUTE_AFTER_ZERO_S = 1.0
_ERROR_CODE = (
    (Fault.OVER_TEMPERATURE, 1),
    (Fault.OVER_CURRENT, 2),
    (Fault.OVER_VOLTAGE, 3),
    (Fault.LOW_VOLTAGE, 4),
    (Fault.ENCODER, 5),
    (Fault.PHASE_IMBALANCE, 6),
)


class AkMitModeDevice:
    """One AK driver in MIT mode on a :class:`SimMotor` (module docstring)."""

    pushes = False

    def __init__(self, motor: SimMotor, can_id: int, options: ProfileOptions) -> None:
        setup = options.model_dump()
        self.motor = motor
        self.can_id = can_id
        self.master_id = int(setup.get("master_id", 0))
        self.ranges = configured_ranges(setup, v_max=50.0, t_max=18.0)
        self.nm_per_amp = float(setup.get("torque_constant_nm_per_a", 0.819))
        self.timeout_s = int(setup.get("comm_timeout_ms", 0)) / 1000
        self.long_reply = int(setup.get("reply_bytes", 8)) == 8
        self.motor_mode = False
        self.muted_until = -math.inf
        self.heard_at: float | None = None
        motor.enabled = False  # out of motor mode at power-up

    def accepts(self, msg: can.Message) -> bool:
        return (
            not msg.is_extended_id
            and not msg.is_remote_frame
            and msg.arbitration_id == self.can_id
            and len(msg.data) == 8
        )

    def handle(self, msg: can.Message, now: float) -> list[can.Message]:
        self.tick(now)
        self.heard_at = now
        data = bytes(msg.data)
        if data[:7] == SPECIAL:
            if data[7] == _ENTER:
                self.motor_mode = True
                self.motor.enable(now)
            elif data[7] == _EXIT:
                self.motor_mode = False
                self.motor.disable(now)
            elif data[7] == _ZERO:
                self.motor.set_zero(now)
                self.muted_until = now + _MUTE_AFTER_ZERO_S
        elif self.motor_mode:
            if not self.motor.enabled:  # after its own timeout: a command drives it again
                self.motor.enable(now)
            position_rad = command_setpoints(data, self.ranges)[0]
            self.motor.command_position(math.degrees(position_rad), None, now)
        else:
            return []
        return [] if now < self.muted_until else [self.reply()]

    def status(self, now: float) -> list[can.Message]:
        return []

    def tick(self, now: float) -> None:
        quiet = self.heard_at is not None and now - self.heard_at > self.timeout_s
        if self.timeout_s > 0 and quiet and self.motor.enabled:
            self.motor.disable(now)

    def reply(self) -> can.Message:
        motor = self.motor
        body = feedback_body(
            self.can_id,
            math.radians(motor.position_deg),
            math.radians(motor.velocity_dps),
            motor.measured_current_a() * self.nm_per_amp,
            self.ranges,
        )
        if self.long_reply:
            temperature = max(-128, min(127, round(motor.temperature_c))) & 0xFF
            error = next((code for fault, code in _ERROR_CODE if fault in motor.active_faults), 0)
            body += bytes([temperature, error])
        return can.Message(arbitration_id=self.master_id, is_extended_id=False, data=body)
