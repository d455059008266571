"""Why a device did not open, in the words of the fixes a user can make.

``cannot start: [Errno 2] could not open port /dev/ttyACM0`` named neither the bus nor the
usual fixes (issue 37). :func:`open_causes` reads the failure (its ``errno``, wherever in the
exception's cause chain it is, else the ``[Errno N]`` in its text) and the kind of device (from
the interface's channel form in :data:`~mavservo.transport.channel_rules.RULES`, or a serial
path for the MAVLink link) and returns the causes worth checking, most likely first. The bridge
(``mavservo run``) and ``mavservo doctor`` both print them, under the name and line of the bus
or link that failed.
"""

from __future__ import annotations

import errno
import re

from mavservo.transport.channel_rules import PI_UART_PATH, RULES

_ERRNO_TEXT = re.compile(r"\[Errno (\d+)\]")

_MISSING = frozenset({errno.ENOENT, errno.ENODEV, errno.ENXIO})
_DENIED = frozenset({errno.EACCES, errno.EPERM})

DIALOUT = (
    "permission: your user is not in the `dialout` group, which owns serial devices: "
    "`sudo usermod -aG dialout $USER`, then log out and in (a service: "
    "`SupplementaryGroups=dialout`)"
)
PI_UART = (
    "a Raspberry Pi UART: turn the serial login console off and the port on (`sudo raspi-config`"
    " -> Interface Options -> Serial Port: login shell No, hardware Yes; or `enable_uart=1` in "
    "/boot/firmware/config.txt and no `console=serial0,...` in cmdline.txt), then reboot"
)


def failure_errno(exc: BaseException | str) -> int | None:
    """The OS error number behind a failure: the first ``errno`` in the cause chain, else the
    ``[Errno N]`` its text quotes (python-can and the AA-55 driver wrap the ``OSError``)."""
    seen: set[int] = set()
    current: BaseException | None = exc if isinstance(exc, BaseException) else None
    while current is not None and id(current) not in seen:
        seen.add(id(current))
        number = getattr(current, "errno", None)
        if isinstance(number, int):
            return number
        current = current.__cause__ or current.__context__
    found = _ERRNO_TEXT.search(str(exc))
    return int(found.group(1)) if found else None


def serial_causes(device: str, exc: BaseException | str, *, what: str = "the adapter") -> list[str]:
    """The usual causes of a serial device that did not open, most likely first. ``what`` is
    the thing that should be at ``device``: the CAN adapter, or the autopilot's USB port or
    serial adapter for the MAVLink link."""
    number = failure_errno(exc)
    text = str(exc).lower()
    causes: list[str] = []
    if PI_UART_PATH.match(device) and number not in _DENIED:
        causes.append(PI_UART)  # the Pi's own UART is missing or busy while it is a console
    if number in _DENIED:
        causes.append(DIALOUT)
    elif number in _MISSING and not causes:
        causes.append(
            f"missing: nothing at {device}: is {what} plugged in (a charge-only USB cable "
            "has no data lines)? USB names move between boots and replugs: use the stable "
            "/dev/serial/by-id/... path (`ls -l /dev/serial/by-id/`)"
        )
    elif number == errno.EBUSY or "lock" in text or "in use" in text:
        causes.append(
            f"busy: another program holds {device} (another mavservo, ModemManager, a serial "
            f"console): `sudo fuser -v {device}` names it"
        )
    if not causes:  # nothing said which: the usual suspects, in order
        causes += [
            f"the device: is {device} {what} (`ls -l /dev/serial/by-id/`), plugged in?",
            DIALOUT,
        ]
    return causes


def socketcan_causes(name: str, bitrate: int, exc: BaseException | str) -> list[str]:
    """The usual causes of a SocketCAN interface that did not open or carry frames."""
    number = failure_errno(exc)
    text = str(exc).lower()
    if number == errno.ENETDOWN or "is down" in text:
        return [
            f"interface {name} is down: `sudo ip link set {name} up type can bitrate {bitrate}`"
            " (SocketCAN takes the bitrate from the link)"
        ]
    if number == errno.EAFNOSUPPORT:
        return [
            "this kernel has no CAN sockets (not Linux, or the can/can_raw modules are not "
            "loaded: `sudo modprobe can_raw`)"
        ]
    if number in _DENIED:
        return ["permission: configuring a CAN link needs root (`sudo ip link set ...`)"]
    return [
        f"no interface {name}: `ip link` lists them; a candleLight CANable (gs_usb driver) or a "
        "Pi CAN HAT (mcp251x) is `can0` on socketcan once its driver is loaded",
        "an adapter that shows up as /dev/ttyACM0 instead (slcan firmware) is `interface: "
        "slcan` with that device as its channel",
    ]


def open_causes(
    interface: str, channel: str | int, bitrate: int, exc: BaseException | str
) -> list[str]:
    """The usual causes of a bus of ``interface`` on ``channel`` that did not open."""
    rule = RULES.get(interface)
    form = rule.channel if rule is not None else None
    if form == "serial":
        device = str(channel).partition("@")[0] if interface == "slcan" else str(channel)
        return serial_causes(device, exc)
    if form == "netdev":
        return socketcan_causes(str(channel), bitrate, exc)
    number = failure_errno(exc)
    if number in _DENIED:
        return [f"permission: your user may not open the {interface} device"]
    return [
        f"is the {interface} adapter plugged in, its driver installed, and {channel!r} its "
        "channel name? (python-can's page for the interface lists the names)"
    ]
