"""The servo commands: DO_SET_SERVO, DO_REPEAT_SERVO and DO_SET_ACTUATOR, checked and applied.

Why a part of its own: what these three commands mean (a PWM on a servo channel, a repeat that
alternates with the trim, up to six actuator values in a set) and the running repeats are state
and rules of their own; the command handler (``commands.CommandHandler``) decides who a command
is for, whether it is a retry, and ACKs it, whatever the command. This part sees only the
parameters, never the message, and answers an :class:`~.backend.ApplyResult` (or None: "not
ours", for a broadcast), so it is tested alone against a recording backend. Pure apart from
logging: time comes in as an argument.

Every parameter is validated before the first setpoint goes out; a refusal names its kind
(``bad_param``, ``unmapped``, ``cycle_too_short``) for the handler's counters.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

from mavservo.mavlink.arbitration import CommandHold
from mavservo.mavlink.backend import ActuatorBackend, ApplyResult, Outcome
from mavservo.mavlink.settings import MavlinkSettings

log = logging.getLogger(__name__)

MAV_CMD_DO_SET_SERVO = 183
MAV_CMD_DO_REPEAT_SERVO = 184
MAV_CMD_DO_SET_ACTUATOR = 187

INT32_MAX = 2**31 - 1
#: DO_SET_ACTUATOR in COMMAND_INT carries actuators 5 and 6 in x/y, scaled by 1e7 (spec).
COMMAND_INT_XY_SCALE = 1e7
#: Widest PWM any hobby servo protocol uses; narrower limits come from the channel mapping.
PWM_MIN_US = 500.0
PWM_MAX_US = 2500.0
#: A repeat longer than this is almost certainly a unit mix-up (ms read as s), so it is refused.
MAX_REPEAT_COUNT = 1000
MAX_REPEAT_CYCLE_S = 600.0
#: Shortest DO_REPEAT_SERVO half cycle whatever the scheduler's period: the MAVLink side's tick
#: (mavlink/side.py TICK_S, 10 ms) steps the repeats, so a shorter half cycle puts several
#: steps into one tick (a 1 ms cycle and count 1000 gave 2,000 setpoints at once).
MIN_REPEAT_HALF_CYCLE_S = 0.01
#: DO_SET_ACTUATOR carries six values; param 7 is the index of the set of six they belong to.
ACTUATORS_PER_SET = 6

#: A servo command's handler: (params, sent as COMMAND_INT, now, broadcast) -> its result, or
#: None for a broadcast that concerns nothing mapped.
ServoCommandHandler = Callable[[tuple[float, ...], bool, float, bool], ApplyResult | None]


@dataclass
class _RepeatJob:
    """A running DO_REPEAT_SERVO: alternate pwm and trim every half cycle, end on trim."""

    channel: int
    steps: list[tuple[float, float]]  # (due time, pwm), in order


class ServoCommands:
    """Carries out the three servo commands on the backend and claims their channels in
    ``hold`` (mirroring of the autopilot's stream stays off a commanded channel)."""

    def __init__(
        self, backend: ActuatorBackend, settings: MavlinkSettings, hold: CommandHold
    ) -> None:
        self.backend = backend
        self.settings = settings
        self.hold = hold
        self._repeats: dict[int, _RepeatJob] = {}
        #: command id -> its handler ``(params, is_int, now, broadcast) -> result``: the
        #: result, or None when a broadcast concerns nothing mapped (whoever owns it answers).
        #: A table built once, so dispatching costs one lookup and one call per command.
        self.handlers: dict[int, ServoCommandHandler] = {
            MAV_CMD_DO_SET_SERVO: self._do_set_servo,
            MAV_CMD_DO_REPEAT_SERVO: self._do_repeat_servo,
            MAV_CMD_DO_SET_ACTUATOR: self._do_set_actuator,
        }

    def tick(self, now: float) -> None:
        """Advance running DO_REPEAT_SERVO jobs."""
        for channel in list(self._repeats):
            job = self._repeats[channel]
            while job.steps and job.steps[0][0] <= now:
                _, pwm = job.steps.pop(0)
                result = self.backend.apply_servo_output(channel, pwm, "do_repeat_servo", now)
                self.hold.note_command(("servo", channel), now)
                log.debug("repeat servo %d -> %.0f us: %s", channel, pwm, result.outcome.name)
            if not job.steps:
                del self._repeats[channel]

    def min_repeat_cycle_s(self) -> float:
        """The shortest DO_REPEAT_SERVO cycle accepted: two half cycles, each at least one
        command period of the scheduler (a shorter one would be overwritten before its slot
        came, or, below the tick, several steps would go out at once) and one tick."""
        return 2.0 * max(self.settings.command_period_s, MIN_REPEAT_HALF_CYCLE_S)

    def repeating_channels(self) -> set[int]:
        return set(self._repeats)

    def cancel_all(self) -> None:
        """Stop every running repeat (failsafe: nothing moves until fresh commands)."""
        self._repeats.clear()

    def _servo_channel(
        self, params: tuple[float, ...], broadcast: bool
    ) -> int | ApplyResult | None:
        """Validated, mapped channel from param 1, or the refusal, or None (not ours)."""
        raw = params[0]
        if not is_int(raw) or raw < 1:
            return None if broadcast else denied("bad_param", f"servo instance {raw!r}")
        channel = int(raw)
        if channel not in self.backend.mapped_servo_channels():
            return None if broadcast else denied("unmapped", f"servo channel {channel}")
        return channel

    def _do_set_servo(
        self, params: tuple[float, ...], is_int_message: bool, now: float, broadcast: bool
    ) -> ApplyResult | None:
        channel = self._servo_channel(params, broadcast)
        if not isinstance(channel, int):
            return channel
        pwm = params[1]
        if not _valid_pwm(pwm):
            return denied("bad_param", f"PWM {pwm!r} outside {PWM_MIN_US:.0f}..{PWM_MAX_US:.0f}")
        self._repeats.pop(channel, None)
        result = self.backend.apply_servo_output(channel, pwm, "do_set_servo", now)
        if result.ok:
            self.hold.note_command(("servo", channel), now)
        return result

    def _do_repeat_servo(
        self, params: tuple[float, ...], is_int_message: bool, now: float, broadcast: bool
    ) -> ApplyResult | None:
        channel = self._servo_channel(params, broadcast)
        if not isinstance(channel, int):
            return channel
        pwm, count, cycle = params[1], params[2], params[3]
        if not _valid_pwm(pwm):
            return denied("bad_param", f"PWM {pwm!r}")
        if not is_int(count) or not 1 <= count <= MAX_REPEAT_COUNT:
            return denied("bad_param", f"repeat count {count!r}")
        if not math.isfinite(cycle) or cycle <= 0:
            return denied("bad_param", f"cycle time {cycle!r}")
        cycle_s = cycle / 1000.0 if self.settings.repeat_servo_cycle == "milliseconds" else cycle
        if cycle_s > MAX_REPEAT_CYCLE_S:
            return denied("bad_param", f"cycle time {cycle_s} s")
        shortest = self.min_repeat_cycle_s()
        if cycle_s < shortest:
            return denied(
                "cycle_too_short",
                f"cycle time {cycle_s:g} s < {shortest:g} s (two command periods: each half "
                "cycle needs a command slot of its own)",
            )
        result = self.backend.apply_servo_output(channel, pwm, "do_repeat_servo", now)
        if not result.ok:
            return result
        self.hold.note_command(("servo", channel), now)
        half = cycle_s / 2.0
        trim = self.settings.trim_us(channel)
        steps = [(now + k * half, trim if k % 2 else pwm) for k in range(1, 2 * int(count))]
        self._repeats[channel] = _RepeatJob(channel, steps)
        return result

    def _do_set_actuator(
        self, params: tuple[float, ...], is_int_message: bool, now: float, broadcast: bool
    ) -> ApplyResult | None:
        """Param 7 is the MAVLink spec's "index of actuator set (i.e. if set to 1, Actuator 1
        becomes Actuator 7)": set 0 carries actuators 1..6, the 1-based numbers that
        ``source: actuator`` channels map (PX4 acts on set 0 only)."""
        values = actuator_values(params, is_int_message)
        if values is None:
            return (
                None
                if broadcast
                else denied("bad_param", f"actuator set index (param 7) {params[6]!r}")
            )
        set_index = int(params[6])
        mapped = self.backend.mapped_actuator_indices()
        ours = {index: v for index, v in values.items() if index in mapped}
        if not ours:
            if broadcast:
                return None
            what = (
                "no actuator value given"
                if not values
                else f"unmapped actuators {sorted(values)} (set index {set_index})"
            )
            return denied("unmapped" if values else "bad_param", what)
        bad = {index: v for index, v in ours.items() if not -1.0 <= v <= 1.0}
        if bad:
            return denied("bad_param", f"actuator values outside [-1, 1]: {bad}")
        worst = ApplyResult(Outcome.ACCEPTED)
        for index, value in sorted(ours.items()):
            result = self.backend.apply_actuator(index, value, "do_set_actuator", now)
            if result.ok:
                self.hold.note_command(("actuator", index), now)
            elif worst.ok:
                worst = result
        return worst


def is_int(value: float) -> bool:
    return math.isfinite(value) and float(value).is_integer()


def actuator_values(params: tuple[float, ...], is_int_message: bool) -> dict[int, float] | None:
    """DO_SET_ACTUATOR's values by 1-based actuator number (NaN = leave alone, left out), or
    None when param 7, the actuator set index, is not a non-negative integer.

    COMMAND_INT x/y are integers: the spec scales actuators 5/6 by 1e7 there and uses
    INT32_MAX for "leave alone", since an integer cannot carry NaN."""
    set_index = params[6]
    if not is_int(set_index) or set_index < 0:
        return None
    first = int(set_index) * ACTUATORS_PER_SET + 1
    values: dict[int, float] = {}
    for i, raw in enumerate(params[:ACTUATORS_PER_SET]):
        value = raw
        if is_int_message and i >= 4:
            value = math.nan if raw == INT32_MAX else raw / COMMAND_INT_XY_SCALE
        if not math.isnan(value):
            values[first + i] = value
    return values


def _valid_pwm(value: float) -> bool:
    return math.isfinite(value) and PWM_MIN_US <= value <= PWM_MAX_US


def denied(kind: str, detail: str) -> ApplyResult:
    """A DENIED result whose reason starts with its kind (counted as ``reason_<kind>``)."""
    return ApplyResult(Outcome.DENIED, f"{kind}:{detail}")
