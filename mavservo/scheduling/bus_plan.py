"""What each servo of one bus costs on the wire, planned once when its schedule is built.

Why apart from :class:`~mavservo.scheduling.schedule_core.ScheduleCore`: the plan is arithmetic
on the configuration (poll and push periods, the bus time of a poll and of a command, the
worst-case load R of paper eq. 4, the phase of the telemetry tick) that never changes while the
bus runs; the core is the state machine that runs on it. Pure: no clock, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import can

from mavservo.servos import node_reports_of

from .busload import (
    FrameFlow,
    ServoTraffic,
    frame_time,
    load_ratio,
    message_bits,
    servo_traffic,
    worst_case_load,
)

if TYPE_CHECKING:
    from .schedule_core import ServoSpec, TimingConfig

REPLY_DLC = 8
"""The data length a reply is costed at: the worst case, whatever the profile answers."""


@dataclass(frozen=True)
class ServoCosts:
    """One servo's planned periods (None: not polled / not pushing) and bus times."""

    poll_period: float | None
    poll_cost_s: float
    command_cost_s: float
    push_period: float | None


@dataclass(frozen=True)
class BusPlan:
    """The plan of one bus: per-servo costs, the worst-case load, the telemetry tick's phase
    and what the configuration will not do as said (warnings, in the order found)."""

    servos: Mapping[str, ServoCosts]
    worst_case_load: float
    servo_loads: Mapping[str, float]
    """Each servo's own share of the worst-case load (named when the bus is over budget)."""
    telemetry_phase_s: float
    warnings: tuple[str, ...]

    def over_budget(self, timing: TimingConfig) -> str | None:
        """Why the bus cannot run this plan (its worst case over ``max_load``, naming the
        heaviest servos and what to change); None when it fits."""
        if self.worst_case_load <= timing.max_load:
            return None
        heaviest = sorted(self.servo_loads.items(), key=lambda kv: -kv[1])[:3]
        detail = ", ".join(f"{name} {share:.1%}" for name, share in heaviest)
        return (
            f"worst-case bus load R = {self.worst_case_load:.1%} exceeds max_load "
            f"{timing.max_load:.1%} at {timing.bitrate} bit/s with {len(self.servos)} servos "
            f"(heaviest: {detail}); lower telemetry_hz, lengthen command_period_s or "
            "immediate_min_spacing_s, or raise the bitrate"
        )


def plan_bus(
    servos: Sequence[ServoSpec],
    timing: TimingConfig,
    *,
    startup_retry_s: float,
    packed: frozenset[str] = frozenset(),
    extra_flows: Sequence[FrameFlow] = (),
) -> BusPlan:
    """The plan of ``servos`` under ``timing``; ``packed`` servos' commands are counted by a bus
    node's ``extra_flows`` (DroneCAN) instead of one frame each, start-up frames at
    ``1 / startup_retry_s``."""
    warnings: list[str] = []
    traffic = {
        spec.name: _traffic(spec, timing, packed, startup_retry_s, warnings=None) for spec in servos
    }
    load = worst_case_load(traffic.values(), timing.bitrate)
    load += load_ratio(tuple(extra_flows), timing.bitrate)
    servo_loads = {name: worst_case_load([t], timing.bitrate) for name, t in traffic.items()}
    costs = {
        spec.name: ServoCosts(
            poll_period=_poll_period(spec, timing, warnings),
            poll_cost_s=_poll_cost(spec, timing),
            command_cost_s=_command_cost(spec, timing),
            push_period=_push_period(spec, timing),
        )
        for spec in servos
    }
    phase = (
        _automatic_phase(costs.values(), timing)
        if timing.telemetry_phase_s is None
        else timing.telemetry_phase_s
    )
    _check_polls_fit(costs.values(), timing, warnings)
    return BusPlan(costs, load, servo_loads, phase, tuple(warnings))


def _poll_period(spec: ServoSpec, timing: TimingConfig, warnings: list[str] | None) -> float | None:
    if not spec.profile.telemetry_requests():
        return None
    hz = spec.telemetry_hz
    if hz is None:
        hz = 1 / timing.telemetry_period_s
    if hz == 0:
        return None
    if hz > 1 / timing.telemetry_period_s * (1 + 1e-9) and warnings is not None:
        warnings.append(
            f"servo {spec.name!r}: telemetry_hz {hz:g} is faster than the telemetry tick "
            f"({1 / timing.telemetry_period_s:g} Hz); it will be polled at the tick rate"
        )
    return max(1 / hz, timing.telemetry_period_s)


def _push_period(spec: ServoSpec, timing: TimingConfig) -> float | None:
    """A pushing servo's report period: ``1 / telemetry_hz`` (default the telemetry tick, as
    the budget assumes); None for polled servos and for one configured to push nothing."""
    if spec.profile.telemetry_requests():
        return None
    reports = node_reports_of(spec.profile)
    if reports is not None and reports.heartbeat_period_s:
        return reports.heartbeat_period_s  # its own heartbeat says it is alive
    hz = spec.telemetry_hz
    if hz is None:
        return timing.telemetry_period_s
    return None if hz == 0 else 1 / hz


def _msg_shape(msg: can.Message) -> tuple[bool, int]:
    return bool(msg.is_extended_id), int(msg.dlc)


def _poll_cost(spec: ServoSpec, timing: TimingConfig) -> float:
    """Worst-case bus time one poll of this servo takes: requests plus their replies."""
    cost = 0.0
    bitrate = timing.bitrate
    for req in spec.profile.telemetry_requests():
        extended, dlc = _msg_shape(req)
        cost += frame_time(extended, dlc, bitrate, bool(req.is_remote_frame))
        replies = spec.profile.replies_per_request
        cost += replies * frame_time(extended, REPLY_DLC, bitrate)
    return cost


def _command_hz(spec: ServoSpec, timing: TimingConfig) -> float:
    """Worst-case commands per second: every slot, or back to back at the minimum spacing for
    ``immediate`` servos (slots honour that spacing too, so it is a true ceiling)."""
    hz = 1 / timing.command_period_s
    if spec.command_mode == "immediate":
        hz = max(hz, 1 / timing.immediate_min_spacing_s)
    return hz


def _traffic(
    spec: ServoSpec,
    timing: TimingConfig,
    packed: frozenset[str],
    startup_retry_s: float,
    *,
    warnings: list[str] | None,
) -> ServoTraffic:
    period = _poll_period(spec, timing, warnings)  # None: not polled
    return servo_traffic(
        spec.profile,
        command_hz=0.0 if spec.name in packed else _command_hz(spec, timing),
        poll_hz=0.0 if period is None else 1 / period,
        # a push-style servo sends status on its own at its telemetry_hz
        status_hz=(
            1 / timing.telemetry_period_s if spec.telemetry_hz is None else spec.telemetry_hz
        ),
        max_speed_dps=spec.max_speed_dps,
        startup_hz=1 / startup_retry_s,
    )


def _command_cost(spec: ServoSpec, timing: TimingConfig) -> float:
    """Worst-case bus time of one command to this servo and the replies it provokes."""
    command = spec.profile.position_command(0.0, spec.max_speed_dps)
    replies = spec.profile.replies_per_command
    bitrate = timing.bitrate
    return message_bits(command) / bitrate + replies * frame_time(
        bool(command.is_extended_id), REPLY_DLC, bitrate
    )


def _automatic_phase(costs: Iterable[ServoCosts], timing: TimingConfig) -> float:
    """The tick phase farthest, in bus time, from both neighbouring command bursts.

    Relative to a slot, ticks only ever fall at ``phase mod g + j * g`` with
    ``g = gcd(T_c, T_t)`` (computed on whole microseconds), so it is enough to keep
    ``[phase mod g, + poll burst + guard]`` clear of ``[0, command burst]`` and of the next
    multiple of ``g``: the phase is the middle of the gap between the end of a slot's command
    burst and the latest start that lets a full poll round end ``command_guard_s`` before the
    next slot. When the bursts do not fit in ``g`` there is no clear phase; the ticks go right
    after the command burst, and the suspension rule defers what does not fit to after the next
    slot's commands.
    """
    servos = list(costs)
    g = math.gcd(round(timing.command_period_s * 1e6), round(timing.telemetry_period_s * 1e6)) / 1e6
    command_burst = sum(c.command_cost_s for c in servos)
    poll_burst = sum(c.poll_cost_s for c in servos if c.poll_period)
    latest_start = g - timing.command_guard_s - poll_burst
    return (command_burst + max(0.0, latest_start - command_burst) / 2) % g


def _check_polls_fit(
    costs: Iterable[ServoCosts], timing: TimingConfig, warnings: list[str]
) -> None:
    """Say so at start-up when the configured poll rates cannot all fit between slots."""
    servos = list(costs)
    free_per_period = (
        timing.command_period_s - timing.command_guard_s - sum(c.command_cost_s for c in servos)
    )
    demand_per_period = sum(
        c.poll_cost_s * timing.command_period_s / c.poll_period for c in servos if c.poll_period
    )
    if free_per_period <= 0 or demand_per_period > free_per_period:
        warnings.append(
            f"telemetry cannot keep its rate: polls need {demand_per_period * 1e3:.2f} ms of "
            f"bus per {timing.command_period_s * 1e3:g} ms command period but only "
            f"{max(free_per_period, 0) * 1e3:.2f} ms is free; servos will be polled late "
            "(oldest first) and the achieved intervals will show it"
        )
