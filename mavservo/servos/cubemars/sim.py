"""A simulated CubeMars AK module in servo mode, written from CubeMars' "AK Series Actuator Driver
Manual" (servo mode chapter; sources: ``docs/profiles.md``), not from the ``cubemars-ak``
profile: it imports nothing of it.

What the driver does, as the manual states it (extended ids ``mode << 8 | id``, big-endian):

* mode 4, position loop: ``int32`` output degrees x 10000 (4 bytes): it moves at its own
  configured speed;
* mode 6, position-speed loop: the same position, then ``int16`` speed and ``int16``
  acceleration in units of 10 ERPM and 10 ERPM/s: electrical RPM of the rotor, so one output
  degree per second is pole pairs x reduction / 6 ERPM;
* it reports on ``0x2900 | id`` at its configured rate: ``int16`` output position x 10,
  ``int16`` rotor speed / 10 ERPM, ``int16`` current x 100, ``int8`` temperature, ``u8`` error
  code (1 over-temperature, 2 over-current, 3 over-voltage, 4 under-voltage, 5 encoder,
  6 phase-current imbalance); this simulation also reports after every command.
"""

from __future__ import annotations

import can

from ..base import Fault, ProfileOptions, SimMotor

_POSITION_LOOP, _POSITION_SPEED_LOOP = 4, 6
_REPORT_BASE = 0x2900

_POLE_PAIRS = {"AK60-6": 14}
"""The modules' motor pole pairs (manual, product parameters): 21 but for the AK60-6's 14."""

_ERROR_CODE = (
    (Fault.OVER_TEMPERATURE, 1),
    (Fault.OVER_CURRENT, 2),
    (Fault.OVER_VOLTAGE, 3),
    (Fault.LOW_VOLTAGE, 4),
    (Fault.ENCODER, 5),
    (Fault.PHASE_IMBALANCE, 6),
)


def _int(value: float, bits: int) -> int:
    """A reading rounded into a signed field of ``bits`` (saturated)."""
    whole = int(value + 0.5) if value >= 0 else -int(-value + 0.5)
    top = (1 << (bits - 1)) - 1
    return min(top, max(-top - 1, whole))


class AkServoModeDevice:
    """One AK module in servo mode on a :class:`SimMotor` (module docstring)."""

    pushes = True

    def __init__(self, motor: SimMotor, can_id: int, options: ProfileOptions) -> None:
        setup = options.model_dump()
        model = str(setup.get("model", "AK80-9"))
        pole_pairs = setup.get("pole_pairs") or _POLE_PAIRS.get(model, 21)
        reduction = setup.get("gear_ratio") or float(model.split("-")[1])  # AK80-9: 9:1
        self.erpm_per_output_dps = pole_pairs * reduction / 6.0
        self.motor = motor
        self.can_id = can_id

    def accepts(self, msg: can.Message) -> bool:
        if (
            not msg.is_extended_id
            or msg.is_remote_frame
            or msg.arbitration_id & 0xFF != self.can_id
        ):
            return False
        mode = msg.arbitration_id >> 8
        return (mode, len(msg.data)) in ((_POSITION_LOOP, 4), (_POSITION_SPEED_LOOP, 8))

    def handle(self, msg: can.Message, now: float) -> list[can.Message]:
        data = bytes(msg.data)
        target = int.from_bytes(data[0:4], "big", signed=True) / 10_000
        if msg.arbitration_id >> 8 == _POSITION_LOOP:
            self.motor.command_position(target, None, now)
        else:
            speed = abs(int.from_bytes(data[4:6], "big", signed=True)) * 10
            accel = abs(int.from_bytes(data[6:8], "big", signed=True)) * 10
            per = self.erpm_per_output_dps
            self.motor.command_position(target, speed / per, now, accel / per)
        return self.status(now)

    def status(self, now: float) -> list[can.Message]:
        motor = self.motor
        error = next((code for fault, code in _ERROR_CODE if fault in motor.active_faults), 0)
        body = _int(motor.position_deg * 10, 16).to_bytes(2, "big", signed=True)
        body += _int(motor.velocity_dps * self.erpm_per_output_dps / 10, 16).to_bytes(
            2, "big", signed=True
        )
        body += _int(motor.measured_current_a() * 100, 16).to_bytes(2, "big", signed=True)
        body += _int(motor.temperature_c, 8).to_bytes(1, "big", signed=True) + bytes([error])
        report_id = _REPORT_BASE | self.can_id
        return [can.Message(arbitration_id=report_id, is_extended_id=True, data=body)]

    def tick(self, now: float) -> None:
        return None
