"""Simulated CAN servos: the device side of every profile, with physics and fault injection.

A :class:`SimServo` answers exactly what the real servo answers, at the same resolution (an RMD
status reply carries whole degrees, so even a perfect servo shows up to 0.5 deg of error), and
its telemetry moves the way a real one does: a position loop with speed and acceleration limits,
current that follows acceleration, friction and load, temperature that rises with current
squared and cools toward ambient, and a limp drift when no command has arrived for
``relax_after_s`` (what the scheduler's keep-alive refresh exists to prevent).

Mechanical faults the servo does not report itself, for the bridge's health monitor to find
(``simulation.servos.<name>.faults``): an obstruction (``jammed_at_deg``: the output stops there
and, while the position loop pushes against it, the current rises to ``stall_current_a``), a
slipped coupling (``slipping``: the motor turns, the output and its reported angle stay) and a
sagging supply (``supply_v``); heating under a held load is in the physics already
(``load_current``, ``heating_c_per_a2s``).

Nothing here reads a clock or does I/O: every call takes ``now`` (seconds, any monotonic base)
and the randomness (dropped replies, current noise) comes from a seeded generator, so a run is
reproducible. The simulated bus (:mod:`mavservo.sim.canbus`) and the adapter emulator decide
when "now" is.
"""

from __future__ import annotations

import math
import random
from typing import TYPE_CHECKING

import can

from ..config.simulation import Faults, Physics
from ..servos import ProfileOptions, get_profile, node_family
from ..servos.base import NO_FAULT, Fault, SimDevice

if TYPE_CHECKING:
    from ..config import Config

Reply = tuple[float, can.Message]
"""A frame the servo will put on the bus, and the earliest time it is ready to."""

_MAX_STEPS_PER_ADVANCE = 20_000
_STEP_S = 0.001


class SimServo:
    """One simulated servo speaking ``profile`` on ``can_id``: the motor (physics, faults, on or
    off) behind the profile's own simulated device (``sim_device``, from the registry).

    ``receive(msg, now)`` handles a frame seen on the bus and returns the replies it provokes;
    ``poll(now)`` returns status pushes that are due (push-style profiles only), and
    ``next_push_time()`` says when the next one is. Physics is integrated lazily up to each
    ``now``; times that go backwards are treated as "now" (no rewinding).
    """

    def __init__(
        self,
        profile: str,
        can_id: int,
        physics: Physics | None = None,
        faults: Faults | None = None,
        *,
        seed: int = 0,
        status_rate_hz: float = 50.0,
        reply_latency_s: float = 0.0002,
        options: ProfileOptions | None = None,
    ) -> None:
        profile_class = get_profile(profile)  # a clear error for unknown names
        self.profile = profile
        self.can_id = can_id
        self.physics = physics or Physics()
        self.faults = faults or Faults()
        self.reply_latency_s = reply_latency_s
        self.status_rate_hz = status_rate_hz
        self._rng = random.Random(seed)
        self.enabled = True
        """False after the device turned the motor off (release, its own timeout): it coasts."""
        self.zero_offset_deg = 0.0
        self.options = options if options is not None else profile_class.Options()
        self._device = profile_class.sim_device(self, can_id, self.options)

        self.time: float | None = None
        self.position_deg = self.physics.initial_position_deg
        self.velocity_dps = 0.0
        self.accel_dps2 = 0.0
        self.temperature_c = self.physics.ambient_c
        self.target_deg = self.position_deg
        self.speed_limit_dps = self.physics.max_speed_dps
        self.accel_limit_dps2 = self.physics.max_accel_dps2
        self.last_command_time: float | None = None
        self._next_push: float | None = None
        self.motor_position_deg = self.position_deg
        """Where the motor shaft is: the output's angle unless the coupling slips."""
        self.blocked = False
        """True while the output rests on the obstruction and the loop pushes into it."""
        self._jam_side = 0.0

        self.commands = 0
        self.requests = 0
        self.replies = 0
        self.replies_dropped = 0

    # -- physics ---------------------------------------------------------------------------

    @property
    def voltage_v(self) -> float:
        """Supply voltage the servo measures (an injected sag replaces the nominal one)."""
        sag = self.faults.supply_v
        return self.physics.voltage_v if sag is None else float(sag)

    def enable(self, now: float) -> None:
        """The device turned the motor on: it holds where it is until commanded."""
        self.advance(now)
        if not self.enabled:
            self.enabled = True
            self.target_deg = self.position_deg

    def disable(self, now: float) -> None:
        """The device turned the motor off (torque free): it stops driving and coasts to rest."""
        self.advance(now)
        self.enabled = False

    def set_zero(self, now: float) -> None:
        """The present position becomes 0 (a device's set-zero command)."""
        self.advance(now)
        self.target_deg -= self.position_deg
        self.motor_position_deg -= self.position_deg
        self.position_deg = 0.0

    @property
    def relaxed(self) -> bool:
        """True while the servo is limp because no command came for ``relax_after_s``."""
        limit = self.physics.relax_after_s
        if limit is None or self.time is None:
            return False
        since = self.last_command_time if self.last_command_time is not None else self._t0
        return self.time - since > limit

    @property
    def current_a(self) -> float:
        """Motor current implied by the present motion and load (noise-free)."""
        p = self.physics
        if self.relaxed:
            return 0.0
        if not self.enabled:
            return 0.0
        if self.blocked:  # the loop saturates against the obstruction: the drive's limit
            push = math.copysign(p.stall_current_a, self.target_deg - self.position_deg)
            return push + p.load_current
        moving = abs(self.velocity_dps) > 1e-6
        friction = math.copysign(p.friction_current, self.velocity_dps) if moving else 0.0
        return (
            p.current_per_accel * self.accel_dps2
            + p.viscous_current * self.velocity_dps
            + friction
            + p.load_current
        )

    def measured_current_a(self) -> float:
        """Current as a sensor reports it (with seeded noise)."""
        return self.current_a + self._rng.gauss(0.0, self.physics.current_noise_a)

    @property
    def active_faults(self) -> Fault:
        """Fault flags the servo reports now: injected ones plus those the physics trips."""
        faults = NO_FAULT
        if self.faults.over_current or abs(self.current_a) > self.physics.over_current_a:
            faults |= Fault.OVER_CURRENT
        if self.faults.over_temperature or self.temperature_c > self.physics.over_temperature_c:
            faults |= Fault.OVER_TEMPERATURE
        return faults

    def advance(self, now: float) -> None:
        """Integrate the physics up to ``now`` (fixed 1 ms steps, bounded per call)."""
        if self.time is None:
            self.time = now
            self._t0 = now
            return
        span = now - self.time
        if span <= 0:
            return
        steps = min(_MAX_STEPS_PER_ADVANCE, max(1, math.ceil(span / _STEP_S)))
        h = span / steps
        for _ in range(steps):
            self._step(h)
        self.time = now

    def _step(self, h: float) -> None:
        p = self.physics
        self.time = (self.time or 0.0) + h
        if not self.enabled:
            self._coast(h)
        elif self.relaxed:
            offset = self.position_deg - p.relax_rest_deg
            drift = min(p.relax_rate_dps, abs(offset) / h)
            self.velocity_dps = -math.copysign(drift, offset) if offset else 0.0
            self.accel_dps2 = 0.0
        else:
            error = self.target_deg - self.position_deg
            accel = self.accel_limit_dps2
            wanted = min(
                self.speed_limit_dps,
                p.position_gain * abs(error),
                math.sqrt(2.0 * accel * abs(error)),
            )
            wanted = math.copysign(wanted, error)
            self.accel_dps2 = max(-accel, min(accel, (wanted - self.velocity_dps) / h))
            self.velocity_dps += self.accel_dps2 * h
        self._move(self.velocity_dps * h)
        current = self.current_a
        self.temperature_c += (
            p.heating_c_per_a2s * current * current
            - p.cooling_per_s * (self.temperature_c - p.ambient_c)
        ) * h

    def _move(self, delta_deg: float) -> None:
        """Turn the motor by ``delta_deg``; the output follows unless it slips or is blocked."""
        self.motor_position_deg += delta_deg
        self.blocked = False
        if self.faults.slipping:
            return  # the output, and the angle the servo reports, stay
        new = self.position_deg + delta_deg
        jam = self.faults.jammed_at_deg
        if jam is None:
            self.position_deg = new
            return
        if self.position_deg != jam:
            self._jam_side = math.copysign(1.0, self.position_deg - jam)
        elif not self._jam_side:  # it starts on the obstruction: blocked toward its target
            self._jam_side = -math.copysign(1.0, self.target_deg - jam)
        if (new - jam) * self._jam_side > 0:
            self.position_deg = new
            return
        self.position_deg = float(jam)
        self.motor_position_deg = float(jam)
        self.velocity_dps = 0.0
        self.accel_dps2 = 0.0
        pushing = (self.target_deg - jam) * self._jam_side
        self.blocked = self.enabled and not self.relaxed and pushing < -0.05

    def _coast(self, h: float) -> None:
        """Torque off: friction brings the motor to rest at the greatest rate the drive could."""
        decel = self.physics.max_accel_dps2 * h
        speed = max(0.0, abs(self.velocity_dps) - decel)
        self.velocity_dps = math.copysign(speed, self.velocity_dps)
        self.accel_dps2 = 0.0

    def command_position(
        self,
        angle_deg: float,
        speed_dps: float | None,
        now: float,
        accel_dps2: float | None = None,
    ) -> None:
        """Apply a decoded position command (called by the protocol devices; a device whose
        motor is off turns it on first when the real one would)."""
        self.advance(now)
        self.commands += 1
        self.last_command_time = self.time
        self.target_deg = angle_deg
        ceiling = self.physics.max_speed_dps
        self.speed_limit_dps = ceiling if not speed_dps else min(speed_dps, ceiling)
        accel_ceiling = self.physics.max_accel_dps2
        self.accel_limit_dps2 = accel_ceiling if not accel_dps2 else min(accel_dps2, accel_ceiling)

    # -- the bus side ------------------------------------------------------------------------

    def receive(self, msg: can.Message, now: float) -> list[Reply]:
        """Frame ``msg`` finished on the bus at ``now``: act on it, return the replies."""
        if msg.is_remote_frame or not self._device.accepts(msg):
            return []
        self.advance(now)
        commands = self.commands
        replies = self._device.handle(msg, self.time if self.time is not None else now)
        if self.commands == commands:
            self.requests += 1
        return self._emit(replies, now)

    def next_push_time(self) -> float | None:
        """When the next unsolicited status push is due; None for polled profiles."""
        if not self._device.pushes:
            return None
        return self._next_push

    def poll(self, now: float) -> list[Reply]:
        """Status pushes due by ``now`` (at most one: a late caller does not get a flood); the
        device's own timers (its communication-loss timeout) run here too."""
        self._device.tick(now)
        if not self._device.pushes or self.status_rate_hz <= 0:
            return []
        period = 1.0 / self.status_rate_hz
        if self._next_push is None:
            self._next_push = now + period
            self.advance(now)
            return []
        if now < self._next_push:
            return []
        due = self._next_push
        self._next_push = max(due + period, now - period + 1e-9)
        self.advance(now)
        return self._emit(self._device.status(due), due)

    def _emit(self, replies: list[can.Message], now: float) -> list[Reply]:
        out: list[Reply] = []
        for reply in replies:
            if self.faults.silent:
                return []
            if self.faults.drop_reply_prob and self._rng.random() < self.faults.drop_reply_prob:
                self.replies_dropped += 1
                continue
            self.replies += 1
            due = now + self.reply_latency_s + self.faults.reply_delay_s
            reply.timestamp = due
            out.append((due, reply))
        return out


def simulated_servos(config: Config, bus_name: str) -> list[SimServo]:
    """The simulated devices for the servos on ``bus_name`` (``simulation.servos`` tunes them)."""
    out = []
    for index, servo in enumerate(config.servos):
        if config.bus_of(servo).name != bus_name:
            continue
        physics, faults = config.simulated_settings(servo)
        # push-style servos (CubeMars) report at the rate the config budgets for them
        out.append(
            SimServo(
                servo.profile,
                servo.can_id,
                Physics.from_dict(physics),
                Faults.from_dict(faults),
                seed=index,
                status_rate_hz=servo.telemetry_hz,
                options=servo.profile_options(),
            )
        )
    return share_nodes(out)


def share_nodes(servos: list[SimServo]) -> list[SimServo]:
    """Let the devices of one family meet (``BusNodeFamily.link_sim_devices``): a DroneCAN node
    with several actuators is one node for the servos on its id."""
    by_profile: dict[str, list[SimDevice]] = {}
    for servo in servos:
        by_profile.setdefault(servo.profile, []).append(servo._device)
    for profile, devices in by_profile.items():
        family = node_family(get_profile(profile))
        if family is not None:
            family.link_sim_devices(devices)
    return servos
