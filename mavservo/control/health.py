"""Servo health the bridge sees itself: what a servo was told against what it measures.

A servo reports what it knows about itself (an error word, a health byte, sometimes nothing). A
surface jammed by ice, a slipped horn, a winding cooking at stall current or a sagging supply
often trips none of that, and only the bridge sees both the command and the measurement. This
module is the judgement, per servo, as a pure core: it is fed the decoded states the scheduler
already has and the setpoints the backend already sends, takes time as an argument, does no I/O
and keeps no clock (like the scheduler's core and the mapping). The bridge wires its events to
telemetry, STATUSTEXT, gimbal failure flags and the run records (``docs/health.md``).

Each check is a condition with an onset delay and a clearing hysteresis, so one episode gives
exactly one onset event and one clearing event, and a condition that flickers does not flood
the crew (onset texts of one check are also spaced by ``text_interval_s``; an episode inside
that spacing is counted, not announced, and the next text says how many there were).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Literal

from mavservo.mavlink import NO_HEALTH_PROBLEM, Health

TemperatureAction = Literal["warn", "slow", "hold", "release"]

#: the checks in the order their texts name them
CHECKS: tuple[Health, ...] = tuple(Health)

#: the velocity estimate from positions needs samples at least this far apart (whole-degree
#: positions, as an RMD-X status reply carries, make a shorter difference mostly noise)
MIN_DERIVATIVE_SPAN_S = 0.2
#: and looks back no further than this
MAX_DERIVATIVE_SPAN_S = 0.6
#: a gap between two samples longer than this (an outage) is not integrated as one step
MAX_SAMPLE_GAP_S = 0.5
#: I^2 t is counted with currents up to this (a reading beyond is garbage or a short), so no
#: reading can make it overflow
MAX_CURRENT_A = 1000.0
#: the commanded trajectory (:meth:`ServoHealth.command`) is kept this far back from the newest
#: command: a state judged up to this old still finds the setpoints of its time
TRAJECTORY_KEEP_S = 3.0
#: slipping: the output moves at less than this fraction of the motor's reported speed
SLIP_RATIO = 0.25
#: a supply range learned from the first readings (none configured): down to this fraction
#: of them. A servo fed straight from a lithium pack sees it fall from 4.2 V a cell (full, as
#: at take-off) to 3.3 V (loaded, near empty): 21 % in a normal flight, which a +-15 % band
#: called a supply fault (a 4S pack at 14.2 V, 3.55 V a cell). Below this it is one.
LEARNED_SUPPLY_LOW = 0.78
#: and up to this fraction (a supply above its first readings has no such normal cause)
LEARNED_SUPPLY_HIGH = 1.15


@dataclass(frozen=True)
class HealthLimits:
    """The thresholds of one servo (``servos[].health`` in the YAML; defaults derived from the
    servo's speed limit, slew, telemetry rate and physics by
    ``mavservo.control.health_thresholds``).
    Angles in deg, speeds in deg/s, currents in A, temperatures in degC, times in s."""

    tolerance_deg: float = 3.0
    """Tracking error that always counts as "where it was told" (sensor resolution, backlash)."""
    speed_dps: float = 360.0
    """How fast the servo is expected to move toward a new setpoint (speed limit, slew)."""
    response_s: float = 0.5
    """How long a healthy servo lags its setpoint: acceleration, loop settling, telemetry age.
    The setpoint's own motion over this time is added to the tolerance."""
    tracking_s: float = 0.5
    """Grace after the time the commanded move needs, before "not following" is said."""
    stopped_dps: float = 5.0
    """Slower than this is "not moving"."""
    jam_current_a: float = 2.8
    """Current at which a servo that is told to move and does not is blocked (near its limit)."""
    jam_s: float = 0.3
    slip_speed_dps: float = 30.0
    """Motor speed above which an output that does not follow is slipping."""
    slip_s: float = 0.5
    continuous_current_a: float = 2.0
    """The current the servo can carry indefinitely (I^2 t counts only what is above it)."""
    overload_s: float = 10.0
    """The I^2 t budget: this long at sqrt(2) times the continuous current."""
    temperature_warning_c: float = 65.0
    temperature_limit_c: float = 75.0
    temperature_hysteresis_c: float = 5.0
    temperature_action: TemperatureAction = "warn"
    """What the bridge does at the limit: warn only, slow (lower the speed limit), hold (keep
    the present position, refuse new setpoints), release (motor off)."""
    slow_factor: float = 0.5
    """``slow``: the fraction of the speed limit left."""
    supply_min_v: float | None = None
    supply_max_v: float | None = None
    """Supply range; None: learned around the first readings (``supply_learn_s``), -22 % / +15 %."""
    supply_s: float = 0.5
    supply_learn_s: float = 2.0
    clear_s: float = 1.0
    """A condition must be gone this long before its fault clears."""
    text_interval_s: float = 10.0
    """Least time between two onset texts of one check of one servo."""
    enabled: bool = True


@dataclass(frozen=True)
class Sample:
    """One decoded state of a servo with the setpoint in force when it came (None: none, e.g.
    released). NaN fields are what the family does not report; a check that needs one skips."""

    t: float
    setpoint_deg: float | None
    position_deg: float
    velocity_dps: float
    current_a: float
    temperature_c: float
    voltage_v: float | None = None


@dataclass(frozen=True)
class HealthEvent:
    """One transition of one check: ``active`` True at onset, False when it cleared.

    ``text`` is what the crew reads (STATUSTEXT, console); ``announce`` is False for an onset
    inside ``text_interval_s`` of the last text of its check, and for the clearing of such an
    episode (recorded, not said); ``figures`` are the numbers in the text, for the records."""

    servo: str
    check: Health
    active: bool
    t: float
    text: str
    announce: bool = True
    figures: dict[str, float] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return check_name(self.check)


def check_name(check: Health) -> str:
    """``jammed``, ``tracking``...: the name a check has in texts, records and the YAML."""
    return (check.name or str(check.value)).lower()


def finite(value: float | None) -> bool:
    return value is not None and math.isfinite(value)


class _Debounce:
    """A condition that must hold ``on_s`` to start an episode and be gone ``off_s`` to end it."""

    def __init__(self) -> None:
        self.active = False
        self.since: float | None = None  # condition true since (inactive) / false since (active)

    def update(self, condition: bool, t: float, on_s: float, off_s: float) -> bool | None:
        """True at onset, False at clearing, None when nothing changed."""
        if condition != self.active:
            if self.since is None:
                self.since = t
            if t - self.since >= (on_s if condition else off_s):
                self.active = condition
                self.since = None
                return condition
            return None
        self.since = None
        return None

    def reset(self) -> None:
        """Forget a condition on its way in (an active episode stays until it clears)."""
        if not self.active:
            self.since = None


class ServoHealth:
    """The health judgement of one servo. Feed it :meth:`update` with each new state."""

    def __init__(self, name: str, limits: HealthLimits) -> None:
        self.name = name
        self.limits = limits
        self._debounce = {check: _Debounce() for check in CHECKS}
        self._last: Sample | None = None
        #: (t, setpoint) within ``response_s``: how far the setpoint moved lately
        self._setpoints: deque[tuple[float, float]] = deque()
        #: (t, position, reported velocity) for the velocity from positions
        self._motion: deque[tuple[float, float, float]] = deque()
        #: (t, setpoint) as commanded, stamped with the bridge's clock when it was in force
        #: (:meth:`command`); None while nobody tells the commanded trajectory (the setpoints
        #: seen with the states are used then)
        self._trajectory: deque[tuple[float, float]] | None = None
        self._late_since: float | None = None
        self._late_budget_s = 0.0
        self._late_setpoint: float | None = None
        self._settled_at: float | None = None  # setpoint of the last time it was on target
        self._i2t = 0.0
        self._supply_readings: list[float] = []
        self._supply_range: tuple[float, float] | None = None
        self._supply_learn_until: float | None = None
        self.set_limits(limits)
        self._last_text: dict[Health, float] = {}
        self._unsaid: dict[Health, int] = {}
        self._announced: dict[Health, bool] = {}
        self._onset: dict[Health, float] = {}
        self.episodes: dict[str, int] = {}
        self.judged = 0
        """States judged so far (a quiet run that judged nothing proves nothing)."""

    def set_limits(self, limits: HealthLimits) -> None:
        """Thresholds in force from the next state (a learned supply range is kept unless the
        new limits give one)."""
        self.limits = limits
        if limits.supply_min_v is not None or limits.supply_max_v is not None:
            self._supply_range = (
                limits.supply_min_v if limits.supply_min_v is not None else -math.inf,
                limits.supply_max_v if limits.supply_max_v is not None else math.inf,
            )

    # ------------------------------------------------------------------ views

    @property
    def active(self) -> Health:
        flags = NO_HEALTH_PROBLEM
        for check, debounce in self._debounce.items():
            if debounce.active:
                flags |= check
        return flags

    @property
    def supply_range(self) -> tuple[float, float] | None:
        """The supply range in force (configured, or learned once enough readings came)."""
        return self._supply_range

    # ------------------------------------------------------------------ input

    def offline(self) -> None:
        """The servo stopped answering: no judgement on old data; episodes on their way in are
        forgotten, active ones stay until the servo is back and the condition is gone."""
        for debounce in self._debounce.values():
            debounce.reset()
        self._last = None
        self._motion.clear()
        self._late_since = None

    def command(self, t: float, setpoint_deg: float | None) -> None:
        """The setpoint in force at ``t``, on the clock the states are stamped with (the
        bridge calls this every tick, before it judges the new states).

        Why: a state is judged against the trajectory commanded up to its own time stamp, not
        against the setpoints that happened to be in force when states came in. On a loaded
        machine states come late and in bunches, the setpoint has moved on by then, and the
        setpoints seen with the states had the wrong times: a DroneCAN servo following a
        sweep was judged "not following, 16.7 deg behind" (issue 37). With the commanded
        trajectory the allowance is the setpoint's motion from ``response_s`` before the
        state was measured up to the newest command, whatever the state's age."""
        if self._trajectory is None:
            self._trajectory = deque()
        trajectory = self._trajectory
        if setpoint_deg is None or not math.isfinite(setpoint_deg):
            trajectory.clear()
            return
        if not trajectory or trajectory[-1][1] != setpoint_deg:
            trajectory.append((t, setpoint_deg))
        while len(trajectory) > 1 and trajectory[1][0] <= t - TRAJECTORY_KEEP_S:
            trajectory.popleft()

    def update(self, sample: Sample) -> list[HealthEvent]:
        """Judge a new state; the transitions it causes (usually none)."""
        if not self.limits.enabled:
            return []
        last = self._last
        if last is not None and sample.t <= last.t:
            return []  # the same state again (or out of order): nothing new to judge
        dt = 0.0 if last is None else min(sample.t - last.t, MAX_SAMPLE_GAP_S)
        self._last = sample
        self.judged += 1
        self._remember(sample)
        conditions = self._conditions(sample, dt)
        events: list[HealthEvent] = []
        lim = self.limits
        on_off = {
            Health.TRACKING: (0.0, lim.clear_s),  # its own timing decides the onset
            Health.JAMMED: (lim.jam_s, lim.clear_s),
            Health.SLIPPING: (lim.slip_s, lim.clear_s),
            Health.OVERLOAD: (0.0, 0.0),  # the I^2 t budget is its own hysteresis
            Health.HOT: (0.0, lim.clear_s),
            Health.OVERHEATED: (0.0, lim.clear_s),
            Health.SUPPLY: (lim.supply_s, lim.clear_s),
        }
        for check in CHECKS:
            condition = conditions.get(check)
            if condition is None:
                continue
            on_s, off_s = on_off[check]
            change = self._debounce[check].update(condition, sample.t, on_s, off_s)
            if change is not None:
                events.append(self._event(check, change, sample))
        return events

    # ------------------------------------------------------------------ the checks

    def _remember(self, s: Sample) -> None:
        window = self.limits.response_s
        if finite(s.setpoint_deg):
            assert s.setpoint_deg is not None
            self._setpoints.append((s.t, s.setpoint_deg))
        else:
            self._setpoints.clear()
        while len(self._setpoints) > 1 and self._setpoints[1][0] <= s.t - window:
            self._setpoints.popleft()
        if finite(s.position_deg):
            self._motion.append((s.t, s.position_deg, s.velocity_dps))
        while self._motion and self._motion[0][0] < s.t - MAX_DERIVATIVE_SPAN_S:
            self._motion.popleft()

    def _recent_setpoint_motion(self, setpoint: float, t: float | None = None) -> float:
        """How far the setpoint moved within the last ``response_s``: the lag a healthy servo
        may have on top of the tolerance (a sweep is followed a little behind). With the
        commanded trajectory (:meth:`command`) and the state's time ``t``: from the setpoint in
        force ``response_s`` before ``t`` to the newest command."""
        trajectory = self._trajectory
        if trajectory and t is not None:
            start = t - self.limits.response_s
            since = [sp for when, sp in trajectory if when > start]
            before = [sp for when, sp in trajectory if when <= start][-1:]
            return max((abs(setpoint - old) for old in before + since), default=0.0)
        return max((abs(setpoint - old) for _, old in self._setpoints), default=0.0)

    def _speeds(self, t: float) -> tuple[float | None, float | None]:
        """(output speed from positions, mean reported speed) over the recent window; None when
        the window is too short or nothing was reported."""
        if not self._motion or t - self._motion[0][0] < MIN_DERIVATIVE_SPAN_S:
            return None, None
        t0, p0, _ = self._motion[0]
        _, p1, _ = self._motion[-1]
        output = (p1 - p0) / (t - t0)
        reported = [v for _, _, v in self._motion if math.isfinite(v)]
        motor = sum(reported) / len(reported) if reported else None
        return output, motor

    def _conditions(self, s: Sample, dt: float) -> dict[Health, bool]:
        lim = self.limits
        out: dict[Health, bool] = {}
        output_dps, motor_dps = self._speeds(s.t)
        speed = s.velocity_dps if finite(s.velocity_dps) else output_dps
        error: float | None = None
        off_target = False
        if finite(s.setpoint_deg) and finite(s.position_deg):
            assert s.setpoint_deg is not None
            error = s.setpoint_deg - s.position_deg
            allowance = lim.tolerance_deg + self._recent_setpoint_motion(s.setpoint_deg, s.t)
            off_target = abs(error) > allowance
            if abs(error) <= lim.tolerance_deg:
                self._settled_at = s.setpoint_deg
            elif self._settled_at is not None and abs(self._settled_at - s.setpoint_deg) > 1e-6:
                self._settled_at = None  # told to go elsewhere since it was on target
        else:
            self._settled_at = None

        # slipping: the motor turns and the output does not follow, or the output moves on its
        # own while the setpoint stands still and the servo had reached it (back-driven)
        slipping = False
        if output_dps is not None and motor_dps is not None:
            slipping = abs(motor_dps) > lim.slip_speed_dps and abs(output_dps) < SLIP_RATIO * abs(
                motor_dps
            )
        if (
            not slipping
            and output_dps is not None
            and error is not None
            and self._settled_at is not None
            and abs(error) > lim.tolerance_deg
            and self._recent_setpoint_motion(s.setpoint_deg or 0.0) == 0.0
            and abs(output_dps) > lim.stopped_dps
            and output_dps * error < 0  # moving away from where it is held
        ):
            slipping = True
        if output_dps is not None:
            out[Health.SLIPPING] = slipping

        # jammed: told to be elsewhere, not moving, current near its limit (the current is the
        # evidence, so the plain tolerance will do: a healthy move at that current is moving)
        if error is not None and finite(s.current_a) and speed is not None and finite(speed):
            out[Health.JAMMED] = (
                abs(error) > lim.tolerance_deg
                and abs(speed) < lim.stopped_dps
                and abs(s.current_a) >= lim.jam_current_a
            )
        elif not finite(s.setpoint_deg):
            out[Health.JAMMED] = False  # released: told nothing, so blocked from nothing
        if error is not None:
            explained = bool(self.active & (Health.JAMMED | Health.SLIPPING))
            out[Health.TRACKING] = self._late(s, error, off_target and not explained)
        elif not finite(s.setpoint_deg):
            out[Health.TRACKING] = False
            self._late_since = None

        if finite(s.current_a):
            ic2 = lim.continuous_current_a**2
            amps = min(abs(s.current_a), MAX_CURRENT_A)  # a garbage reading cannot overflow
            budget = ic2 * lim.overload_s
            # counted up to the budget: an overload clears half a budget after the current
            # drops, however long it lasted (like a winding that cannot get hotter than hot)
            self._i2t = min(budget, max(0.0, self._i2t + (amps**2 - ic2) * dt))
            was = self._debounce[Health.OVERLOAD].active
            out[Health.OVERLOAD] = self._i2t >= (0.5 * budget if was else budget)

        if finite(s.temperature_c):
            for check, level in (
                (Health.HOT, lim.temperature_warning_c),
                (Health.OVERHEATED, lim.temperature_limit_c),
            ):
                was = self._debounce[check].active
                threshold = level - lim.temperature_hysteresis_c if was else level
                out[check] = s.temperature_c >= threshold

        if finite(s.voltage_v):
            assert s.voltage_v is not None
            supply = self._supply(s.t, s.voltage_v)
            if supply is not None:
                out[Health.SUPPLY] = supply
        return out

    def _late(self, s: Sample, error: float, off_target: bool) -> bool:
        """Tracking: off target for longer than the move it was told to make needs.

        When the error first exceeds its allowance, the servo is given the time to cover that
        error at ``speed_dps``, plus ``tracking_s``; every later setpoint change adds the time
        to cover it. A sweep the servo follows a little behind never starts an episode (its lag
        is inside the allowance); a jammed servo's error grows until the budget is spent."""
        lim = self.limits
        assert s.setpoint_deg is not None
        if not off_target:
            self._late_since = None
            return False
        speed = max(self._expected_speed(), 1e-6)
        if self._late_since is None:
            self._late_since = s.t
            self._late_budget_s = abs(error) / speed + lim.tracking_s
            self._late_setpoint = s.setpoint_deg
        elif self._late_setpoint is not None:
            self._late_budget_s += abs(s.setpoint_deg - self._late_setpoint) / speed
            self._late_setpoint = s.setpoint_deg
        return s.t - self._late_since > self._late_budget_s

    def _expected_speed(self) -> float:
        """``speed_dps``, lowered by ``slow_factor`` while the temperature limit's ``slow``
        action is in force (the bridge slews the servo's moves to that fraction: judging them
        at the full speed would call the servo late for the bridge's own action)."""
        lim = self.limits
        slowed = lim.temperature_action == "slow" and self._debounce[Health.OVERHEATED].active
        return lim.speed_dps * lim.slow_factor if slowed else lim.speed_dps

    def _supply(self, t: float, volts: float) -> bool | None:
        lim = self.limits
        if self._supply_range is None:
            if self._supply_learn_until is None:
                self._supply_learn_until = t + lim.supply_learn_s
            self._supply_readings.append(volts)
            if t < self._supply_learn_until:
                return None
            nominal = sorted(self._supply_readings)[len(self._supply_readings) // 2]
            self._supply_range = (LEARNED_SUPPLY_LOW * nominal, LEARNED_SUPPLY_HIGH * nominal)
            self._supply_readings.clear()
        low, high = self._supply_range
        margin = 0.02 * max(abs(low), abs(high)) if math.isfinite(high) else 0.02 * abs(low)
        if self._debounce[Health.SUPPLY].active:
            return not low + margin <= volts <= high - margin
        return not low <= volts <= high

    # ------------------------------------------------------------------ events

    def _event(self, check: Health, active: bool, s: Sample) -> HealthEvent:
        name = check_name(check)
        if active:
            self._onset[check] = s.t
            self.episodes[name] = self.episodes.get(name, 0) + 1
            last = self._last_text.get(check)
            announce = last is None or s.t - last >= self.limits.text_interval_s
            self._announced[check] = announce
            figures = self._figures(check, s)
            text = self._onset_text(check, s, figures)
            if announce:
                self._last_text[check] = s.t
                unsaid = self._unsaid.pop(check, 0)
                if unsaid:
                    text += f" ({unsaid} more since the last report)"
            else:
                self._unsaid[check] = self._unsaid.get(check, 0) + 1
            return HealthEvent(self.name, check, True, s.t, text, announce, figures)
        lasted = s.t - self._onset.pop(check, s.t)
        text = f"{self.name}: {_CLEARED[check]} after {lasted:.1f} s"
        announce = self._announced.pop(check, True)
        return HealthEvent(self.name, check, False, s.t, text, announce, {"lasted_s": lasted})

    def _figures(self, check: Health, s: Sample) -> dict[str, float]:
        figures: dict[str, float] = {}
        if finite(s.setpoint_deg) and finite(s.position_deg):
            assert s.setpoint_deg is not None
            figures["error_deg"] = abs(s.setpoint_deg - s.position_deg)
        for key, value in (
            ("position_deg", s.position_deg),
            ("velocity_dps", s.velocity_dps),
            ("current_a", s.current_a),
            ("temperature_c", s.temperature_c),
            ("voltage_v", s.voltage_v),
        ):
            if finite(value):
                assert value is not None
                figures[key] = value
        if check is Health.TRACKING and self._late_since is not None:
            figures["for_s"] = s.t - self._late_since
        elif check in (Health.JAMMED, Health.SLIPPING):
            figures["for_s"] = self._pending_for(check)
        output, motor = self._speeds(s.t)
        if output is not None:
            figures["output_dps"] = output
        if motor is not None:
            figures["motor_dps"] = motor
        return figures

    def _pending_for(self, check: Health) -> float:
        return {Health.JAMMED: self.limits.jam_s, Health.SLIPPING: self.limits.slip_s}[check]

    def _onset_text(self, check: Health, s: Sample, f: dict[str, float]) -> str:
        lim = self.limits
        amps = f" at {_shown(abs(f['current_a']), 1)} A" if "current_a" in f else ""
        behind = _shown(f.get("error_deg", math.nan), 1)
        if check is Health.TRACKING:
            lasted = _shown(f.get("for_s", 0.0), 1)
            what = f"not following, {behind} deg behind for {lasted} s{amps}"
        elif check is Health.JAMMED:
            where = _shown(f.get("position_deg", math.nan), 1)
            what = f"jammed at {where} deg, {behind} deg short{amps}"
        elif check is Health.SLIPPING:
            motor = _shown(abs(f.get("motor_dps", math.nan)), 0)
            output = _shown(abs(f.get("output_dps", math.nan)), 0)
            what = f"slipping, motor {motor} deg/s, output {output} deg/s{amps}"
        elif check is Health.OVERLOAD:
            what = (
                f"overloaded, {_shown(abs(f.get('current_a', math.nan)), 1)} A, I2t budget of "
                f"{_shown(lim.continuous_current_a, 1)} A continuous spent"
            )
        elif check is Health.HOT:
            what = (
                f"hot, {_shown(s.temperature_c, 0)} C "
                f"(warning {_shown(lim.temperature_warning_c, 0)} C)"
            )
        elif check is Health.OVERHEATED:
            what = (
                f"overheated, {_shown(s.temperature_c, 0)} C "
                f"(limit {_shown(lim.temperature_limit_c, 0)} C): "
                f"{_ACTION_TEXT[lim.temperature_action]}"
            )
        else:
            low, high = self._supply_range or (math.nan, math.nan)
            volts = _shown(f.get("voltage_v", math.nan), 1)
            what = f"supply {volts} V outside {_shown(low, 1)}-{_shown(high, 1)} V"
        return f"{self.name}: {what}"


def _shown(value: float, decimals: int) -> str:
    """A figure for a text: fixed-point up to a million, three significant digits beyond (a
    lying reply's 1e38 A or deg would otherwise be a 40-digit number, and a STATUSTEXT of it
    several chunks long)."""
    if math.isfinite(value) and abs(value) >= 1e6:
        return f"{value:.3g}"
    return f"{value:.{decimals}f}"


_CLEARED = {
    Health.TRACKING: "following again",
    Health.JAMMED: "moving again",
    Health.SLIPPING: "no longer slipping",
    Health.OVERLOAD: "overload over",
    Health.HOT: "temperature back below warning",
    Health.OVERHEATED: "temperature back below limit",
    Health.SUPPLY: "supply back in range",
}

_ACTION_TEXT: dict[str, str] = {
    "warn": "warning only",
    "slow": "speed limit lowered",
    "hold": "holding, new setpoints refused",
    "release": "released (motor off)",
}
