"""The one place a bus named by a config is opened: an AA-55 adapter, any python-can
interface with its ``options:``, or a simulated adapter standing in for either.

Why here (the transport layer) and not in the bridge: ``mavservo run`` and ``mavservo doctor``
open the same buses, and the doctor also opens them listen-only and at other bitrates; one
factory keeps the rules (which keys go where, which interface has a listen-only mode, which
has a simulation) in one table. The simulation lives in a higher layer, so the caller hands in
a :data:`SimulatorFactory`; this module only knows that ``channel: sim`` asks for one.

Every bus comes back wrapped in :class:`~mavservo.transport.resilient_bus.ResilientBus`
(reconnect with backoff, frame tap), and the bridge reads nothing of it but python-can's
``BusABC`` and the :class:`~mavservo.transport.counters.TransportCounters` contract.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

import can

from mavservo.transport.channel_rules import SYS_CLASS_NET, interface_is_up
from mavservo.transport.resilient_bus import ResilientBus
from mavservo.transport.tunnel_bus import (
    MAVLINK_CAN,
    TUNNEL_MAX_BACKOFF_S,
    FrameCarrier,
    tunnel_factory,
)

#: The channel that asks for the built-in simulation instead of a device.
SIM_CHANNEL = "sim"

#: The interfaces with a simulated adapter behind ``channel: sim`` (mavservo.sim: the AA-55
#: emulator and the LAWICEL/slcan emulator, both on a pty opened by the real driver).
SIMULATED_INTERFACES = ("aa55", "slcan")

#: python-can interfaces whose frames never leave this process (or machine) for a wire: a bus
#: on one of them moves no real servo, whatever its channel. Every other interface reaches
#: hardware unless it is on ``channel: sim`` (``udp_multicast`` is not listed: a gateway on the
#: network may bridge it to a real bus). An interface added to the project (say, CAN over
#: MAVLink) reaches hardware until it is listed here.
SOFTWARE_INTERFACES = frozenset({"virtual", "sitl-mcast"})  # sitl-mcast: SITL's UDP CAN

#: How each interface is told to listen without transmitting (no ACK, no error frames, no
#: frames of ours): the AA-55 settings frame's silent mode (Waveshare USB-CAN-A manual, the
#: ``0x02`` mode byte), LAWICEL's ``L`` command instead of ``O`` (CAN232/CANUSB manual), a PCAN
#: channel's listen-only state (python-can ``BusState.PASSIVE``). Others have none that
#: python-can exposes (SocketCAN sets it on the link: ``ip link set can0 type can listen-only
#: on``).
LISTEN_ONLY: dict[str, dict[str, Any]] = {
    "aa55": {"mode": "silent"},
    "slcan": {"listen_only": True},
    "pcan": {"state": can.BusState.PASSIVE},
}

#: Interfaces whose bitrate python-can does not set: SocketCAN takes it from the link (``ip link
#: set can0 type can bitrate N``), the software buses have none. Opening them "at" another
#: bitrate changes nothing, so the doctor does not search bitrates on them.
BITRATE_SET_OUTSIDE = frozenset(
    # mavlink-can: the autopilot's CAN_Px_BITRATE; sitl-mcast: a software bus
    {"socketcan", "socketcand", "virtual", "udp_multicast", MAVLINK_CAN, "sitl-mcast"}
)

#: The standard CAN bitrates a bus is tried at when nothing is heard at the configured one,
#: most common first (CiA 301's table; 1 Mbit/s and 500 kbit/s are what servo families ship at).
STANDARD_BITRATES = (1_000_000, 500_000, 250_000, 125_000, 800_000, 100_000, 50_000, 20_000)


class SimulatedAdapter(Protocol):
    """A simulated adapter on a serial port (pty) that a real interface opens at ``path``."""

    path: str

    def stop(self) -> None:
        """Close the port and stop the simulation."""
        ...


#: ``(bus name, interface, bitrate)`` -> a started simulated adapter, or None when the
#: interface has no simulation.
SimulatorFactory = Callable[[str, str, int], SimulatedAdapter | None]


class NoSimulationError(can.CanInitializationError):
    """``channel: sim`` on an interface without a simulated adapter."""


class LinkDownError(can.CanInitializationError):
    """A SocketCAN interface that exists but is down: python-can opens it, and every send
    fails with ``Network is down`` afterwards, so it is refused at the open."""


@dataclass(frozen=True)
class BusRequest:
    """What to open: the bus's YAML keys, plus how (listen-only, another bitrate)."""

    name: str
    interface: str
    channel: str | int
    bitrate: int
    options: Mapping[str, Any] = field(default_factory=dict)
    listen_only: bool = False

    def kwargs(self, channel: str | int) -> dict[str, Any]:
        """The keyword arguments of ``can.Bus`` for this request on ``channel``."""
        out: dict[str, Any] = {
            "interface": self.interface,
            "channel": channel,
            "bitrate": self.bitrate,
            **self.options,
            # the YAML is the only configuration: python-can would otherwise merge in keys
            # of CAN_CONFIG / ~/.canrc / /etc/can.conf that `check` never saw (listen_only,
            # receive_own_messages, can_filters)
            "ignore_config": True,
        }
        if self.listen_only:
            out.update(LISTEN_ONLY.get(self.interface, {}))
        return out


@dataclass
class OpenedBus:
    """A bus and the simulated adapter behind it (None on a real device)."""

    bus: ResilientBus
    simulator: SimulatedAdapter | None = None

    def close(self) -> None:
        """Shut the bus, then stop its simulation (each step even if the other fails)."""
        try:
            self.bus.shutdown()
        finally:
            if self.simulator is not None:
                self.simulator.stop()


def reaches_hardware(interface: str, channel: str | int) -> bool:
    """Whether a bus of ``interface`` on ``channel`` can move a real servo: False only for the
    built-in simulation (``channel: sim`` of a :data:`SIMULATED_INTERFACES` interface) and the
    :data:`SOFTWARE_INTERFACES`. The built-in simulated autopilot drives only buses for which
    this is False (issue 37: it swept real servos of a config that lost its ``mavlink.url``)."""
    if channel == SIM_CHANNEL and interface in SIMULATED_INTERFACES:
        return False
    if interface == MAVLINK_CAN:  # the autopilot's own CAN port: behind the simulated
        return False  # autopilot it is that autopilot's simulated bus, never a real one
    return interface not in SOFTWARE_INTERFACES


def has_listen_only(interface: str) -> bool:
    """Whether :func:`open_bus` can open ``interface`` so that it never transmits."""
    return interface in LISTEN_ONLY


def open_bus(
    request: BusRequest,
    *,
    simulate: SimulatorFactory | None = None,
    on_event: Callable[[str], None] | None = None,
    on_reject: Callable[[Any, bytes], None] | None = None,
    on_frame: Callable[[can.Message, float], None] | None = None,
    carrier: FrameCarrier | None = None,
) -> OpenedBus:
    """Open ``request`` (starting its simulation for ``channel: sim``), wrapped for reconnects.

    ``on_reject`` reaches the ``aa55`` bus's decoder rejections; ``on_frame`` sees every frame
    received (see :class:`ResilientBus`). ``carrier``: the bridge's MAVLink link, which a
    ``mavlink-can`` bus speaks through (:mod:`mavservo.transport.tunnel_bus`).
    """
    channel = request.channel
    simulator: SimulatedAdapter | None = None
    if channel == SIM_CHANNEL:
        simulator = simulate(request.name, request.interface, request.bitrate) if simulate else None
        if simulator is None:
            raise NoSimulationError(
                f"bus {request.name}: interface {request.interface!r} has no built-in "
                "simulation (aa55 and slcan have one); give the device as `channel:`"
            )
        channel = simulator.path
    if request.interface == "socketcan" and not interface_is_up(SYS_CLASS_NET / str(channel)):
        raise LinkDownError(f"socketcan: interface {channel} is down")
    kwargs = request.kwargs(channel)
    if request.interface == "aa55" and on_reject is not None:
        kwargs["on_reject"] = on_reject

    def factory() -> can.BusABC:
        return can.Bus(**kwargs)

    if request.interface == MAVLINK_CAN:  # an object to speak through, not a device
        factory = tunnel_factory(kwargs, carrier)  # noqa: F811 - the interface's own opener

    try:
        bus = ResilientBus(
            factory,
            name=request.name,
            on_event=on_event,
            path=str(channel),
            on_frame=on_frame,
            max_backoff_s=TUNNEL_MAX_BACKOFF_S if request.interface == MAVLINK_CAN else 2.0,
        )
    except BaseException:
        if simulator is not None:
            simulator.stop()
        raise
    return OpenedBus(bus, simulator)
