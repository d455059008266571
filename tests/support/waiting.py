"""Bounded waits and free loopback ports, shared by the test files (``from tests.support.waiting
import wait_until``).

Every loop here is bounded in time and in count (the project's rule for tests), and the network
helpers use loopback only.
"""

from __future__ import annotations

import socket
import time
from collections.abc import Callable
from typing import Any

WAIT_S = 10.0
"""Upper bound of a wait for something that should happen. Generous on purpose: a passing test
returns as soon as the condition holds, only a failing one waits this long."""


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that was free a moment ago (the OS picks it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def wait_until(
    predicate: Callable[[], Any], timeout: float = WAIT_S, interval: float = 0.01
) -> bool:
    """Poll ``predicate`` until it is truthy or ``timeout`` passes (bounded in time and count)."""
    deadline = time.monotonic() + timeout
    for _ in range(int(timeout / interval) + 2):
        if predicate():
            return True
        if time.monotonic() >= deadline:
            break
        time.sleep(interval)
    return bool(predicate())


def wait_for_message(
    conn: Any,
    predicate: Callable[[Any], bool],
    timeout: float = WAIT_S,
    keep: list[Any] | None = None,
    limit: int = 20_000,
) -> Any | None:
    """The first MAVLink message from ``conn`` satisfying ``predicate``, or None after
    ``timeout`` or ``limit`` messages; every message received is appended to ``keep``."""
    deadline = time.monotonic() + timeout
    for _ in range(limit):
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            return None
        msg = conn.recv_match(blocking=True, timeout=min(remaining, 0.2))
        if msg is None:
            continue
        if keep is not None:
            keep.append(msg)
        if predicate(msg):
            return msg
    return None
