"""Robstride RS00..RS06 joint motors (and the Xiaomi CyberGear they descend from).

Wire facts: Robstride's user manuals (RS00..RS06 "User Manual 260428", chapter 4 "Driver
protocol and instructions" for the private protocol, chapter 6 "MIT Communication Protocol
Description"), 1 Mbit/s.

**Private protocol** (the factory default): 29-bit extended ids, ``type << 24 | data << 8 |
target``; the host sends with ``data`` = its host id (default 0xFD) and ``target`` = the motor
id; the motor answers with ``data`` = its own id (bits 15..8) and ``target`` = the host id
(bits 7..0), and in the feedback frames bits 21..16 carry the fault bits and 23..22 the mode
(0 reset, 1 calibration, 2 run). Types used here:

* 3 enable (run), 4 stop (``data[0] = 1`` also clears faults; it leaves the motor in reset
  mode), 6 set the mechanical zero (``data[0] = 1``);
* 0x12 single parameter write: ``[index u16 LE, 0, 0, value LE]``: ``run_mode`` 0x7005 = 5
  (position mode CSP), ``loc_ref`` 0x7016 (float rad: the position command), ``limit_spd``
  0x7017 (float rad/s: the CSP speed limit), ``EPScan_time`` 0x7026 (u16: 1 = 10 ms, each
  further count 5 ms more), ``canTimeout`` 0x7028 (u32: 20000 = 1 s; 0 = none; the motor stops
  when no frame came for that long);
* 0x18 active reporting on (``01 02 03 04 05 06 F_CMD``, F_CMD 1) at the EPScan_time period;
  the reports are feedback frames of type 0x18 (type 2 on older firmware: both are accepted);
* answers: every frame above is answered with a feedback frame (type 2): angle u16 over
  +-4 pi rad, velocity u16 and torque u16 over the model's +-V and +-T, temperature u16 in
  0.1 degC, all big-endian; 0x15 fault frames carry a 32-bit fault word.

**MIT protocol** (after the protocol switch, type 0x19 F_CMD 2, which takes effect after a power
cycle): standard ids; the MIT packing of :mod:`.mit` on the motor id with the model's ranges;
``FF x7 FC`` enable, ``FD`` stop, ``FF x6 FF FB`` clear faults, ``FF x6 01 F9`` active
reporting on; parameter writes on ``0x400 | id`` (same layout, echoed on the same id); answers
on the host id: ``[id, position 16, velocity 12, torque 12, temperature u16 x 10]``; while the
motor is faulted it answers a fault report instead: ``[id, fault word u16 LE, 0, 0, 0, 0, 0]``
(bit 14 overload, 7 uncalibrated, 3 encoder, 2 under-voltage, 1 driver, 0 over-temperature:
RobStride's sample program), so a state report means no fault. MIT feedback carries no mode: a
motor stopped by its own timeout is not seen as stopped (it is started again when it comes back
from offline); the private protocol reports it, so it is the default.

A motor answers only in the protocol it is set to, so a host speaking the other one hears
silence: :meth:`Robstride.diagnose` recognises the other protocol's frames from this motor and
:meth:`Robstride.silence_hint` says what to check when it never answers at all.

Range policy: an angle outside the model's position range (+-4 pi rad: what the feedback can
express) raises ``ValueError`` before anything is built; speed limits saturate at the model's
velocity range. The speed limit is a parameter of its own (limit_spd), not part of the
position write: it goes with the set-up step of the start-up, from the latest limit a command
asked for (the servo's ``max_speed_dps``, constant per servo). MIT mode takes no speed limit
(the gains shape the motion).

Assumed where the manual is silent: the switch-on frame for active reporting is answered with
one report (the manual's answer table for type 0x18 is the report itself).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Hashable
from dataclasses import dataclass
from typing import ClassVar, Literal

import can
from pydantic import Field, model_validator

from .. import mit
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

# -- private protocol ----------------------------------------------------------------------
TYPE_GET_ID = 0x00
TYPE_CONTROL = 0x01
TYPE_FEEDBACK = 0x02
TYPE_ENABLE = 0x03
TYPE_STOP = 0x04
TYPE_SET_ZERO = 0x06
TYPE_PARAM_READ = 0x11
TYPE_PARAM_WRITE = 0x12
TYPE_FAULT = 0x15
TYPE_REPORT = 0x18
TYPE_PROTOCOL = 0x19

PARAM_RUN_MODE = 0x7005
PARAM_LOC_REF = 0x7016
PARAM_LIMIT_SPD = 0x7017
PARAM_EPSCAN_TIME = 0x7026
PARAM_CAN_TIMEOUT = 0x7028
RUN_MODE_CSP = 5
CAN_TIMEOUT_UNITS_PER_MS = 20
"""canTimeout counts 50 us: 20000 is one second (the manuals' parameter table)."""
REPORT_BASE_MS = 10
REPORT_STEP_MS = 5
"""EPScan_time: 1 means 10 ms, every further count 5 ms more."""

MODE_RESET, MODE_CALIBRATION, MODE_RUN = 0, 1, 2
ID_MASK = 0x1F00FFFF
"""Bits that identify a motor's answer: type and the two ids (fault and mode bits vary)."""
POSITION_RANGE_RAD = 4 * math.pi
"""Feedback angle range (+-4 pi, the manuals' type 2 table)."""

FEEDBACK_FAULT_BITS: dict[int, Fault] = {
    16: Fault.LOW_VOLTAGE,
    17: Fault.OVER_CURRENT,  # three-phase over-current
    18: Fault.OVER_TEMPERATURE,
    19: Fault.ENCODER,  # magnetic encoder
    20: Fault.STALL,  # stall / overload
    21: Fault.UNCALIBRATED,
}
"""The fault bits of a feedback frame's id (the manuals' type 2 table)."""
FAULT_WORD_BITS: dict[int, Fault] = {
    0: Fault.OVER_TEMPERATURE,
    1: Fault.DRIVER,  # driver chip
    2: Fault.LOW_VOLTAGE,
    3: Fault.OVER_VOLTAGE,
    4: Fault.OVER_CURRENT,  # B-phase current sampling
    5: Fault.OVER_CURRENT,  # C-phase current sampling
    7: Fault.UNCALIBRATED,  # encoder not calibrated
    8: Fault.DRIVER,  # hardware identification
    9: Fault.ENCODER,  # position initialisation
    14: Fault.STALL,  # stall overload protection
    16: Fault.OVER_CURRENT,  # A-phase current sampling
}
"""The fault word of a type 0x15 frame (bytes 0-3, little-endian); other bits are OTHER."""

# -- MIT protocol --------------------------------------------------------------------------
MIT_PARAM_WRITE_BASE = 0x400
MIT_CLEAR_FAULTS = b"\xff" * 7 + b"\xfb"
MIT_REPORT_ON = b"\xff" * 6 + b"\x01\xf9"
MIT_POSITION_RAD = 12.57
"""P_MAX of every model's manual, MIT section (its example code and "-12.57 rad ~ 12.57 rad",
the RS00..RS06 manuals alike; RobStride Dynamics' own robstride_dynamics package maps 4 pi,
which rounds to it). RobStride's sample program maps +-12.5 (the CyberGear heritage): a motor
whose firmware does is configured with the ``mit_position_max_rad`` option."""
MIT_FAULT_WORD_BITS: dict[int, Fault] = {
    0: Fault.OVER_TEMPERATURE,
    1: Fault.DRIVER,  # driver fault
    2: Fault.LOW_VOLTAGE,
    3: Fault.ENCODER,
    7: Fault.UNCALIBRATED,
    14: Fault.STALL,  # overload
}
"""The fault word of an MIT fault report (bytes 1..2 little-endian, bytes 3..7 zero: RobStride's
sample program); other bits are OTHER."""
MIT_FAULT_REPORT_TAIL = bytes(5)
MIT_RESERVED_PREFIX = b"\xff" * 6
"""Frames starting with six 0xFF are the MIT special commands (enable, stop, clear, modes,
reporting, protocol): a position command never goes out looking like one."""


@dataclass(frozen=True)
class Model:
    """One model's ranges (the manuals' example code: V_MAX, T_MAX, KP_MAX, KD_MAX) and its
    torque constant (the specification table, N m/Arms)."""

    v_max_rad_s: float
    t_max_nm: float
    kp_max: float
    kd_max: float
    torque_constant_nm_per_a: float
    mit_position_rad: float = MIT_POSITION_RAD
    """The MIT packing's position range (+-), per model: every manual says 12.57."""


MODELS: dict[str, Model] = {
    "RS00": Model(33.0, 14.0, 500.0, 5.0, 1.48),
    "RS01": Model(44.0, 17.0, 500.0, 5.0, 1.22),
    "RS02": Model(44.0, 17.0, 500.0, 5.0, 1.22),
    "RS03": Model(20.0, 60.0, 5000.0, 100.0, 2.36),
    "RS04": Model(15.0, 120.0, 5000.0, 100.0, 2.1),
    "RS05": Model(50.0, 5.5, 500.0, 5.0, 0.94),
    "RS06": Model(50.0, 36.0, 5000.0, 100.0, 1.09),
}
ModelName = Literal["RS00", "RS01", "RS02", "RS03", "RS04", "RS05", "RS06"]


def faults_from_id(arbitration_id: int) -> Fault:
    """The named faults of a feedback frame's id bits 21..16 (every bit is documented)."""
    faults = NO_FAULT
    for bit, fault in FEEDBACK_FAULT_BITS.items():
        if arbitration_id >> bit & 1:
            faults |= fault
    return faults


def faults_from_word(word: int) -> Fault:
    """The named faults of a type 0x15 fault word; an undocumented bit is ``Fault.OTHER``."""
    faults = NO_FAULT
    for bit in range(32):
        if word >> bit & 1:
            faults |= FAULT_WORD_BITS.get(bit, Fault.OTHER)
    return faults


def faults_from_mit_word(word: int) -> Fault:
    """The named faults of an MIT fault report's word; an undocumented bit is OTHER."""
    faults = NO_FAULT
    for bit in range(16):
        if word >> bit & 1:
            faults |= MIT_FAULT_WORD_BITS.get(bit, Fault.OTHER)
    return faults


def report_counts(hz: float) -> int:
    """EPScan_time for a report rate: the longest period not longer than ``1 / hz``."""
    period_ms = 1000.0 / hz
    return max(1, min(0xFFFF, math.floor((period_ms - REPORT_BASE_MS) / REPORT_STEP_MS) + 1))


def report_period_s(counts: int) -> float:
    """The report period EPScan_time ``counts`` stands for."""
    return (REPORT_BASE_MS + REPORT_STEP_MS * (max(1, counts) - 1)) / 1000


def to_u16(value: float, limit: float) -> int:
    """``value`` on a u16 over ``-limit..limit`` (saturated, nearest count: a sensor reading)."""
    value = 0.0 if math.isnan(value) else min(limit, max(-limit, value))
    return min(0xFFFF, max(0, math.floor((value + limit) * 0xFFFF / (2 * limit) + 0.5)))


def from_u16(field: int, limit: float) -> float:
    """The value of a u16 field over ``-limit..limit`` (the manuals' uint-to-float)."""
    return field * 2 * limit / 0xFFFF - limit


class RobstrideOptions(ProfileOptions):
    """Per-servo ``options:`` of a Robstride motor. Defaults: an RS01 in the private protocol,
    host id 0xFD, 200 ms communication timeout."""

    model: ModelName = Field("RS01", description="the motor model: its velocity/torque ranges")
    host_id: int = Field(
        0xFD, ge=0, le=0xFF, description="the host (master) CAN id the motor answers to"
    )
    protocol: Literal["private", "mit"] = Field(
        "private", description="what the motor is set to speak (it answers in nothing else)"
    )
    comm_timeout_ms: int = Field(
        200,
        ge=0,
        le=60_000,
        description="the motor's own CAN timeout (canTimeout), written at start-up: it stops "
        "after this long without a frame (0: never)",
    )
    default_speed_dps: float = Field(
        360.0, gt=0, le=100_000, description="private protocol speed limit (limit_spd), deg/s"
    )
    kp: float = Field(20.0, ge=0, le=5000, description="MIT stiffness, N m/rad")
    kd: float = Field(
        1.0, gt=0, le=100, description="MIT damping, N m s/rad (never 0: the motor oscillates)"
    )
    mit_position_max_rad: float | None = Field(
        None,
        ge=1.0,
        le=100.0,
        description="MIT packing position range +-rad (null: the model's, 12.57 per the "
        "manuals; 12.5 for firmware that maps like RobStride's sample program)",
    )

    @model_validator(mode="after")
    def _gains_fit_the_model(self) -> RobstrideOptions:
        spec = MODELS[self.model]
        if self.kp > spec.kp_max or self.kd > spec.kd_max:
            raise ValueError(
                f"kp/kd of a {self.model} must be within 0..{spec.kp_max:g} and "
                f"0..{spec.kd_max:g}, got kp {self.kp:g}, kd {self.kd:g}"
            )
        return self

    @property
    def spec(self) -> Model:
        return MODELS[self.model]

    @property
    def mit_position_rad(self) -> float:
        """The MIT position range in use: the option, else the model's."""
        if self.mit_position_max_rad is not None:
            return self.mit_position_max_rad
        return self.spec.mit_position_rad

    def mit_ranges(self) -> mit.MitRanges:
        """The MIT packing ranges of this model (MIT protocol)."""
        spec = self.spec
        return mit.MitRanges(
            position_rad=mit.Span.symmetric(self.mit_position_rad),
            velocity_rad_s=mit.Span.symmetric(spec.v_max_rad_s),
            torque_nm=mit.Span.symmetric(spec.t_max_nm),
            kp=mit.Span(0.0, spec.kp_max),
            kd=mit.Span(0.0, spec.kd_max),
        )


def parse_id(arbitration_id: int) -> tuple[int, int, int]:
    """``(type, data, target)`` of a private-protocol id."""
    return arbitration_id >> 24 & 0x1F, arbitration_id >> 8 & 0xFFFF, arbitration_id & 0xFF


def param_payload(index: int, value: bytes) -> bytes:
    """``[index LE, 0, 0, value LE]``: a parameter write's eight bytes."""
    return struct.pack("<HH", index, 0) + value.ljust(4, b"\0")


class Robstride(ServoProfile):
    """A Robstride motor: position mode (CSP) in the private protocol, or the MIT packing after
    a protocol switch; it pushes its state at the servo's telemetry rate (active reporting)."""

    STOP_BEHAVIOUR = (
        "holds its last target until its own communication timeout, when set in the motor, "
        "stops it (fault: communication lost)"
    )

    name = "robstride"
    replies_per_command = 1
    replies_per_request = 0
    replies_per_lifecycle = 1
    """Every start-up, stop and parameter frame is answered with one feedback frame."""
    min_id, max_id = 1, 0x7F
    Options: ClassVar[type[ProfileOptions]] = RobstrideOptions
    options: RobstrideOptions
    telemetry = "pushed"

    def __init__(self, can_id: int, options: ProfileOptions | None = None, **overrides: object):
        super().__init__(can_id, options, **overrides)
        o = self.options
        self.spec = o.spec
        self.ranges = o.mit_ranges()
        self.private = o.protocol == "private"
        limit = POSITION_RANGE_RAD if self.private else o.mit_position_rad
        self.max_angle_deg = math.degrees(limit)
        self.min_angle_deg = -self.max_angle_deg
        self.max_speed_dps = math.degrees(self.spec.v_max_rad_s)
        self.resolution_deg = math.degrees(2 * limit / 0xFFFF)
        self._speed_dps = min(o.default_speed_dps, self.max_speed_dps)
        """The latest speed limit asked for: limit_spd at the next start-up."""
        self._startup_due = False
        self._clean_reset = False
        """The latest feedback says reset mode without a fault."""
        self._last_feedback_t: float | None = None
        self._last_report_t: float | None = None
        """When the latest feedback and the latest active report came: reports still coming
        mean the motor kept its settings (see :meth:`startup_frames`)."""

    # -- frames the bridge sends -----------------------------------------------------------

    def private_frame(self, comm_type: int, data: bytes, field: int | None = None) -> can.Message:
        """A private-protocol frame to this motor (``field``: bits 23..8, default host id)."""
        field = self.options.host_id if field is None else field
        arbitration_id = comm_type << 24 | field << 8 | self.can_id
        return can.Message(arbitration_id=arbitration_id, is_extended_id=True, data=data)

    def param_write(self, index: int, value: bytes) -> can.Message:
        """A single parameter write (RAM only: nothing is stored in flash)."""
        data = param_payload(index, value)
        if self.private:
            return self.private_frame(TYPE_PARAM_WRITE, data)
        return self._mit(data, MIT_PARAM_WRITE_BASE | self.can_id)

    def _mit(self, data: bytes, arbitration_id: int | None = None) -> can.Message:
        target = self.can_id if arbitration_id is None else arbitration_id
        return can.Message(arbitration_id=target, is_extended_id=False, data=data)

    def position_command(self, angle_deg: float, max_speed_dps: float | None = None) -> can.Message:
        self._check_angle(angle_deg)
        speed = self._speed_limit(max_speed_dps, self.options.default_speed_dps)
        if not self.private:
            command = mit.MitCommand(
                math.radians(angle_deg), 0.0, self.options.kp, self.options.kd, 0.0
            )
            data = mit.pack_command(command, self.ranges)
            if data[:6] == MIT_RESERVED_PREFIX:
                raise ValueError(f"{self.name}: the command would read as a special frame")
            return self._mit(data)
        self._speed_dps = speed
        return self.param_write(PARAM_LOC_REF, struct.pack("<f", math.radians(angle_deg)))

    def telemetry_requests(self) -> list[can.Message]:
        return []

    def startup_frames(self) -> list[can.Message]:
        """Private protocol, in two steps (the manual's CSP sequence): first clear faults
        (stop), position mode, the motor's own timeout, the report period, the speed limit,
        active reporting on; then, once the motor's answers say reset mode and its
        reports come, the enable alone, at the next command slot (:meth:`startup_continues`).

        Why two: on the wire the enable (type 3) wins arbitration over the stop (type 4) and
        the parameter writes (0x12) queued with it. Sent in one burst, an adapter with several
        frames waiting sends it first: the run-mode write then finds the motor running and is
        refused (the manual: change modes only when stopped), and the motor runs in operation
        control mode, ignoring every position. So the enable is sent alone, once the latest
        feedback says reset mode without a fault while the active reports still come (the
        motor has its settings). The same rule re-enables a motor its own timeout stopped; a
        power-cycled motor (reports off) or a faulted one (a clear is due) gets the first step
        again."""
        self._startup_due = False
        hz = self.telemetry_hz or DEFAULT_REPORT_HZ
        timeout = struct.pack("<I", self.options.comm_timeout_ms * CAN_TIMEOUT_UNITS_PER_MS)
        report = struct.pack("<H", report_counts(hz))
        if not self.private:
            return [
                self.param_write(PARAM_CAN_TIMEOUT, timeout),
                self.param_write(PARAM_EPSCAN_TIME, report),
                self._mit(MIT_CLEAR_FAULTS),
                self._mit(mit.ENTER_MOTOR_MODE),
                self._mit(MIT_REPORT_ON),
            ]
        enable = self.private_frame(TYPE_ENABLE, bytes(8))
        if self._clean_reset and self._reports_coming(hz):
            return [enable]
        speed = struct.pack("<f", math.radians(max(self._speed_dps, 1e-3)))
        self._startup_due = True  # the enable follows at the next start-up
        return [
            self.private_frame(TYPE_STOP, b"\x01" + bytes(7)),
            self.param_write(PARAM_RUN_MODE, bytes([RUN_MODE_CSP])),
            self.param_write(PARAM_CAN_TIMEOUT, timeout),
            self.param_write(PARAM_EPSCAN_TIME, report),
            self.param_write(PARAM_LIMIT_SPD, speed),
            self.private_frame(TYPE_REPORT, bytes([1, 2, 3, 4, 5, 6, 1, 0])),
        ]

    def _reports_coming(self, hz: float) -> bool:
        """True when an active report came within three report periods of the latest
        feedback (times as handed to :meth:`decode`)."""
        last, report = self._last_feedback_t, self._last_report_t
        window = 3 * report_period_s(report_counts(hz))
        return last is not None and report is not None and last - report <= window

    def needs_startup(self) -> bool:
        return self._startup_due

    def startup_continues(self) -> bool:
        """The enable alone is what the next start-up sends (the set-up step is answered and
        the reports come): it goes at the next command slot, not a retry interval later."""
        hz = self.telemetry_hz or DEFAULT_REPORT_HZ
        return self.private and self._startup_due and self._clean_reset and self._reports_coming(hz)

    def release_frames(self) -> list[can.Message]:
        """Stop: torque off, reset mode."""
        if not self.private:
            return [self._mit(mit.EXIT_MOTOR_MODE)]
        return [self.private_frame(TYPE_STOP, bytes(8))]

    def shutdown_frames(self) -> list[can.Message]:
        return self.release_frames()

    def set_zero_frame(self) -> can.Message:
        """Make the present position the zero (never sent by the bridge on its own)."""
        if not self.private:
            return self._mit(mit.SET_ZERO)
        return self.private_frame(TYPE_SET_ZERO, b"\x01" + bytes(7))

    @classmethod
    def sim_device(cls, motor: SimMotor, can_id: int, options: ProfileOptions) -> SimDevice:
        """The simulated motor (built-in simulation, ``mavservo sim``)."""
        return simulated_device(cls, motor, can_id, options)

    def identifiers(self) -> tuple[FrameId, ...]:
        """Private: the host's frames ``type << 24 | host << 8 | id`` (exact), the motor's
        answers ``type << 24 | id << 8 | host`` with the fault and mode bits masked out. MIT:
        commands on the id, parameter writes and their echo on ``0x400 | id``, answers on the
        host id naming the motor in byte 0."""
        host = self.options.host_id
        if self.private:
            sent = [
                FrameId(t << 24 | host << 8 | self.can_id, True, "to_servo", purpose)
                for t, purpose in (
                    (TYPE_ENABLE, "lifecycle"),
                    (TYPE_STOP, "lifecycle"),
                    (TYPE_SET_ZERO, "lifecycle"),
                    (TYPE_PARAM_WRITE, "command"),
                    (TYPE_REPORT, "lifecycle"),
                )
            ]
            answers = [
                FrameId(t << 24 | self.can_id << 8 | host, True, "from_servo", purpose, ID_MASK)
                for t, purpose in (
                    (TYPE_FEEDBACK, "reply"),
                    (TYPE_REPORT, "push"),
                    (TYPE_FAULT, "push"),
                )
            ]
            return (*sent, *answers)
        params = MIT_PARAM_WRITE_BASE | self.can_id
        return (
            FrameId(self.can_id, False, "to_servo", "command"),
            FrameId(params, False, "to_servo", "lifecycle"),
            FrameId(params, False, "from_servo", "reply"),
            FrameId(host, False, "from_servo", "reply", first_byte=(self.can_id, 0xFF)),
        )

    # -- frames the motor sends --------------------------------------------------------------

    def is_reply(self, msg: can.Message) -> bool:
        if msg.is_remote_frame or len(msg.data) != 8:
            return False
        if self.private:
            if not msg.is_extended_id:
                return False
            comm_type, field, target = parse_id(msg.arbitration_id)
            return (
                comm_type in (TYPE_FEEDBACK, TYPE_REPORT, TYPE_FAULT)
                and field & 0xFF == self.can_id
                and target == self.options.host_id
            )
        if msg.is_extended_id:
            return False
        if msg.arbitration_id == MIT_PARAM_WRITE_BASE | self.can_id:
            return True
        return msg.arbitration_id == self.options.host_id and msg.data[0] == self.can_id

    def exchange_key(self, msg: can.Message) -> Hashable | None:
        """Private: ``"report"`` for the active-report switch and the reports, ``"feedback"``
        for everything else (all answered with a type 2 frame). MIT: ``("param", index)``
        for a parameter write and its echo, ``"feedback"`` otherwise."""
        if msg.is_extended_id:
            return "report" if parse_id(msg.arbitration_id)[0] == TYPE_REPORT else "feedback"
        if msg.arbitration_id == MIT_PARAM_WRITE_BASE | self.can_id and len(msg.data) >= 2:
            return ("param", msg.data[0] | msg.data[1] << 8)
        return "feedback"

    def decode(self, msg: can.Message, timestamp: float) -> ServoState | None:
        if not self.is_reply(msg):
            return None
        data = bytes(msg.data)
        if not self.private:
            if msg.arbitration_id != self.options.host_id:
                return self._merge(timestamp)  # a parameter echo: proof of life only
            if data[3:] == MIT_FAULT_REPORT_TAIL:  # a fault report, not a state
                word = int.from_bytes(data[1:3], "little")
                return self._merge(timestamp, faults=faults_from_mit_word(word))
            reply = mit.unpack_reply(data, self.ranges)
            return self._merge(
                timestamp,
                position_deg=math.degrees(reply.position_rad),
                velocity_dps=math.degrees(reply.velocity_rad_s),
                current_a=reply.torque_nm / self.spec.torque_constant_nm_per_a,
                temperature_c=struct.unpack_from(">H", data, 6)[0] / 10,
                faults=NO_FAULT,  # a state report: the motor reports no fault
            )
        comm_type = parse_id(msg.arbitration_id)[0]
        if comm_type == TYPE_FAULT:
            word = struct.unpack_from("<I", data)[0]
            self._clean_reset = False
            return self._merge(timestamp, faults=faults_from_word(word))
        mode = msg.arbitration_id >> 22 & 0x3
        # the latest feedback decides: the answers before the enable still say "reset"
        self._startup_due = mode != MODE_RUN
        faults = faults_from_id(msg.arbitration_id)
        self._clean_reset = mode == MODE_RESET and not faults
        self._last_feedback_t = timestamp
        if comm_type == TYPE_REPORT:
            self._last_report_t = timestamp
        angle, velocity, torque, temperature = struct.unpack(">HHHH", data)
        return self._merge(
            timestamp,
            position_deg=math.degrees(from_u16(angle, POSITION_RANGE_RAD)),
            velocity_dps=math.degrees(from_u16(velocity, self.spec.v_max_rad_s)),
            current_a=from_u16(torque, self.spec.t_max_nm) / self.spec.torque_constant_nm_per_a,
            temperature_c=temperature / 10,
            faults=faults,
        )

    # -- when the motor is not heard ----------------------------------------------------------

    def diagnose(self, msg: can.Message) -> str | None:
        """This motor's frames in the protocol it is not configured for: what to change."""
        if msg.is_remote_frame or len(msg.data) != 8:
            return None
        host = self.options.host_id
        mit_reply = not msg.is_extended_id and msg.arbitration_id == host
        if self.private and mit_reply and msg.data[0] == self.can_id:
            return (
                f"answers in the MIT protocol (standard id 0x{msg.arbitration_id:X}); set "
                "options.protocol: mit, or switch the motor back to the private protocol "
                "(MIT command FF FF FF FF FF FF 00 FD, then power-cycle it)"
            )
        if not self.private and msg.is_extended_id:
            comm_type, field, _ = parse_id(msg.arbitration_id)
            if comm_type in (TYPE_FEEDBACK, TYPE_REPORT, TYPE_GET_ID) and field & 0xFF == (
                self.can_id
            ):
                return (
                    f"answers in the private protocol (extended id 0x{msg.arbitration_id:08X}); "
                    "set options.protocol: private, or switch the motor to MIT (private type "
                    "0x19 with F_CMD 2, then power-cycle it)"
                )
        if self.private and msg.is_extended_id:
            comm_type, field, target = parse_id(msg.arbitration_id)
            ours = comm_type in (TYPE_FEEDBACK, TYPE_REPORT) and field & 0xFF == self.can_id
            if ours and target != host:
                return (
                    f"answers host id 0x{target:02X}, not 0x{host:02X}; set "
                    f"options.host_id: 0x{target:02X}"
                )
        return None

    def silence_hint(self) -> str | None:
        """What to check when the motor never answered."""
        other = "MIT" if self.private else "private"
        return (
            f"robstride motor id {self.can_id} never answered in the {self.options.protocol} "
            f"protocol (host id 0x{self.options.host_id:02X}); check its CAN id, the 1 Mbit/s "
            f"bitrate, power, and whether it was switched to the {other} protocol "
            "(it then ignores these frames)"
        )


DEFAULT_REPORT_HZ = 10.0
"""Report rate when the servo's telemetry rate is not given (the config's default)."""
