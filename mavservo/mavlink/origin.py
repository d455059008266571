"""Where a received frame came from: the address (UDP) or connection (TCP) it arrived on.

Why (issue 40): on an unsigned link a (system, component) pair is only a claim; anyone can
send as the ground station 255/190 from another address. Keyed by the ids alone, the
stranger took the station's answers (they went to wherever the identity was last heard), its
set budget (one bucket for both) and its writes. So the link tags every frame it hands on
with its origin, and whether that origin holds the identity's pin (the one address, or
connection, a privileged identity is bound to: :data:`~.link.PIN_REBIND_S`); the core keys
answers, rate limits and sessions by :class:`Requester` (identity *and* origin), and answers
go back to the origin the request came from, never to the identity's last address.

A frame from a link with a single peer (serial, ``udpout:`` from the address it sends to) or
made by a test carries no tag: its origin is None and it counts as from the pinned address (there
is no other). A ``udpout:`` socket takes datagrams from anyone who finds its port: those from
another address are tagged with it, the peer holding every privileged identity.
"""

from __future__ import annotations

from collections.abc import Hashable
from typing import Any, NamedTuple

_ORIGIN = "_mavservo_origin"
_PINNED = "_mavservo_pinned"


class Requester(NamedTuple):
    """Who asked: the claimed (system, component) and the origin it spoke from."""

    system: int
    component: int
    origin: Hashable = None

    @property
    def identity(self) -> tuple[int, int]:
        return (self.system, self.component)


def tag(msg: Any, origin: Hashable, pinned: bool) -> None:
    """Record on a received message where it came from and whether that origin holds the pin
    of the identity it claims (True for an identity that pins nothing)."""
    setattr(msg, _ORIGIN, origin)
    setattr(msg, _PINNED, pinned)


def origin_of(msg: Any) -> Hashable:
    return getattr(msg, _ORIGIN, None)


def from_pinned(msg: Any) -> bool:
    """False only when the link saw the frame's identity pinned to another origin."""
    return bool(getattr(msg, _PINNED, True))


def requester_of(msg: Any) -> Requester:
    return Requester(msg.get_srcSystem(), msg.get_srcComponent(), origin_of(msg))


def describe(origin: Hashable) -> str:
    """An origin for a log line or a STATUSTEXT: ``udp 127.0.0.1:14550``, ``tcp ...``."""
    if isinstance(origin, tuple) and len(origin) >= 2:
        return f"udp {origin[0]}:{origin[1]}"
    address = getattr(origin, "address", None)
    if isinstance(address, tuple) and len(address) >= 2:
        return f"tcp {address[0]}:{address[1]}"
    return "this link" if origin is None else str(origin)
