"""TCP server (tcpin:) against clients that connect and never read / never send.

(a) A stranger connects first and sends nothing; then the GCS connects and sends a command.
(b) A client that sends one HEARTBEAT and never reads for 20 s: does the bridge keep running
    (its ACK to a command sent afterwards), does it stop on time at --duration?

Usage: python attack/a12_tcp.py
"""

from __future__ import annotations

import socket
import time

from harness import BridgeProc, encoder, free_port, pack
from pymavlink.dialects.v20 import ardupilotmega as m2


def connect(port: int) -> socket.socket:
    for _ in range(100):
        try:
            return socket.create_connection(("127.0.0.1", port), timeout=1)
        except OSError:
            time.sleep(0.1)
    raise RuntimeError("no connect")


def read_acks(s: socket.socket, seconds: float) -> list:
    dec = m2.MAVLink(None)
    dec.robust_parsing = True
    s.settimeout(0.1)
    data = b""
    deadline = time.monotonic() + seconds
    for _ in range(10_000):
        if time.monotonic() > deadline:
            break
        try:
            chunk = s.recv(65536)
            if not chunk:
                break
            data += chunk
        except (TimeoutError, BlockingIOError):
            continue
    return [m for m in (dec.parse_buffer(data) or []) if m.get_type() == "COMMAND_ACK"]


def main() -> None:
    port = free_port()
    bridge = BridgeProc("cfg_open.yaml", duration=12, url=f"tcpin:127.0.0.1:{port}")
    time.sleep(3)
    idle = connect(port)  # the stranger: connects, sends nothing, reads nothing
    time.sleep(0.5)
    gcs = connect(port)
    enc = encoder()
    gcs.sendall(pack(enc, enc.heartbeat_encode(6, 8, 0, 0, 4)))
    gcs.sendall(pack(enc, enc.command_long_encode(1, 140, 183, 0, 9, 1900, 0, 0, 0, 0, 0)))
    acks = read_acks(gcs, 3.0)
    print(f"(a) idle stranger connected first: GCS command ACKs = {len(acks)}")
    idle.close()
    acks = read_acks(gcs, 3.0)
    print(f"    after the stranger closed: GCS ACKs = {len(acks)}")
    gcs.close()
    rc = bridge.finish()
    print("    link:", bridge.mavlink_stats()["link"], "exit", rc)

    port = free_port()
    bridge = BridgeProc("cfg_open.yaml", duration=25, url=f"tcpin:127.0.0.1:{port}")
    time.sleep(3)
    s = connect(port)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    s.sendall(pack(enc, enc.heartbeat_encode(6, 8, 0, 0, 4)))
    t0 = time.monotonic()
    time.sleep(15)  # never read
    s.sendall(pack(enc, enc.command_long_encode(1, 140, 183, 0, 9, 1100, 0, 0, 0, 0, 0)))
    time.sleep(1)
    still_running = bridge.proc.poll() is None
    print("bridge still running after the idle client:", still_running)
    rc = bridge.finish(timeout=40)
    dt = time.monotonic() - t0
    st = bridge.mavlink_stats()
    print(
        f"(b) client never read for 15 s: bridge exit={rc} {dt:.0f} s after connect "
        f"(duration 25 s incl. start); commands={st['commands']}; link={st['link']}"
    )
    s.close()


if __name__ == "__main__":
    main()
