"""Frames on the wire: the AA-55 USB-CAN adapter (:mod:`mavservo.transport.aa55`) and the bus
wrapper that survives an unplugged adapter."""

from __future__ import annotations

from typing import TYPE_CHECKING

from mavservo.faces import lazy_face

# The face: what the other layers use from this package (``tests/test_package_faces.py``), each
# name imported from its module on first use (:func:`mavservo.faces.lazy_face`); the modules'
# other names are the package's own business.
if TYPE_CHECKING:
    from .aa55.codec import BITRATE_CODES
    from .aa55.codec import MODES as AA55_MODES
    from .aa55.codec import AdapterSettings as AA55Settings
    from .aa55.codec import Decoder as AA55Decoder
    from .aa55.codec import Frame as AA55Frame
    from .aa55.codec import ProtocolName as AA55Protocol
    from .aa55.codec import encode as encode_aa55
    from .bus_factory import (
        BITRATE_SET_OUTSIDE,
        SIM_CHANNEL,
        SIMULATED_INTERFACES,
        SOFTWARE_INTERFACES,
        STANDARD_BITRATES,
        BusRequest,
        OpenedBus,
        has_listen_only,
        open_bus,
        reaches_hardware,
    )
    from .channel_rules import BusProblem, bus_problems, device_problems, serial_device_problem
    from .counters import transport_stats
    from .interface_signatures import UnknownInterfaceError, interface_options, option_problems
    from .open_advice import open_causes, serial_causes
    from .tunnel_bus import FORWARD_TIMEOUT_S as TUNNEL_FORWARD_TIMEOUT_S
    from .tunnel_bus import KEEPALIVE_S as TUNNEL_KEEPALIVE_S
    from .tunnel_bus import MAVLINK_CAN, FrameCarrier, TunnelledCanBus, filter_key
    from .tunnel_bus import OPTION_BOUNDS as TUNNEL_OPTION_BOUNDS

__all__ = [
    "BITRATE_CODES",
    "BITRATE_SET_OUTSIDE",
    "BusProblem",
    "BusRequest",
    "FrameCarrier",
    "MAVLINK_CAN",
    "TunnelledCanBus",
    "OpenedBus",
    "SIMULATED_INTERFACES",
    "SIM_CHANNEL",
    "SOFTWARE_INTERFACES",
    "STANDARD_BITRATES",
    "UnknownInterfaceError",
    "bus_problems",
    "device_problems",
    "has_listen_only",
    "interface_options",
    "open_bus",
    "open_causes",
    "option_problems",
    "reaches_hardware",
    "serial_causes",
    "serial_device_problem",
    "transport_stats",
    "filter_key",
    "TUNNEL_FORWARD_TIMEOUT_S",
    "TUNNEL_KEEPALIVE_S",
    "TUNNEL_OPTION_BOUNDS",
    "AA55Frame",
    "AA55Decoder",
    "AA55Settings",
    "AA55_MODES",
    "AA55Protocol",
    "encode_aa55",
]
__getattr__ = lazy_face(
    __name__,
    {
        "BITRATE_CODES": "aa55.codec",
        "BITRATE_SET_OUTSIDE": "bus_factory",
        "BusProblem": "channel_rules",
        "BusRequest": "bus_factory",
        "FrameCarrier": "tunnel_bus",
        "MAVLINK_CAN": "tunnel_bus",
        "TunnelledCanBus": "tunnel_bus",
        "OpenedBus": "bus_factory",
        "SIMULATED_INTERFACES": "bus_factory",
        "SIM_CHANNEL": "bus_factory",
        "SOFTWARE_INTERFACES": "bus_factory",
        "STANDARD_BITRATES": "bus_factory",
        "UnknownInterfaceError": "interface_signatures",
        "bus_problems": "channel_rules",
        "device_problems": "channel_rules",
        "has_listen_only": "bus_factory",
        "interface_options": "interface_signatures",
        "open_bus": "bus_factory",
        "open_causes": "open_advice",
        "serial_causes": "open_advice",
        "option_problems": "interface_signatures",
        "reaches_hardware": "bus_factory",
        "serial_device_problem": "channel_rules",
        "transport_stats": "counters",
        "filter_key": "tunnel_bus",
        "TUNNEL_FORWARD_TIMEOUT_S": "tunnel_bus:FORWARD_TIMEOUT_S",
        "TUNNEL_KEEPALIVE_S": "tunnel_bus:KEEPALIVE_S",
        "TUNNEL_OPTION_BOUNDS": "tunnel_bus:OPTION_BOUNDS",
        "AA55Frame": "aa55.codec:Frame",
        "AA55Decoder": "aa55.codec:Decoder",
        "AA55Settings": "aa55.codec:AdapterSettings",
        "AA55_MODES": "aa55.codec:MODES",
        "AA55Protocol": "aa55.codec:ProtocolName",
        "encode_aa55": "aa55.codec:encode",
    },
)
