"""A device that did not open at start-up, said with its place in the config and its fixes.

``mavservo: cannot start: [Errno 2] could not open port /dev/ttyACM0`` said neither which bus it
was (or that it was the autopilot link) nor what usually fixes it (issue 37). The bridge wraps
each open that fails in a :class:`DeviceOpenError` naming the piece (``bus bus0``, ``the
autopilot link``), its config key and device; :func:`failure_lines` adds the file's line and
the usual causes for that kind of device (:mod:`mavservo.transport.open_advice`). ``mavservo
run`` and ``mavservo doctor`` print the same lines.
"""

from __future__ import annotations

import errno
from collections.abc import Callable, Sequence

from mavservo.config import BusConfig, MavlinkConfig
from mavservo.errors import StartupError
from mavservo.transport import open_causes, serial_causes

Loc = tuple[str | int, ...]


class DeviceOpenError(StartupError):
    """``what`` (``bus bus0``) could not open ``device``; ``loc`` is its config key."""

    def __init__(
        self, what: str, loc: Loc, device: str, causes: Sequence[str], cause: BaseException | str
    ) -> None:
        self.what = what
        self.loc = loc
        self.device = device
        self.causes = list(causes)
        self.reason = str(cause) or type(cause).__name__
        super().__init__(f"{what}: cannot open {device}: {self.reason}")


def bus_open_error(index: int, bus: BusConfig, exc: BaseException | str) -> DeviceOpenError:
    """Bus ``index`` of ``can.buses`` did not open."""
    causes = open_causes(bus.interface, bus.channel, bus.bitrate, exc)
    device = f"{bus.interface} {bus.channel}"
    return DeviceOpenError(
        f"bus {bus.name}", ("can", "buses", index, "channel"), device, causes, exc
    )


def link_open_error(mavlink: MavlinkConfig, exc: BaseException) -> DeviceOpenError:
    """The autopilot link (``mavlink.url``) did not open."""
    url = mavlink.url
    number = getattr(exc, "errno", None)
    if url.startswith("/") or url.upper().startswith("COM"):
        device = url.partition(",")[0]
        causes = serial_causes(
            device,
            exc,
            what="the autopilot (its USB cable, or the USB-serial adapter on its TELEM port)",
        )
    elif number == errno.EADDRINUSE:
        causes = [
            "busy: another program (a second mavservo, MAVProxy, mavlink-router, a ground "
            "station) already listens on that port: stop it, or give this bridge another port"
        ]
    elif number == errno.EADDRNOTAVAIL:
        causes = ["the host is not an address of this machine: listen on 0.0.0.0 or 127.0.0.1"]
    else:
        causes = ["is the address right, and the network (or mavlink-router) up?"]
    return DeviceOpenError("the autopilot link", ("mavlink", "url"), url, causes, exc)


def failure_lines(error: DeviceOpenError, place: Callable[[Loc], str] | None = None) -> list[str]:
    """The failure, where it is configured (``FILE:LINE: key`` from ``place``), and the usual
    causes, one per line."""
    where = place(error.loc) if place is not None else None
    head = f"{error.what} ({where})" if where else error.what
    lines = [f"{head}: cannot open {error.device}: {error.reason}", "usual causes:"]
    lines += [f"  - {cause}" for cause in error.causes]
    return lines
