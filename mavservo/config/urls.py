"""MAVLink connection strings: checked at load time, described in plain words.

pymavlink finds out that ``udpin:127.0.0.1:99999`` or ``udpin:host:bad`` is unusable only when
it opens the socket, and then says ``bind(): port must be 0-65535`` or ``invalid literal for
int()``, naming neither the key nor the file. The same rules pymavlink applies (exactly one
``HOST:PORT`` after the scheme, a numeric port) are checked here, where the loader can still
point at the line; serial device paths are left as they are (whether a device exists is a
question for the machine the bridge runs on, not for the file).
"""

from __future__ import annotations

import re

#: Scheme -> True when the bridge listens on the address (port 0 = any free port, empty host =
#: every interface) rather than sending to it.
NETWORK_SCHEMES: dict[str, bool] = {
    "udpin": True,
    "udp": True,  # pymavlink's legacy spelling of udpin for an input connection
    "tcpin": True,
    "udpout": False,
    "udpbcast": False,
    "tcp": False,
}

#: The built-in autopilot stream simulator.
SIM = "sim"

_SERIAL = re.compile(r"^(/|COM\d+)")
_EXPECTED = (
    "expected 'sim', a pymavlink connection string (udpin:HOST:PORT, udpout:HOST:PORT, "
    "tcp:HOST:PORT, tcpin:HOST:PORT, udpbcast:HOST:PORT) or a serial device path"
)


def is_serial_url(url: str) -> bool:
    """True for a serial device path (``/dev/ttyAMA0``, ``COM3``): a link of ``mavlink.baud``."""
    return bool(_SERIAL.match(url))


def url_problem(url: str, *, allow_sim: bool = True) -> str | None:
    """What is wrong with ``url`` as a MAVLink endpoint, or None when pymavlink can use it."""
    if url == SIM:
        return None if allow_sim else "'sim' is only valid for mavlink.url"
    if _SERIAL.match(url):
        return None
    scheme, colon, rest = url.partition(":")
    if not colon or scheme not in NETWORK_SCHEMES:
        return f"{_EXPECTED}, got {url!r}"
    listening = NETWORK_SCHEMES[scheme]
    example = f"{scheme}:0.0.0.0:14550" if listening else f"{scheme}:127.0.0.1:14550"
    parts = rest.split(":")
    if len(parts) != 2:
        return f"expected {scheme}:HOST:PORT (e.g. {example}), got {url!r}"
    host, port_text = parts
    if not host and not listening:
        return f"{url!r} has no host to send to; expected {scheme}:HOST:PORT (e.g. {example})"
    lowest = 0 if listening else 1
    if not port_text.isdigit() or not lowest <= int(port_text) <= 65535:
        return (
            f"port {port_text!r} in {url!r} is not a number in {lowest}..65535; "
            f"expected {scheme}:HOST:PORT (e.g. {example})"
        )
    return None


def describe_url(url: str, baud: int) -> str:
    """``url`` in words, for the start-up banner and ``mavservo check``."""
    if url == SIM:
        return "built-in stream simulator"
    if _SERIAL.match(url):
        device, comma, rate = url.rpartition(",")
        if comma and rate.isdigit():  # pymavlink's "DEVICE,BAUD" form overrides mavlink.baud
            url, baud = device, int(rate)
        return f"serial {url} @ {baud} baud"
    scheme = url.partition(":")[0]
    if NETWORK_SCHEMES.get(scheme):
        return f"{url} (listening)"
    return f"{url} (sending to)"
