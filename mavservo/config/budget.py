"""Worst-case bus load of a configuration, per bus (paper eq. 4).

The frames each servo puts on the bus come from its profile (what one position command and one
telemetry poll look like, and how many replies each gets), the rates from the scheduler settings,
and the arithmetic from :mod:`mavservo.scheduling.busload`. A configuration whose worst case exceeds
its
bus's ``max_load`` is refused at load time, before anything touches the bus.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from mavservo.scheduling import STARTUP_RETRY_S, FrameFlow, family_nodes, load_ratio, servo_traffic

if TYPE_CHECKING:
    from mavservo.config.schema import BusConfig, Config, SchedulerConfig, ServoConfig
    from mavservo.scheduling import ServoTraffic
    from mavservo.servos import BusNode, ServoProfile


@dataclass(frozen=True)
class BusLoad:
    """The worst-case load R of one bus against its budget."""

    bus: str
    bitrate: int
    load: float
    max_load: float
    servo_count: int

    @property
    def over_budget(self) -> bool:
        return self.load > self.max_load


def command_rate_hz(servo: ServoConfig, timing: SchedulerConfig) -> float:
    """Worst-case commands per second: one per period, or back-to-back for ``immediate``."""
    if servo.command_mode == "immediate":
        return 1.0 / timing.immediate_min_spacing_s
    return 1.0 / timing.command_period_s


def telemetry_rate_hz(servo: ServoConfig, timing: SchedulerConfig) -> float:
    """Polls per second: the servo's own rate, never faster than the telemetry loop runs."""
    return min(servo.telemetry_hz, 1.0 / timing.telemetry_period_s)


def profile_of(servo: ServoConfig) -> ServoProfile:
    """The servo's profile instance (its id and options): the frames it is sent and answers."""
    return servo.make_profile()


def is_polled(profile: ServoProfile) -> bool:
    """True when the scheduler polls a servo of this profile; False for push-style ones
    (CubeMars servo mode), which report on their own and so are not held to the poll cap."""
    return bool(profile.telemetry_requests())


def servo_traffic_of(
    servo: ServoConfig, timing: SchedulerConfig, *, packed: bool = False
) -> ServoTraffic:
    """One servo's worst-case traffic, from its profile's own frames. ``packed``: its
    commands travel in its bus node's shared transfer, which :func:`node_flows` counts."""
    return servo_traffic(
        profile_of(servo),
        command_hz=0.0 if packed else command_rate_hz(servo, timing),
        poll_hz=telemetry_rate_hz(servo, timing),
        # a push-style servo reports at the rate the config asks for: the telemetry loop
        # paces polls only
        status_hz=servo.telemetry_hz,
        max_speed_dps=servo.max_speed_dps,
        startup_hz=1 / STARTUP_RETRY_S,
    )


def servo_flows(
    servo: ServoConfig, timing: SchedulerConfig, *, packed: bool = False
) -> list[FrameFlow]:
    """Every frame flow one servo causes (:func:`servo_traffic_of`)."""
    return servo_traffic_of(servo, timing, packed=packed).flows()


def bus_loads(config: Config) -> list[BusLoad]:
    """Worst-case R for every bus in the config, in config order."""
    loads = []
    for bus in config.can.buses:
        servos = [s for s in config.servos if _bus_name(config, s) == bus.name]
        loads.append(_bus_load(bus, servos, config.scheduler))
    return loads


def bus_nodes(
    bus: BusConfig, servos: list[ServoConfig]
) -> list[tuple[str, list[ServoConfig], BusNode]]:
    """The bus nodes the scheduler of ``bus`` will own, with their servos: ``(profile name,
    servos, node)``, built by the scheduler's own :func:`family_nodes`. A node that refuses its
    servos (a node id clash) is left out: the semantic checks report it with its line."""
    built = family_nodes([profile_of(s) for s in servos], bus.node_options(), bus.name)
    return [(b.family, [servos[i] for i in b.members], b.node) for b in built if b.node is not None]


def node_flows(
    bus: BusConfig, servos: list[ServoConfig], timing: SchedulerConfig
) -> tuple[list[FrameFlow], set[str]]:
    """The bus nodes' own traffic (DroneCAN: the bridge's NodeStatus and the commands of all
    its servos packed into shared multi-frame transfers), and the servos whose commands they
    carry: what the scheduler counts at start-up, computed by the same node."""
    flows: list[FrameFlow] = []
    packed: set[str] = set()
    for _, group, node in bus_nodes(bus, servos):
        packed |= {servo.name for servo in group}
        hz = max(command_rate_hz(servo, timing) for servo in group)
        flows += [
            FrameFlow(rate, extended, dlc)
            for rate, extended, dlc in node.bus_frames_per_second(len(group), hz)
        ]
    return flows, packed


def servos_on(config: Config, bus: BusConfig) -> list[ServoConfig]:
    return [s for s in config.servos if _bus_name(config, s) == bus.name]


def _bus_load(bus: BusConfig, servos: list[ServoConfig], timing: SchedulerConfig) -> BusLoad:
    flows, packed = node_flows(bus, servos, timing)
    flows += [
        flow for servo in servos for flow in servo_flows(servo, timing, packed=servo.name in packed)
    ]
    return BusLoad(bus.name, bus.bitrate, load_ratio(flows, bus.bitrate), bus.max_load, len(servos))


def _bus_name(config: Config, servo: ServoConfig) -> str:
    return servo.bus if servo.bus is not None else config.can.buses[0].name
