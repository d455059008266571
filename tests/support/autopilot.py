"""Helpers for tests that talk to the simulator: free UDP ports and bounded receive loops."""

from __future__ import annotations

import socket
import time
from collections.abc import Callable
from typing import Any

from mavservo.mavlink.connection import open_connection

#: Receive buffer asked for by test peers. A replay at 40x speed sends ~2,300 datagrams in
#: seconds; with the default ~208 KiB (about 270 loopback datagrams) a test process stalled by a
#: loaded machine lost the tail of the stream (seen in CI: 10 of 2,302 missing).
PEER_RCVBUF_BYTES = 4 * 1024 * 1024


def peer(port: int, component: int = 191) -> Any:
    """A companion-side pymavlink endpoint listening on 127.0.0.1:``port`` (MAVLink 2)."""
    conn = open_connection(f"udpin:127.0.0.1:{port}", source_system=1, source_component=component)
    conn.port.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, PEER_RCVBUF_BYTES)
    return conn


def collect(
    conn: Any,
    seconds: float,
    until: Callable[[Any], bool] | None = None,
    limit: int = 20_000,
    on_message: Callable[[Any], None] | None = None,
) -> list[tuple[float, Any]]:
    """(t_monotonic, msg) received within ``seconds`` (at most ``limit``), or until ``until``."""
    out: list[tuple[float, Any]] = []
    end = time.monotonic() + seconds
    while time.monotonic() < end and len(out) < limit:
        msg = conn.recv_match(blocking=True, timeout=0.05)
        if msg is None or msg.get_type() == "BAD_DATA":
            continue
        out.append((time.monotonic(), msg))
        if on_message is not None:
            on_message(msg)
        if until is not None and until(msg):
            break
    return out


def of_type(messages: list[tuple[float, Any]], name: str) -> list[Any]:
    return [m for _, m in messages if m.get_type() == name]
