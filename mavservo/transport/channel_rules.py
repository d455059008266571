"""What each interface takes as ``channel`` and ``bitrate``, checked before anything is opened.

python-can finds out that an slcan bitrate is not one of LAWICEL's ``Sn`` codes, or that a
SocketCAN channel is a tty path, only when the bus opens (``Invalid bitrate, choose one of
...``; ``[Errno 97] Address family not supported by protocol``), so ``mavservo check`` said
"valid" and ``mavservo run`` refused (issue 37). The rules per interface live in one table,
:data:`RULES`: the form of its channel and, where python-can declares them, the bitrates it
takes (read from python-can itself, no copy kept here). An interface without an entry is not
checked here (its open says what is wrong); a new interface gets an entry.

Two kinds of finding: :func:`bus_problems` are facts of the config alone (the same verdict on
every machine: errors), :func:`device_problems` are facts of this machine (a serial device not
plugged in, a SocketCAN interface absent or down: warnings, since the config may be checked on
a laptop or before the adapter is plugged in).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Collection
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

#: The channel that asks for the built-in simulation (as :data:`bus_factory.SIM_CHANNEL`).
_SIM = "sim"

#: A serial device as pyserial opens it: a path (absolute, or relative with a ``/`` such as
#: ``./adapter``, the link ``mavservo sim --link`` makes), a Windows COM port, or one of pyserial's
#: URL handlers (``serial.serial_for_url``: ``socket://``, ``rfc2217://``, ``loop://``, ...).
_SERIAL_FORM = re.compile(r"^(/|\.{1,2}/|COM\d+$|[a-z][a-z0-9+]*://)", re.IGNORECASE)

#: A Linux network interface name: 1..15 bytes (IFNAMSIZ 16 with its NUL, include/uapi/linux/
#: if.h), no ``/``, no white space (net/core/dev.c, ``dev_valid_name``).
_NETDEV_FORM = re.compile(r"^[^/\s:]{1,15}$")

#: IFF_UP in ``/sys/class/net/<name>/flags`` (include/uapi/linux/if.h).
IFF_UP = 0x1

#: Where Linux lists its network interfaces (a test points it elsewhere).
SYS_CLASS_NET = Path("/sys/class/net")

ChannelForm = Literal["serial", "netdev", "pcan", "any"]


@dataclass(frozen=True)
class BusProblem:
    """One problem of a bus's ``key`` (``channel``, ``bitrate``); a warning or an error."""

    key: str
    message: str
    warning: bool = False


def _slcan_bitrates() -> Collection[int] | None:
    from can.interfaces.slcan import slcanBus

    return tuple(getattr(slcanBus, "_BITRATES", {})) or None


def _pcan_bitrates() -> Collection[int] | None:
    try:
        from can.interfaces.pcan.basic import PCAN_BITRATES
    except Exception:  # noqa: BLE001 - its module could not load here: not checked
        return None
    return tuple(PCAN_BITRATES)


def _pcan_channels() -> Collection[str] | None:
    try:
        from can.interfaces.pcan.basic import PCAN_CHANNEL_NAMES
    except Exception:  # noqa: BLE001 - its module could not load here: not checked
        return None
    return tuple(name for name in PCAN_CHANNEL_NAMES if name != "PCAN_NONEBUS")


@dataclass(frozen=True)
class InterfaceRule:
    """How an interface names its device, and the bitrates it can set (None: not checked)."""

    channel: ChannelForm
    example: str
    bitrates: Callable[[], Collection[int] | None] | None = None
    #: ``channel@baud`` is accepted (python-can's slcan splits it off)
    baud_suffix: bool = False


#: Per interface: the channel form and the bitrates python-can declares. aa55's bitrates are
#: the codec's table, checked by the schema at the bitrate key (``BITRATE_CODES``).
RULES: dict[str, InterfaceRule] = {
    "aa55": InterfaceRule("serial", "/dev/ttyUSB0"),
    "slcan": InterfaceRule("serial", "/dev/ttyACM0", _slcan_bitrates, baud_suffix=True),
    "serial": InterfaceRule("serial", "/dev/ttyUSB0"),
    "robotell": InterfaceRule("serial", "/dev/ttyUSB0"),
    "seeedstudio": InterfaceRule("serial", "/dev/ttyUSB0"),
    "socketcan": InterfaceRule("netdev", "can0"),
    "pcan": InterfaceRule("pcan", "PCAN_USBBUS1", _pcan_bitrates),
}

#: What a user means by a channel of the wrong form, for the message.
_SOCKETCAN_HINT = (
    "a USB adapter that shows up as a network interface (a candleLight/CANable with candleLight "
    "firmware, a Raspberry Pi CAN HAT) is `interface: socketcan, channel: can0` (see `ip link`)"
)
_SLCAN_HINT = (
    "a serial-line adapter (a CANable with slcan firmware) is `interface: slcan, channel: "
    "/dev/ttyACM0`; with candleLight firmware it is can0 on socketcan (see `ip link`)"
)


def _serial_channel(text: str, rule: InterfaceRule) -> str:
    """The device path of a serial channel (``/dev/ttyACM0@115200`` -> ``/dev/ttyACM0``)."""
    if rule.baud_suffix and "@" in text:
        return text.rpartition("@")[0] or text
    return text


def bus_problems(interface: str, channel: str | int, bitrate: int) -> list[BusProblem]:
    """The errors of a bus that the config alone shows (no device is looked at)."""
    rule = RULES.get(interface)
    if rule is None or channel == _SIM:
        return [] if rule is None else _bitrate_problems(interface, rule, bitrate)
    out = _channel_problems(interface, rule, channel)
    return out + _bitrate_problems(interface, rule, bitrate)


def _channel_problems(interface: str, rule: InterfaceRule, channel: str | int) -> list[BusProblem]:
    """The channel's form against the interface's: ``[]`` when it fits."""
    text = str(channel)
    if rule.channel == "serial":
        fits = not isinstance(channel, int) and bool(
            _SERIAL_FORM.match(_serial_channel(text, rule))
        )
        wanted = f"a serial device (e.g. {rule.example}, or a stable /dev/serial/by-id/... path)"
        hint = f"; {_SOCKETCAN_HINT}" if _NETDEV_FORM.match(text) else ""
    elif rule.channel == "netdev":
        fits = not isinstance(channel, int) and bool(_NETDEV_FORM.match(text))
        wanted = (
            f"a network interface name (e.g. {rule.example}, vcan0; at most 15 characters, no '/')"
        )
        hint = f": that is a serial device; {_SLCAN_HINT}" if text.startswith("/") else ""
    elif rule.channel == "pcan":
        names = _pcan_channels()
        fits = names is None or text in names
        wanted, hint = f"a PCAN channel name (e.g. {rule.example})", ""
    else:
        return []
    if fits:
        return []
    return [BusProblem("channel", f"interface {interface} takes {wanted}, got {text!r}{hint}")]


def _bitrate_problems(interface: str, rule: InterfaceRule, bitrate: int) -> list[BusProblem]:
    allowed = rule.bitrates() if rule.bitrates is not None else None
    if allowed is None or bitrate in allowed:
        return []
    rates = ", ".join(str(rate) for rate in sorted(allowed, reverse=True))
    return [
        BusProblem(
            "bitrate",
            f"python-can's {interface} interface sets only the bitrates {rates}; got {bitrate}",
        )
    ]


def device_problems(
    interface: str, channel: str | int, bitrate: int, *, sys_class_net: Path | None = None
) -> list[BusProblem]:
    """Warnings about this machine's device for a bus of a well-formed channel: a serial device
    that does not exist (yet), a SocketCAN interface that is absent or down."""
    rule = RULES.get(interface)
    if rule is None or channel == _SIM or _channel_problems(interface, rule, channel):
        return []  # the simulation, an unchecked interface, or a channel already refused
    text = str(channel)
    problem = None
    if rule.channel == "serial":
        problem = serial_device_problem(_serial_channel(text, rule))
    elif rule.channel == "netdev":
        problem = netdev_problem(text, bitrate, sys_class_net or SYS_CLASS_NET)
    return [] if problem is None else [BusProblem("channel", problem, warning=True)]


#: Serial devices of a Raspberry Pi's own UART (the header's GPIO14/15), as Raspberry Pi OS
#: names them (documentation: "Configuring UARTs", primary and secondary UART).
PI_UART_PATH = re.compile(r"^/dev/(serial[01]|ttyAMA\d+|ttyS0)$")


def serial_device_problem(path: str) -> str | None:
    """Why ``path`` cannot be opened on this machine now, or None (a URL is not looked at)."""
    if "://" in path or not path.startswith(("/", "./", "../")) or Path(path).exists():
        return None
    if PI_UART_PATH.match(path):
        return (
            f"{path} does not exist on this machine (yet): on a Raspberry Pi, turn the UART on "
            "and its login console off (`sudo raspi-config` -> Interface Options -> Serial "
            "Port; or `enable_uart=1` in /boot/firmware/config.txt), then reboot"
        )
    return (
        f"{path} does not exist on this machine (yet): plug the adapter in, or name it by a "
        "stable /dev/serial/by-id/... path (`ls -l /dev/serial/by-id/`)"
    )


def netdev_problem(name: str, bitrate: int, sys_class_net: Path = SYS_CLASS_NET) -> str | None:
    """Why SocketCAN interface ``name`` would not carry frames now, or None."""
    if not sys_class_net.is_dir():
        return None  # not Linux: nothing to look at
    entry = sys_class_net / name
    if not entry.exists():
        return (
            f"no network interface {name!r} on this machine (yet) (`ip link` lists them): plug "
            "the adapter in, load its driver (gs_usb for a candleLight/CANable, mcp251x for a "
            "Pi CAN HAT)"
        )
    if not interface_is_up(entry):
        return (
            f"interface {name} is down: `sudo ip link set {name} up type can bitrate {bitrate}` "
            "(SocketCAN takes the bitrate from the link, not from this file)"
        )
    return None


def interface_is_up(entry: Path) -> bool:
    """IFF_UP of ``/sys/class/net/<name>`` (True when it cannot be read, or there is no such
    interface: not ours to judge, the open says what is wrong)."""
    try:
        flags = int((entry / "flags").read_text().strip(), 16)
    except (OSError, ValueError):
        return True
    return bool(flags & IFF_UP)
