"""CubeMars AK series in MIT ("power") mode, next to the servo mode of :mod:`.cubemars`.

A separate profile name (``cubemars-ak-mit``) rather than a mode option of ``cubemars-ak``:
the two modes share nothing on the wire (servo mode: extended ids, status pushes at the
motor's rate; MIT mode: standard ids, one answer per frame), so each keeps its own identifiers,
telemetry style and simulated device, and the options of one never mean nothing to the other.

Wire facts: CubeMars "AK Series Actuator Driver Manual" V1.0.8, section 5.3 "MIT power mode
communication protocol":

* commands on the standard id = the motor's id: the MIT packing (:mod:`.mit`) with the
  module's ranges from the manual's table (AK80-9: +-12.5 rad, +-50 rad/s, +-18, kp 0..500,
  kd 0..5; other modules differ, hence options);
* special codes on the same id: ``FF x7 FC`` enter motor control mode (required before any
  command; it also makes the motor answer with its state, which is the poll used here),
  ``FD`` exit (torque off), ``FE`` set the present position as zero;
* the driver answers ``[driver id, position 16, speed 12, current 12]`` (DLC 6, the manual's
  MIT reply table) or with ``temperature, error`` after it (DLC 8, drivers that add them),
  mapped with the same ranges, on identifier ``0x00`` (the manual's "0X00 + Drive ID" table
  header; the master id is an option for drivers configured otherwise), error codes as in
  servo mode: 1 over-temperature, 2 over-current, 3 over-voltage, 4 under-voltage, 5 encoder,
  6 phase-current imbalance.

The 12-bit "current" field is mapped on the torque range (the manual's ``T`` columns); it is
reported as current through ``torque_constant_nm_per_a``.

Range policy: angles outside ``+-p_max_rad`` raise ``ValueError`` before anything is built; MIT
mode takes no speed limit (the gains shape the motion), so ``max_speed_dps`` is validated and
otherwise ignored.
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import can
from pydantic import Field

from .. import mit
from ..base import FrameId, ProfileOptions, ServoProfile, ServoState, SimDevice, SimMotor
from ..sim_registry import simulated_device
from .profile import fault_from_error_code

REPLY_LENGTHS = (6, 8)
"""The manual's MIT reply table gives DLC 6 (position, speed, current); drivers that add the
temperature and error code send 8. Both are this driver's answer."""
ZERO_MUTE_S = 1.0
"""How long the driver stays silent after a set-zero frame (the manual's "about a second")."""


class CubeMarsMitOptions(mit.MitOptions):
    """Per-servo ``options:`` of an AK module in MIT mode. Defaults are an AK80-9's (manual
    5.3 table: +-12.5 rad, +-50 rad/s, +-18; torque constant 0.091 N m/A x 9:1 gear)."""

    v_max_rad_s: float = Field(50.0, gt=0, le=1000, description="velocity range +-rad/s")
    t_max_nm: float = Field(18.0, gt=0, le=1000, description="torque range +-N m")
    torque_constant_nm_per_a: float = Field(
        0.819, gt=0, le=100, description="output torque per amp (AK80-9: 0.091 x 9)"
    )
    comm_timeout_ms: int = Field(
        0,
        ge=0,
        le=60_000,
        description="the driver's own CAN timeout as set with R-Link (0: none); not writable "
        "over CAN, so it is not sent: it tells the simulation what the driver does",
    )
    reply_bytes: Literal[6, 8] = Field(
        8,
        description="the driver's answer length: 6 (position, speed, current: the manual's "
        "MIT reply table) or 8 (plus temperature and error code); both are decoded, so it "
        "only tells the simulation what the driver sends",
    )


class CubeMarsAKMit(ServoProfile):
    """AK module in MIT mode; polled with the enter-motor-mode frame, one answer per frame."""

    STOP_BEHAVIOUR = "holds the last MIT command (position and gains)"

    name = "cubemars-ak-mit"
    replies_per_command = 1
    replies_per_request = 1
    replies_per_lifecycle = 1
    """FC and FD are answered with the state."""
    min_id, max_id = 1, 0x7F
    Options: ClassVar[type[ProfileOptions]] = CubeMarsMitOptions
    options: CubeMarsMitOptions
    telemetry = "polled"

    def __init__(self, can_id: int, options: ProfileOptions | None = None, **overrides: object):
        super().__init__(can_id, options, **overrides)
        o = self.options
        self.ranges = o.ranges()
        self.max_angle_deg = math.degrees(o.p_max_rad)
        self.min_angle_deg = -self.max_angle_deg
        self.resolution_deg = math.degrees(mit.step(self.ranges.position_rad, mit.POSITION_BITS))
        self._released = False
        """Motor mode was left on purpose: polling with FC would re-enter it, so do not poll."""

    def _frame(self, data: bytes) -> can.Message:
        return can.Message(arbitration_id=self.can_id, is_extended_id=False, data=data)

    def comm_timeout_s(self) -> float | None:
        """The driver's timeout as set with R-Link (``comm_timeout_ms``; 0: none)."""
        return self.options.comm_timeout_ms / 1000 or None

    def position_command(self, angle_deg: float, max_speed_dps: float | None = None) -> can.Message:
        self._check_angle(angle_deg)
        self._speed_limit(max_speed_dps, 0.0)  # validated; MIT mode has no speed limit
        command = mit.MitCommand(
            math.radians(angle_deg), 0.0, self.options.kp, self.options.kd, 0.0
        )
        return self._frame(mit.pack_command(command, self.ranges))

    def telemetry_requests(self) -> list[can.Message]:
        """The manual's way to read the state: ``FF x7 FC``. Never after a release, which
        it would undo by re-entering motor mode."""
        return [] if self._released else [self._frame(mit.ENTER_MOTOR_MODE)]

    def startup_frames(self) -> list[can.Message]:
        self._released = False
        return [self._frame(mit.ENTER_MOTOR_MODE)]

    def release_frames(self) -> list[can.Message]:
        self._released = True
        return [self._frame(mit.EXIT_MOTOR_MODE)]

    def shutdown_frames(self) -> list[can.Message]:
        self._released = True
        return [self._frame(mit.EXIT_MOTOR_MODE)]

    def set_zero_frame(self) -> can.Message:
        """Present position as zero (the motor mutes for about a second; never sent alone)."""
        return self._frame(mit.SET_ZERO)

    @classmethod
    def sim_device(cls, motor: SimMotor, can_id: int, options: ProfileOptions) -> SimDevice:
        """The simulated driver (built-in simulation, ``mavservo sim``)."""
        return simulated_device(cls, motor, can_id, options)

    def identifiers(self) -> tuple[FrameId, ...]:
        """Commands, polls and special frames on the id; answers on the master id, byte 0 the
        driver id."""
        return (
            FrameId(self.can_id, False, "to_servo", "command"),
            FrameId(
                self.options.master_id,
                False,
                "from_servo",
                "reply",
                first_byte=(self.can_id, 0xFF),
            ),
        )

    def is_reply(self, msg: can.Message) -> bool:
        return (
            not msg.is_extended_id
            and not msg.is_remote_frame
            and msg.arbitration_id == self.options.master_id
            and len(msg.data) in REPLY_LENGTHS
            and msg.data[0] == self.can_id
        )

    def decode(self, msg: can.Message, timestamp: float) -> ServoState | None:
        if not self.is_reply(msg):
            return None
        data = bytes(msg.data)
        reply = mit.unpack_reply(data, self.ranges)
        short = len(data) < 8  # no temperature, no error code: those keep their last value
        temperature = None if short else float(data[6] - 256 if data[6] >= 0x80 else data[6])
        return self._merge(
            timestamp,
            position_deg=math.degrees(reply.position_rad),
            velocity_dps=math.degrees(reply.velocity_rad_s),
            current_a=reply.torque_nm / self.options.torque_constant_nm_per_a,
            temperature_c=temperature,
            faults=None if short else fault_from_error_code(data[7]),
        )
