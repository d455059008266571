"""The simulated adapters behind a config's ``channel: sim`` buses, with injected mistakes.

The bridge and ``mavservo doctor`` hand :func:`simulator_factory` to the transport layer's bus
factory; for an ``aa55`` bus it starts the AA-55 emulator, for an ``slcan`` bus the LAWICEL
emulator, each with the bus's simulated servos. ``simulation:`` may inject the mistakes a user
makes wiring a real bus, for the doctor to find: ``bus_bitrates`` (the servos run at another
rate than the bus is set to), and per servo ``can_id`` (it answers on another id), ``profile``
and ``options`` (it speaks another protocol or mode than configured).
"""

from __future__ import annotations

from collections.abc import Callable

from mavservo.config import Config, Faults, Physics
from mavservo.servos import get_profile

from .adapter import AdapterEmulator
from .autopilot.can_forward import SimulatedCanPort
from .pty_adapter import PtyAdapter
from .servo import SimServo, simulated_servos
from .slcan import SlcanEmulator


def wired_servos(config: Config, bus_name: str) -> list[SimServo]:
    """:func:`simulated_servos` of ``bus_name``, each as ``simulation.servos`` says it is
    really wired (its injected id, protocol and options, if any)."""
    servos = simulated_servos(config, bus_name)
    on_bus = [s for s in config.servos if config.bus_of(s).name == bus_name]
    out = []
    for index, (servo, sim) in enumerate(zip(on_bus, servos, strict=True)):
        tuning = config.simulation.servos.get(servo.name)
        if tuning is None or (
            tuning.can_id is None and tuning.profile is None and tuning.options is None
        ):
            out.append(sim)
            continue
        physics, faults = config.simulated_settings(servo)
        profile = tuning.profile or servo.profile
        # the servo's own options were validated with the config; only wired ones are new input
        if tuning.options is None and profile == servo.profile:
            options = servo.profile_options()
        else:
            raw = tuning.options if tuning.options is not None else servo.options
            options = get_profile(profile).Options.model_validate(raw)
        out.append(
            SimServo(
                profile,
                tuning.can_id if tuning.can_id is not None else servo.can_id,
                Physics.from_dict(physics),
                Faults.from_dict(faults),
                seed=index,
                status_rate_hz=servo.telemetry_hz,
                options=options,
            )
        )
    return out


def simulator_factory(
    config: Config, started: dict[str, PtyAdapter] | None = None
) -> Callable[[str, str, int], PtyAdapter | None]:
    """The transport factory's ``simulate`` hook for ``config``; each adapter it starts is also
    put in ``started`` by bus name (the bridge's ``emulators``, for tests and the console)."""

    def make(bus_name: str, interface: str, bitrate: int) -> PtyAdapter | None:
        bus = next(b for b in config.can.buses if b.name == bus_name)
        servos = wired_servos(config, bus_name)
        nodes_bitrate = config.simulation.bus_bitrates.get(bus_name)
        emulator: PtyAdapter
        if interface == "aa55":
            emulator = AdapterEmulator(
                servos, bitrate=bitrate, protocol=bus.protocol, nodes_bitrate=nodes_bitrate
            )
        elif interface == "slcan":
            emulator = SlcanEmulator(servos, bitrate=bitrate, nodes_bitrate=nodes_bitrate)
        else:
            return None
        emulator.start()
        if started is not None:
            started[bus_name] = emulator
        return emulator

    return make


def simulated_can_port(config: Config, bus_name: str) -> SimulatedCanPort:
    """The flight controller's CAN port behind a ``mavlink-can`` bus under ``mavlink.url: sim``:
    the bus's servos, as wired, on the simulated autopilot's CAN (not started)."""
    bus = next(b for b in config.can.buses if b.name == bus_name)
    channel = f"mavservo-fc-can-{id(config)}-{bus_name}"
    return SimulatedCanPort(wired_servos(config, bus_name), int(bus.channel) - 1, channel)
