"""Where a config connects, in words: the MAVLink endpoint and each CAN bus's interface.

``mavlink.url`` and ``can`` both default to the built-in simulation (the quick start relies on
that), so a file that leaves one out runs quietly on simulated hardware. ``mavservo check`` and
``mavservo run`` print these lines so that a user can always tell real hardware from the
simulation, and say so plainly when the simulation was chosen because a key was left out.
"""

from __future__ import annotations

from mavservo.config.schema import BusConfig, Config
from mavservo.config.urls import SIM, describe_url
from mavservo.transport import SIMULATED_INTERFACES


def bitrate_text(bitrate: int) -> str:
    """1000000 -> ``1 Mbit/s``, 500000 -> ``500 kbit/s``, 83333 -> ``83333 bit/s``."""
    if bitrate % 1_000_000 == 0:
        return f"{bitrate // 1_000_000} Mbit/s"
    if bitrate % 1_000 == 0:
        return f"{bitrate // 1_000} kbit/s"
    return f"{bitrate} bit/s"


def is_simulated(bus: BusConfig) -> bool:
    """True when the bridge emulates this bus's adapter (an ``aa55`` or ``slcan`` bus on
    channel ``sim``)."""
    return bus.interface in SIMULATED_INTERFACES and bus.channel == SIM


def describe_bus(bus: BusConfig) -> str:
    """E.g. ``aa55 /dev/ttyUSB0 @ 1 Mbit/s (serial 2000000 baud)``, ``socketcan can0 @ 500
    kbit/s``, or the built-in simulation."""
    rate = bitrate_text(bus.bitrate)
    if is_simulated(bus):
        adapter = "AA-55 adapter" if bus.interface == "aa55" else f"{bus.interface} adapter"
        return f"built-in simulation ({adapter} emulator on a pty, simulated servos) @ {rate}"
    options = ", ".join(f"{k}={v!r}" for k, v in bus.options.items())
    extra = f", options {options}" if options else ""
    if bus.interface == "aa55":
        return f"aa55 {bus.channel} @ {rate} (serial {bus.serial_baud} baud{extra})"
    return f"{bus.interface} {bus.channel} @ {rate}" + (f" ({extra[2:]})" if extra else "")


def endpoint_lines(config: Config) -> list[str]:
    """One line for the MAVLink side and one per bus; a key that was left out is named on its line.

    "Left out" is judged from the keys the file set (pydantic's ``model_fields_set``), so a
    config must come from :func:`~mavservo.config.load_config` or
    :func:`~mavservo.config.overrides.apply_overrides`, which keep that record. The note goes at
    the end of the line that describes the simulation, so each link is said once (issue 37).
    """
    lines = []
    mavlink = config.mavlink
    url_given = "mavlink" in config.model_fields_set and "url" in mavlink.model_fields_set
    link = describe_url(mavlink.url, mavlink.baud)
    if mavlink.signing is not None:
        link += ", signed"
    if mavlink.url == SIM and not url_given:
        link += " (mavlink.url not set)"
    lines.append(f"mavlink: {link}")
    can_given = "can" in config.model_fields_set and "buses" in config.can.model_fields_set
    left_out = "can.buses" if "can" in config.model_fields_set else "can"
    for index, bus in enumerate(config.can.buses):
        note = ""
        if not can_given:
            note = f" ({left_out} not set)"
        elif is_simulated(bus) and "channel" not in bus.model_fields_set:
            note = f" (can.buses[{index}].channel not set)"
        lines.append(f"{bus.name}: {describe_bus(bus)}{note}")
    return lines
