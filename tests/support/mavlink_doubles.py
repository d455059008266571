"""Shared test doubles for the MAVLink tests: a recording ActuatorBackend and message helpers.

The backend double maps servo output channels 1 and 9 and actuator index 1 to three servos,
converts units like a linear mapping would, and records every call, so tests can assert exactly
what reached "the bus" side.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.mavlink.backend import ACCEPTED, ApplyResult, Outcome, ServoStatus
from mavservo.mavlink.component import HostedComponent
from mavservo.mavlink.mavlink_core import MavlinkCore
from mavservo.mavlink.settings import MavlinkSettings
from mavservo.servos.base import Fault, ServoState

SERVO_CHANNELS = {1: "aileron", 9: "drop"}
ACTUATOR_INDICES = {1: "flap", 5: "flap"}  # 5: DO_SET_ACTUATOR param 5 (COMMAND_INT x)
NAMES = ["aileron", "drop", "flap"]
HALF_RANGE_DEG = 30.0


@dataclass
class RecordingBackend:
    calls: list[tuple] = field(default_factory=list)
    offline: set[str] = field(default_factory=set)
    states: dict[str, ServoState] = field(default_factory=dict)
    setpoints: dict[str, float] = field(default_factory=dict)
    in_failsafe: bool = False
    failsafe_events: list[str] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def mapped_servo_channels(self) -> set[int]:
        return set(SERVO_CHANNELS)

    def mapped_actuator_indices(self) -> set[int]:
        return set(ACTUATOR_INDICES)

    def _apply(self, name: str, angle: float) -> ApplyResult:
        if name in self.offline:
            return ApplyResult(Outcome.TEMPORARILY_REJECTED, f"{name} offline")
        self.setpoints[name] = angle
        return ACCEPTED

    def apply_servo_output(self, channel: int, pwm_us: float, source: str, now: float):
        with self.lock:
            self.calls.append(("servo", channel, pwm_us, source))
            return self._apply(SERVO_CHANNELS[channel], (pwm_us - 1500) / 500 * HALF_RANGE_DEG)

    def apply_actuator(self, index: int, value: float, source: str, now: float):
        with self.lock:
            self.calls.append(("actuator", index, value, source))
            return self._apply(ACTUATOR_INDICES[index], value * HALF_RANGE_DEG)

    def apply_gimbal(self, gimbal, roll_deg, pitch_deg, yaw_deg, source, now):
        with self.lock:
            self.calls.append(("gimbal", gimbal, roll_deg, pitch_deg, yaw_deg, source))
            return ACCEPTED

    def servo_statuses(self) -> list[ServoStatus]:
        with self.lock:
            out = []
            for index, name in enumerate(NAMES):
                state = self.states.get(name)
                normalized = None if state is None else state.position_deg / HALF_RANGE_DEG
                channel = next((c for c, n in SERVO_CHANNELS.items() if n == name), None)
                actuator = next((i for i, n in ACTUATOR_INDICES.items() if n == name), None)
                out.append(
                    ServoStatus(
                        name,
                        index,
                        state,
                        name not in self.offline,
                        self.setpoints.get(name),
                        normalized,
                        channel,
                        actuator,
                    )
                )
            return out

    def enter_failsafe(self, reason: str, now: float) -> None:
        self.in_failsafe = True
        self.failsafe_events.append("enter")

    def leave_failsafe(self, now: float) -> None:
        self.in_failsafe = False
        self.failsafe_events.append("leave")

    def health(self) -> dict[str, float]:
        return {}

    def servo_calls(self, kind: str = "servo") -> list[tuple]:
        with self.lock:
            return [c for c in self.calls if c[0] == kind]


def state(
    position: float,
    velocity: float = 0.0,
    current: float = 0.0,
    temperature: float = 30.0,
    faults: Fault | None = None,
    voltage: float | None = None,
) -> ServoState:
    return ServoState(
        position_deg=position,
        velocity_dps=velocity,
        current_a=current,
        temperature_c=temperature,
        faults=faults if faults is not None else Fault(0),
        timestamp=0.0,
        voltage_v=voltage,
    )


def make_mavlink_core(
    backend: RecordingBackend | None = None,
    *,
    boot_time: float = 0.0,
    gimbals: tuple[HostedComponent, ...] = (),
    **settings: Any,
) -> tuple[MavlinkCore, RecordingBackend]:
    """A sans-I/O MAVLink core of system 1 on a recording backend (a fresh one unless given),
    ``settings`` overriding :class:`MavlinkSettings` fields: the one factory of the MAVLink
    tests, so a new required field of the core is added here once."""
    backend = backend if backend is not None else RecordingBackend()
    fields: dict[str, Any] = {"system_id": 1, **settings}
    return MavlinkCore(MavlinkSettings(**fields), backend, gimbals, boot_time=boot_time), backend


def wire(msg: Any, src: tuple[int, int]) -> Any:
    """Round-trip ``msg`` through the real MAVLink 2 codec, so it carries a source header."""
    encoder = mavlink2.MAVLink(None, srcSystem=src[0], srcComponent=src[1])
    decoder = mavlink2.MAVLink(None)
    decoded = decoder.parse_buffer(msg.pack(encoder))
    assert decoded and len(decoded) == 1
    return decoded[0]


def command_long(target: tuple[int, int], command: int, *params: float, confirmation: int = 0):
    p = list(params) + [0.0] * (7 - len(params))
    return mavlink2.MAVLink_command_long_message(target[0], target[1], command, confirmation, *p)


def command_int(
    target: tuple[int, int], command: int, p1=0.0, p2=0.0, p3=0.0, p4=0.0, x=0, y=0, z=0.0
):
    return mavlink2.MAVLink_command_int_message(
        target[0], target[1], 0, command, 0, 0, p1, p2, p3, p4, x, y, z
    )


def heartbeat(mav_type: int = 1, autopilot: int = 3):
    return mavlink2.MAVLink_heartbeat_message(mav_type, autopilot, 0, 0, 4, 3)


def servo_output_raw(port: int = 0, **channels: int):
    values = [channels.get(f"servo{i}", 0) for i in range(1, 17)]
    return mavlink2.MAVLink_servo_output_raw_message(0, port, *values)


NAN = math.nan
