"""CubeMars AK series in "servo mode".

Wire facts (extended 29-bit IDs, big-endian):

* command ID ``(mode << 8) | id``; mode 4 = position, ``int32 deg * 10000`` (4 bytes);
  mode 6 = position + speed: ``int32 deg * 10000, int16 ERPM / 10, int16 ERPM/s / 10``;
* the servo pushes status on ``0x2900 | id`` at its configured rate (no polling):
  ``position i16 0.1 deg, speed i16 10 ERPM, current i16 0.01 A, temperature i8, error u8``,
  error codes 1 over-temperature, 2 over-current, 3 over-voltage, 4 under-voltage, 5 encoder,
  6 phase imbalance.

Speeds travel as electrical RPM. ``erpm_per_dps`` converts (``pole_pairs / 6`` for a speed in
the same shaft frame as the position; the default is the AK80-9's 21 pole pairs).

Range policy: angles outside the documented +-36000 deg raise ``ValueError``; speed limits
saturate at what the int16 field can carry; a position command without a speed limit uses
mode 4 (the servo's own configured speed).
"""

from __future__ import annotations

import struct

import can

from .base import NO_FAULT, Fault, ServoProfile, ServoState

MODE_POSITION = 4
MODE_POSITION_SPEED = 6
STATUS_BASE = 0x2900

ERROR_CODES: dict[int, Fault] = {
    1: Fault.OVER_TEMPERATURE,
    2: Fault.OVER_CURRENT,
    3: Fault.OVER_VOLTAGE,
    4: Fault.LOW_VOLTAGE,
    5: Fault.ENCODER,
    6: Fault.PHASE_IMBALANCE,
}

DEFAULT_POLE_PAIRS = 21


def fault_from_error_code(code: int) -> Fault:
    """The status frame carries one error code (not bits); unknown codes are ``OTHER``."""
    if code == 0:
        return NO_FAULT
    return ERROR_CODES.get(code, Fault.OTHER)


def error_code_from_faults(faults: Fault) -> int:
    """The single code a servo reports for a fault set: the first documented one present."""
    for code, fault in ERROR_CODES.items():
        if fault in faults:
            return code
    return 0


def command_id(mode: int, can_id: int) -> int:
    return (mode << 8) | can_id


class CubeMarsAK(ServoProfile):
    """CubeMars AK servo mode: push-style status, so ``telemetry_requests()`` is empty."""

    name = "cubemars-ak"
    resolution_deg = 0.1
    replies_per_command = 1
    """The real servo only pushes at its rate; the simulator also answers each command, and
    counting that frame keeps the bus-load budget on the safe side."""
    replies_per_request = 0
    min_id, max_id = 0, 255
    min_angle_deg, max_angle_deg = -36000.0, 36000.0

    def __init__(
        self,
        can_id: int,
        *,
        erpm_per_dps: float = DEFAULT_POLE_PAIRS / 6,
        accel_dps2: float = 3600.0,
    ) -> None:
        super().__init__(can_id)
        self.erpm_per_dps = erpm_per_dps
        self.accel_dps2 = accel_dps2
        self.max_speed_dps = 32767 * 10 / erpm_per_dps

    @property
    def status_id(self) -> int:
        return STATUS_BASE | self.can_id

    def position_command(self, angle_deg: float, max_speed_dps: float | None = None) -> can.Message:
        self._check_angle(angle_deg)
        position = round(angle_deg * 10_000)
        if max_speed_dps is None:
            return can.Message(
                arbitration_id=command_id(MODE_POSITION, self.can_id),
                is_extended_id=True,
                data=struct.pack(">i", position),
            )
        speed = self._speed_limit(max_speed_dps, max_speed_dps)
        accel = min(self.accel_dps2, self.max_speed_dps)
        return can.Message(
            arbitration_id=command_id(MODE_POSITION_SPEED, self.can_id),
            is_extended_id=True,
            data=struct.pack(
                ">ihh",
                position,
                self._erpm_field(speed),
                self._erpm_field(accel),
            ),
        )

    def _erpm_field(self, dps: float) -> int:
        """A speed or acceleration in units of 10 ERPM, saturated, and never rounded down to
        0 when it was not 0 (the servo would read 0 as "no limit")."""
        field = min(32767, round(dps * self.erpm_per_dps / 10))
        return max(1, field) if dps > 0 else 0

    def telemetry_requests(self) -> list[can.Message]:
        return []

    def is_reply(self, msg: can.Message) -> bool:
        return (
            msg.is_extended_id
            and not msg.is_remote_frame
            and msg.arbitration_id == self.status_id
            and len(msg.data) == 8
        )

    def decode(self, msg: can.Message, timestamp: float) -> ServoState | None:
        if not self.is_reply(msg):
            return None
        position, speed, current, temperature, error = struct.unpack(">hhhbB", bytes(msg.data))
        return self._merge(
            timestamp,
            position_deg=position / 10,
            velocity_dps=speed * 10 / self.erpm_per_dps,
            current_a=current / 100,
            temperature_c=float(temperature),
            faults=fault_from_error_code(error),
        )
