"""The autopilot's 16 servo outputs: the motion script, overridden by the commands it sent.

A part of its own because it is what ArduPilot's SRV_Channels would output, independent of
how it is sent: the scripted profile's PWM at a time, with a DO_SET_SERVO value holding its
channel and a DO_REPEAT_SERVO cycling it until it ends (then holding its last value), and
which channels changed since the last SERVO_OUTPUT_RAW. PX4's normalized view of the same
frame (ACTUATOR_OUTPUT_STATUS) lives here too.
"""

from __future__ import annotations

import math

from mavservo.config import RepeatServo, repeat_servo_value
from mavservo.sim.autopilot.motion_scripts import (
    SURFACE_MAX,
    SURFACE_MIN,
    SURFACE_TRIM,
    THROTTLE_CHANNEL,
    THROTTLE_MAX,
    THROTTLE_MIN,
    Profile,
)


class ServoOutputs:
    """The output frame at a time; commands mirrored into it when the autopilot would."""

    def __init__(self, profile: Profile, servo_trim: int = 1500, mirror: bool = True) -> None:
        self.profile = profile
        self.servo_trim = servo_trim
        #: a DO_SET_SERVO/DO_REPEAT_SERVO shows in the outputs (as on ArduPilot)
        self.mirror = mirror
        self._overrides: dict[int, int] = {}
        self._repeats: dict[int, tuple[RepeatServo, float]] = {}
        self._last: tuple[int, ...] | None = None

    def set_servo(self, channel: int, pwm: int) -> None:
        """DO_SET_SERVO: ``channel`` holds ``pwm`` (a repeat on it ends)."""
        self._repeats.pop(channel, None)
        if self.mirror:
            self._overrides[channel] = pwm

    def repeat_servo(self, action: RepeatServo, now: float) -> None:
        """DO_REPEAT_SERVO from monotonic ``now``."""
        if self.mirror:
            self._repeats[action.channel] = (action, now)

    def frame(self, profile_t: float, now: float) -> tuple[int, ...]:
        """The 16 outputs: the profile at ``profile_t`` (stream seconds), commands at ``now``."""
        frame = list(self.profile.pwm(profile_t))
        for channel, pwm in self._overrides.items():
            frame[channel - 1] = pwm
        for channel, (action, started) in list(self._repeats.items()):
            pwm, finished = repeat_servo_value(action, now - started, self.servo_trim)
            frame[channel - 1] = pwm
            if finished:
                del self._repeats[channel]
                self._overrides[channel] = pwm
        return tuple(frame)

    def changes(self, frame: tuple[int, ...]) -> list[tuple[int, int]]:
        """(channel, pwm) of each output that differs from the last frame sent (all, at first);
        ``frame`` becomes the last one."""
        previous = self._last
        changed = [
            (channel, pwm)
            for channel, pwm in enumerate(frame, start=1)
            if previous is None or previous[channel - 1] != pwm
        ]
        self._last = frame
        return changed


def normalized_outputs(frame: tuple[int, ...]) -> tuple[list[float], int]:
    """PX4-style ACTUATOR_OUTPUT_STATUS content for a PWM frame: values in [-1, 1], active mask.

    Surfaces map 1100..1900 to -1..1 around 1500 and throttle 1000..2000 to -1..1 (the config's
    ``source: actuator`` input is normalized); channels reading 0 (no pulse) are inactive and NaN.
    """
    values = [math.nan] * 32
    active = 0
    for index, pwm in enumerate(frame):
        if pwm == 0:
            continue
        if index == THROTTLE_CHANNEL - 1:
            value = (pwm - THROTTLE_MIN) / (THROTTLE_MAX - THROTTLE_MIN) * 2.0 - 1.0
        else:
            value = (pwm - SURFACE_TRIM) / ((SURFACE_MAX - SURFACE_MIN) / 2.0)
        values[index] = max(-1.0, min(1.0, value))
        active |= 1 << index
    return values, active
