"""Scripted servo-output profiles: pure functions of time -> 16 PWM values.

A profile stands in for what ArduPilot's SERVO_OUTPUT_RAW would report while a pilot or a
mission moves the control surfaces. Each one is a pure, deterministic function of the time since
the stream started, so a test can ask "what did the autopilot command at t?" without having
recorded anything, and two runs with the same parameters produce the same sequence.

Channel numbering is 1-based like SERVOn; the returned tuple is indexed 0..15 (channel - 1).
Channels a profile does not drive read 0, which ArduPilot uses for "no pulse" (see the README of
the SITL recordings: servo9..16 read 0 until something drives them).
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable
from dataclasses import dataclass, field

N_CHANNELS = 16

# ArduPlane's stock output ranges: aileron/elevator/rudder 1100..1900 around 1500,
# throttle 1000..2000 idling at 1000 (as in tests/data/plane-servos.tlog).
SURFACE_CHANNELS = (1, 2, 4)
THROTTLE_CHANNEL = 3
SURFACE_MIN, SURFACE_TRIM, SURFACE_MAX = 1100, 1500, 1900
THROTTLE_MIN, THROTTLE_MAX = 1000, 2000

PwmFrame = tuple[int, ...]


def _frame(values: dict[int, float]) -> PwmFrame:
    """Build a 16-channel frame from {channel: pwm}, rounding to whole microseconds."""
    out = [0] * N_CHANNELS
    for channel, pwm in values.items():
        out[channel - 1] = int(round(pwm))
    return tuple(out)


class Profile:
    """Base class: ``pwm(t)`` is the whole contract. ``t`` is seconds since the stream started."""

    name = "base"

    def pwm(self, t: float) -> PwmFrame:
        raise NotImplementedError

    def channels(self) -> tuple[int, ...]:
        """1-based channels this profile drives (non-zero output)."""
        return (*SURFACE_CHANNELS, THROTTLE_CHANNEL)


@dataclass(frozen=True)
class HoldProfile(Profile):
    """Neutral outputs forever: surfaces at trim, throttle idle. The baseline for command tests."""

    values: tuple[tuple[int, int], ...] = (
        (1, SURFACE_TRIM),
        (2, SURFACE_TRIM),
        (3, THROTTLE_MIN),
        (4, SURFACE_TRIM),
    )
    name = "hold"

    def pwm(self, t: float) -> PwmFrame:
        return _frame(dict(self.values))

    def channels(self) -> tuple[int, ...]:
        return tuple(channel for channel, _ in self.values)


@dataclass(frozen=True)
class SweepProfile(Profile):
    """Control-surface sweeps shaped like the recorded ArduPlane session.

    Why these shapes: a linear chirp exercises the bridge's slew limiting and the scheduler's
    refresh at rising frequency, and the throttle raised cosine covers its full 1000..2000 range
    smoothly. servo4 mirrors servo1 so a sign error in a reversed mapping shows up at once.
    The pattern repeats every ``period_s``.
    """

    period_s: float = 24.0
    f0_hz: float = 0.10
    f1_hz: float = 0.733
    throttle_hz: float = 0.125
    name = "sweep"

    def _phase(self, tau: float) -> float:
        k = (self.f1_hz - self.f0_hz) / (2.0 * self.period_s)
        return 2.0 * math.pi * (self.f0_hz * tau + k * tau * tau)

    def pwm(self, t: float) -> PwmFrame:
        tau = max(t, 0.0) % self.period_s
        phi = self._phase(tau)
        half = (SURFACE_MAX - SURFACE_MIN) / 2.0
        throttle_half = (THROTTLE_MAX - THROTTLE_MIN) / 2.0
        return _frame(
            {
                1: SURFACE_TRIM + half * math.sin(phi),
                2: SURFACE_TRIM + half * math.sin(phi / 2.0),
                3: THROTTLE_MIN
                + throttle_half * (1.0 - math.cos(2.0 * math.pi * self.throttle_hz * tau)),
                4: SURFACE_TRIM - half * math.sin(phi),
            }
        )


@dataclass(frozen=True)
class StaircaseProfile(Profile):
    """The paper's multi-step experiment (Fig. 3): references raised step by step over a wide range.

    Surfaces climb from SERVOn_MIN to SERVOn_MAX in ``steps`` equal steps (for a +-30 deg mapping
    that is 7.5 deg a step with the default 8), each held ``hold_s`` so a servo at a few hundred
    deg/s has long settled before the next step; then everything returns to neutral for one hold
    and the staircase repeats. Throttle climbs its own range in step with the surfaces.
    """

    steps: int = 8
    hold_s: float = 2.0
    name = "staircase"

    @property
    def period_s(self) -> float:
        return (self.steps + 2) * self.hold_s

    def step_index(self, t: float) -> int:
        """0..steps = level on the staircase, steps+1 = back at neutral."""
        return int((max(t, 0.0) % self.period_s) // self.hold_s)

    def pwm(self, t: float) -> PwmFrame:
        i = self.step_index(t)
        if i > self.steps:
            return HoldProfile().pwm(t)
        frac = i / self.steps
        surface = SURFACE_MIN + frac * (SURFACE_MAX - SURFACE_MIN)
        throttle = THROTTLE_MIN + frac * (THROTTLE_MAX - THROTTLE_MIN)
        values: dict[int, float] = {channel: surface for channel in SURFACE_CHANNELS}
        values[THROTTLE_CHANNEL] = throttle
        return _frame(values)


@dataclass
class RandomWalkProfile(Profile):
    """A seeded random walk, changing every ``step_s``, clamped to each channel's range.

    Still a function of time: the walk is generated lazily from ``random.Random(seed)`` up to the
    step that ``t`` falls in and cached, so any query order gives the same values and the same
    seed always gives the same walk.
    """

    seed: int = 0
    step_s: float = 0.25
    max_step_us: int = 60
    name = "random-walk"
    _walk: list[PwmFrame] = field(default_factory=list, repr=False)
    _rng: random.Random | None = field(default=None, repr=False)

    def _extend_to(self, index: int) -> None:
        if self._rng is None:
            self._rng = random.Random(self.seed)
            self._walk.append(HoldProfile().pwm(0.0))
        while len(self._walk) <= index:
            last = list(self._walk[-1])
            for channel in (*SURFACE_CHANNELS, THROTTLE_CHANNEL):
                lo, hi = (
                    (THROTTLE_MIN, THROTTLE_MAX)
                    if channel == THROTTLE_CHANNEL
                    else (SURFACE_MIN, SURFACE_MAX)
                )
                step = self._rng.randint(-self.max_step_us, self.max_step_us)
                last[channel - 1] = min(hi, max(lo, last[channel - 1] + step))
            self._walk.append(tuple(last))

    def pwm(self, t: float) -> PwmFrame:
        index = int(max(t, 0.0) // self.step_s)
        self._extend_to(index)
        return self._walk[index]


PROFILES: dict[str, Callable[..., Profile]] = {
    "hold": HoldProfile,
    "sweep": SweepProfile,
    "staircase": StaircaseProfile,
    "steps": StaircaseProfile,  # the name mavservo/config.py uses for the same experiment
    "random-walk": RandomWalkProfile,
}


def get_profile(name: str, **params: object) -> Profile:
    """Build a profile by name; unknown names raise ``ValueError`` listing the valid ones."""
    try:
        factory = PROFILES[name]
    except KeyError:
        raise ValueError(f"unknown profile {name!r}; choose one of {sorted(PROFILES)}") from None
    return factory(**params)
