"""Checks that relate several sections of a config to each other.

Each check returns ``(key path, message)`` pairs pointing at the key that has to change, so the
loader can print the line of that key. They run only on a config that passed the per-model
validation, so every field here already has the right type.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

from mavservo.config.schema import (
    ActuatorChannel,
    Config,
    ServoConfig,
    ServoOutputChannel,
)
from mavservo.scheduling import family_nodes
from mavservo.servos import (
    BusNodeError,
    ConfigWarnings,
    FrameId,
    comm_timeout_of,
    release_frames_of,
)

Finding = tuple[tuple[str | int, ...], str]


def can_identifiers(servo: ServoConfig) -> tuple[FrameId, ...]:
    """Every frame a servo is sent or sends, as its own profile declares them."""
    return servo.make_profile().identifiers()


def first_overlap(
    mine: tuple[FrameId, ...], theirs: tuple[FrameId, ...], same_family: bool
) -> tuple[FrameId, FrameId] | None:
    """The first pair of identifiers some frame could be taken for both of, or None.

    Any direction counts: one's request that the other would take for its reply is as wrong as
    two servos pushing on one id. A broadcast every servo of one family shares is not a clash
    between two servos of that family.
    """
    for a in mine:
        for b in theirs:
            if same_family and a.shared and b.shared:
                continue
            if a.overlaps(b):
                return a, b
    return None


def cross_checks(config: Config) -> list[Finding]:
    """All cross-section problems, in file order of the sections."""
    findings: list[Finding] = []
    for check in (
        _bus_names,
        _servo_names,
        _servo_buses,
        _can_id_collisions,
        _bus_nodes,
        _failsafe_positions,
        _failsafe_release,
        _temperature_release,
        _channels,
        _gimbals,
        _simulation_names,
        _stream_request_minimum,
    ):
        findings.extend(check(config))
    return findings


def budget_checks(config: Config) -> list[Finding]:
    """The worst-case bus load of each bus against its ``max_load``."""
    from mavservo.config.budget import bus_loads

    findings: list[Finding] = []
    for index, load in enumerate(bus_loads(config)):
        if load.over_budget:
            findings.append(
                (
                    ("can", "buses", index, "max_load"),
                    f"worst-case bus load {load.load:.3f} of bus {load.bus!r} ({load.servo_count} "
                    f"servos at {load.bitrate} bit/s) exceeds max_load {load.max_load}; lengthen "
                    "scheduler periods, lower telemetry_hz, raise the bitrate or move servos to "
                    "another bus",
                )
            )
    return findings


def advisories(config: Config) -> list[Finding]:
    """Settings that load and run but do not do what they say; ``check`` prints them as warnings.

    A polled servo is never polled faster than the telemetry loop ticks (``1 /
    scheduler.telemetry_period_s``, the scheduler's documented cap); the scheduler says so in
    its log at start-up, ``check`` says it with the line. Push-style servos report on their own
    and are not capped.
    """
    from mavservo.config.budget import is_polled, profile_of, telemetry_rate_hz

    findings: list[Finding] = []
    for index, servo in enumerate(config.servos):
        # the rate the budget counts, which is the cap when the servo asks for more
        cap_hz = telemetry_rate_hz(servo, config.scheduler)
        if cap_hz < servo.telemetry_hz and is_polled(profile_of(servo)):
            findings.append(
                (
                    ("servos", index, "telemetry_hz"),
                    f"{servo.telemetry_hz:g} Hz is faster than the telemetry loop polls "
                    f"(1 / scheduler.telemetry_period_s = {cap_hz:.3g} Hz): servo "
                    f"{servo.name!r} will be polled at {cap_hz:.3g} Hz; lower telemetry_hz or "
                    "shorten scheduler.telemetry_period_s",
                )
            )
    findings += [
        (("servos", index, "options"), f"servo {servo.name!r}: {text}")
        for index, servo in enumerate(config.servos)
        if isinstance(profile := profile_of(servo), ConfigWarnings)
        for text in profile.config_warnings()
    ]
    findings += _undriven_servos(config)
    findings += _keep_alive_past_timeout(config)
    return findings


def longest_command_gap_s(refresh_interval_s: float, command_period_s: float) -> float:
    """The longest a servo holding one setpoint goes without a command frame: its refresh goes
    out on the first command slot at least ``refresh_interval_s - command_period_s / 2`` after
    the last command (``scheduling.schedule_core``), so the interval rounded to whole slots."""
    slots = math.ceil((refresh_interval_s - command_period_s / 2) / command_period_s - 1e-9)
    return max(1, slots) * command_period_s


def _keep_alive_past_timeout(config: Config) -> list[Finding]:
    """Servos whose own communication timeout or watchdog (``comm_timeout_s`` of their
    profile) is not longer than the longest gap between the commands that keep them alive:
    such a servo stops or disarms by itself while it holds a position."""
    from mavservo.config.budget import profile_of

    sched = config.scheduler
    gap = longest_command_gap_s(sched.refresh_interval_s, sched.command_period_s)
    findings: list[Finding] = []
    for index, servo in enumerate(config.servos):
        timeout = comm_timeout_of(profile_of(servo))
        if timeout is None or gap < timeout:
            continue
        findings.append(
            (
                ("servos", index, "options"),
                f"servo {servo.name!r} stops by itself after {timeout * 1000:g} ms without a "
                f"frame (its own communication timeout or watchdog), but holding a setpoint it "
                f"gets a command only every {gap * 1000:g} ms (scheduler.refresh_interval_s "
                f"{sched.refresh_interval_s:g} s in {sched.command_period_s:g} s command slots): "
                "lower scheduler.refresh_interval_s below the timeout, or raise the timeout",
            )
        )
    return findings


def _undriven_servos(config: Config) -> list[Finding]:
    """Servos that no channel and no gimbal axis names: the bridge polls them and sends them
    their failsafe, but no MAVLink input can ever move them (usually a forgotten channel entry
    or a misspelt name in one)."""
    driven = {channel.servo for channel in config.channels}
    driven |= {name for gimbal in config.gimbals for name in gimbal.axes().values()}
    return [
        (
            ("servos", index, "name"),
            f"servo {servo.name!r} is driven by no input: no channel and no gimbal axis names it, "
            "so no MAVLink command can move it; add a 'channels' entry (servo_output or "
            "actuator) or a gimbal axis for it",
        )
        for index, servo in enumerate(config.servos)
        if servo.name not in driven
    ]


def _stream_request_minimum(config: Config) -> Iterator[Finding]:
    """``min_rate_hz`` above the rate asked for (by default the command rate) would warn for
    ever about a stream that arrives exactly as requested."""
    streams = config.mavlink.request_streams
    rate = streams.rate_hz or 1.0 / config.scheduler.command_period_s
    if streams.min_rate_hz is not None and streams.min_rate_hz > rate:
        yield (
            ("mavlink", "request_streams", "min_rate_hz"),
            f"min_rate_hz {streams.min_rate_hz:g} is above the requested rate {rate:g} Hz "
            "(rate_hz, or 1 / scheduler.command_period_s when unset); lower it",
        )


def _duplicates(names: list[str]) -> Iterator[tuple[int, int]]:
    """(index, index of the first occurrence) for every repeated name."""
    first: dict[str, int] = {}
    for index, name in enumerate(names):
        if name in first:
            yield index, first[name]
        else:
            first[name] = index


def _bus_names(config: Config) -> Iterator[Finding]:
    names = [bus.name for bus in config.can.buses]
    for index, earlier in _duplicates(names):
        yield (
            ("can", "buses", index, "name"),
            f"bus name {names[index]!r} is already used by can.buses[{earlier}]",
        )


def _servo_names(config: Config) -> Iterator[Finding]:
    names = [servo.name for servo in config.servos]
    for index, earlier in _duplicates(names):
        yield (
            ("servos", index, "name"),
            f"servo name {names[index]!r} is already used by servos[{earlier}]",
        )


def _servo_buses(config: Config) -> Iterator[Finding]:
    bus_names = [bus.name for bus in config.can.buses]
    for index, servo in enumerate(config.servos):
        if servo.bus is None and len(bus_names) > 1:
            yield (
                ("servos", index, "bus"),
                f"expected a bus name (one of {', '.join(bus_names)}): there is more than one bus",
            )
        elif servo.bus is not None and servo.bus not in bus_names:
            yield (
                ("servos", index, "bus"),
                f"expected one of the buses in can.buses ({', '.join(bus_names)}), "
                f"found {servo.bus!r}",
            )


def _can_id_collisions(config: Config) -> Iterator[Finding]:
    """Every pair of servos of one bus whose frames could be taken for each other's."""
    bus_names = {bus.name for bus in config.can.buses}
    seen: list[tuple[int, str, tuple[FrameId, ...]]] = []
    for index, servo in enumerate(config.servos):
        bus = servo.bus if servo.bus is not None else config.can.buses[0].name
        if bus not in bus_names:
            continue  # reported by _servo_buses
        mine = can_identifiers(servo)
        for owner, owner_bus, theirs in seen:
            other = config.servos[owner]
            clash = owner_bus == bus and first_overlap(mine, theirs, other.profile == servo.profile)
            if clash:
                yield (("servos", index, "can_id"), _collision_message(servo, other, owner, clash))
        seen.append((index, bus, mine))


def _bus_nodes(config: Config) -> Iterator[Finding]:
    """What a family's bus node refuses (DroneCAN: the bridge's node id taken by a servo, two
    servos on one actuator id), at the key to change; and ``node:`` options for a family that
    has no servo on the bus."""
    for bus_index, bus in enumerate(config.can.buses):
        members = [
            (index, servo)
            for index, servo in enumerate(config.servos)
            if (servo.bus or config.can.buses[0].name) == bus.name
        ]
        built = family_nodes([s.make_profile() for _, s in members], bus.node_options(), bus.name)
        for name in bus.node:
            if not any(b.family == name for b in built):
                yield (
                    ("can", "buses", bus_index, "node", name),
                    f"bus {bus.name!r} has no {name} servo: its node options do nothing; "
                    "remove them or put the servos on this bus",
                )
        for b in built:
            exc = b.error
            if exc is None:
                continue
            if not isinstance(exc, BusNodeError):  # a refusal that names no key: the node's
                yield (("can", "buses", bus_index, "node", b.family), f"{exc} (bus {bus.name!r})")
                continue
            if exc.servo is None:
                path: tuple[str | int, ...] = ("can", "buses", bus_index, "node", b.family)
                if b.family in bus.node:
                    path += tuple(exc.key.split("."))
            else:
                path = ("servos", members[b.members[exc.servo]][0], *exc.key.split("."))
            yield (path, f"{exc} (bus {bus.name!r})")


def _collision_message(
    servo: ServoConfig, other: ServoConfig, owner: int, clash: tuple[FrameId, FrameId]
) -> str:
    mine, theirs = clash
    return (
        f"servo {servo.name!r} ({servo.profile} id {servo.can_id}) collides on its bus with "
        f"servos[{owner}] {other.name!r} ({other.profile} id {other.can_id}): its "
        f"{mine.purpose} {_direction(mine)} on {mine.describe()} and the {theirs.purpose} "
        f"{_direction(theirs)} of {other.name!r} on {theirs.describe()} can be taken for each "
        "other; change one of the ids or put them on different buses"
    )


def _direction(frame: FrameId) -> str:
    return "to the servo" if frame.direction == "to_servo" else "from the servo"


def _failsafe_positions(config: Config) -> Iterator[Finding]:
    for index, servo in enumerate(config.servos):
        position = servo.failsafe.position_deg
        low, high = servo.limits_deg
        if position is not None and not low <= position <= high:
            yield (
                ("servos", index, "failsafe", "position_deg"),
                f"expected an angle inside limits_deg [{low}, {high}], found {position}",
            )


def _failsafe_release(config: Config) -> Iterator[Finding]:
    """``release`` promises motor off: refuse it for a family that has no frame for that."""
    for index, servo in enumerate(config.servos):
        if servo.failsafe.action == "release" and not release_frames_of(servo.make_profile()):
            yield (
                ("servos", index, "failsafe", "action"),
                f"servo {servo.name!r}: the {servo.profile} profile has no motor-off frame, so "
                "'release' could only stop sending while the servo keeps holding its last "
                "target; choose hold, neutral or position (with position_deg)",
            )


def _temperature_release(config: Config) -> Iterator[Finding]:
    """The health monitor's ``temperature_action: release`` promises motor off too (its text
    says "released (motor off)"): refused, like failsafe ``release``, for a family that has no
    motor-off frame, where the overheating servo would keep holding its last target."""
    for index, servo in enumerate(config.servos):
        if servo.health.temperature_action == "release" and not (
            release_frames_of(servo.make_profile())
        ):
            yield (
                ("servos", index, "health", "temperature_action"),
                f"servo {servo.name!r}: the {servo.profile} profile has no motor-off frame, so "
                "'release' at the temperature limit would only refuse setpoints while the "
                "servo keeps holding (and heating); choose hold, slow or warn",
            )


def _channels(config: Config) -> Iterator[Finding]:
    servos = {servo.name: servo for servo in config.servos}
    by_input: dict[tuple[str, int], int] = {}
    by_servo: dict[tuple[str, str], int] = {}
    for index, channel in enumerate(config.channels):
        key_name = "channel" if isinstance(channel, ServoOutputChannel) else "index"
        servo = servos.get(channel.servo)
        if servo is None:
            yield (
                ("channels", index, "servo"),
                f"expected the name of a servo in servos ({', '.join(servos)}), "
                f"found {channel.servo!r}",
            )
        earlier = by_input.setdefault((channel.source, channel.key), index)
        if earlier != index:
            yield (
                ("channels", index, key_name),
                f"{channel.source} {key_name} {channel.key} is already mapped by "
                f"channels[{earlier}]",
            )
        earlier = by_servo.setdefault((channel.source, channel.servo), index)
        if earlier != index:
            yield (
                ("channels", index, "servo"),
                f"servo {channel.servo!r} is already driven by source {channel.source} "
                f"(channels[{earlier}]); one servo takes one mapping per source",
            )
        if servo is not None and channel.output_deg is None:
            yield from _trim_inside_limits(index, channel, servo)


def _trim_inside_limits(
    index: int, channel: ServoOutputChannel | ActuatorChannel, servo: ServoConfig
) -> Iterator[Finding]:
    low, high = servo.limits_deg
    centre = (low + high) / 2 + channel.trim_deg
    if not low < centre < high:
        yield (
            ("channels", index, "trim_deg"),
            f"trim_deg {channel.trim_deg} moves the centre ({centre}) outside the servo's "
            f"limits_deg ({low}, {high})",
        )


def _gimbals(config: Config) -> Iterator[Finding]:
    servo_names = [servo.name for servo in config.servos]
    gimbal_names = [gimbal.name for gimbal in config.gimbals]
    for index, earlier in _duplicates(gimbal_names):
        yield (
            ("gimbals", index, "name"),
            f"gimbal name {gimbal_names[index]!r} is already used by gimbals[{earlier}]",
        )
    ids = [gimbal.component_id for gimbal in config.gimbals]
    for index, earlier in _duplicates([str(i) for i in ids]):
        yield (
            ("gimbals", index, "component_id"),
            f"component id {ids[index]} is already used by gimbals[{earlier}]",
        )
    used: dict[str, str] = {}
    for index, gimbal in enumerate(config.gimbals):
        for axis, servo in gimbal.axes().items():
            where = f"gimbals[{index}].{axis}"
            if servo not in servo_names:
                yield (
                    ("gimbals", index, axis),
                    f"expected the name of a servo in servos ({', '.join(servo_names)}), "
                    f"found {servo!r}",
                )
            elif servo in used:
                yield (("gimbals", index, axis), f"servo {servo!r} already drives {used[servo]}")
            else:
                used[servo] = where


def _simulation_names(config: Config) -> Iterator[Finding]:
    servo_names = {servo.name for servo in config.servos}
    for name in config.simulation.servos:
        if name != "default" and name not in servo_names:
            yield (
                ("simulation", "servos", name),
                f"expected 'default' or the name of a configured servo, found {name!r}",
            )
