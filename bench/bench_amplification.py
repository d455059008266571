"""Amplification factor of the bridge's UDP server: datagrams out per datagram in from senders
that never sent a verified frame (docs/engineering/security.md, "UDP server peers").

A real Bridge (simulated AA-55 adapter and servos) listens on ``udpin:127.0.0.1:PORT`` with
signing on. ``--senders`` sockets on 127.0.0.1 (each a stand-in for one spoofed source address)
send ONE datagram each, of one kind:

* ``unknown``: the 15-byte MAVLink 2 frame with an unknown message id of the attack run;
* ``unsigned``: a valid, unsigned HEARTBEAT (refused by signing);
* ``header``: the 10-byte header announcing 255 bytes.

``--no-signing`` runs the bridge without signing: an unsigned HEARTBEAT is then a verified
frame from every sender, and what bounds the reflection is the number of peers answered.

Then every datagram the senders receive during ``--listen`` seconds is counted. The factor is
datagrams received / datagrams sent (0 = no reflection). The median of ``--runs`` runs is
printed, each run on a fresh bridge.

Run against another checkout (e.g. the code before the fix) with
``PYTHONPATH=/path/to/old/checkout python bench/bench_amplification.py``; the script prints
which mavservo it imported.
"""

from __future__ import annotations

import argparse
import os
import socket
import statistics
import time

os.environ.setdefault("MAVLINK20", "1")

from pymavlink.dialects.v20 import ardupilotmega as mavlink2  # noqa: E402

import mavservo  # noqa: E402
from mavservo.app.bridge import Bridge  # noqa: E402
from mavservo.config.loader import load_config_text  # noqa: E402

KEY = bytes(range(1, 33))
UNKNOWN_V2 = bytes.fromhex("FD 03 00 00 00 42 42 DE BC 0A 01 02 03 00 00")
BLINDING_HEADER = bytes.fromhex("FD FF 00 00 00 01 01 4C 00 00")


def config_text(port: int, signing: bool = True) -> str:
    signing_line = f"  signing: {{key: {KEY.hex()}}}\n" if signing else ""
    return f"""
mavlink:
  url: udpin:127.0.0.1:{port}
  system_id: 1
  heartbeat_timeout_s: 30
{signing_line}  allowed_sources: [{{system: 255, component: 190}}]
can:
  buses:
    - {{name: bus0, interface: aa55, channel: sim, protocol: variable}}
servos:
  - {{name: left, profile: rmd-x, can_id: 1, limits_deg: [-30, 30], telemetry_hz: 5}}
  - {{name: right, profile: rmd-x, can_id: 2, limits_deg: [-30, 30], telemetry_hz: 5}}
channels:
  - {{servo: left, source: servo_output, channel: 1, input: {{min: 1000, max: 2000}},
     output_deg: [-30, 30]}}
  - {{servo: right, source: servo_output, channel: 2, input: {{min: 1000, max: 2000}},
     output_deg: [-30, 30]}}
"""


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def payload(kind: str) -> bytes:
    if kind == "unknown":
        return UNKNOWN_V2
    if kind == "header":
        return BLINDING_HEADER
    encoder = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    return bytes(encoder.heartbeat_encode(6, 8, 0, 0, 4).pack(encoder))


def one_run(kind: str, senders: int, listen_s: float, signing: bool) -> tuple[int, int, int]:
    """(datagrams sent, datagrams received back, bytes received back) for one fresh bridge."""
    port = free_udp_port()
    bridge = Bridge(load_config_text(config_text(port, signing)), log_dir=False)
    bridge.start()
    socks = []
    try:
        time.sleep(0.5)  # start-up settles
        data = payload(kind)
        for _ in range(senders):
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.bind(("127.0.0.1", 0))
            sock.setblocking(False)
            sock.sendto(data, ("127.0.0.1", port))
            socks.append(sock)
        got = got_bytes = 0
        deadline = time.monotonic() + listen_s
        while time.monotonic() < deadline:
            for sock in socks:
                for _ in range(1000):
                    try:
                        got_bytes += len(sock.recv(4096))
                        got += 1
                    except BlockingIOError:
                        break
            time.sleep(0.01)
    finally:
        for sock in socks:
            sock.close()
        bridge.stop()
    return senders, got, got_bytes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kinds", default="unknown,unsigned,header")
    parser.add_argument("--senders", type=int, default=50)
    parser.add_argument("--listen", type=float, default=3.0, help="seconds")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument(
        "--no-signing",
        action="store_true",
        help="bridge without signing: an unsigned HEARTBEAT is then a verified frame",
    )
    args = parser.parse_args()
    print(f"mavservo from {os.path.dirname(mavservo.__file__)}")
    signing = "off" if args.no_signing else "on"
    print(
        f"signing {signing}; {args.senders} senders x 1 datagram, listening {args.listen:.1f} s, "
        f"{args.runs} runs"
    )
    for kind in args.kinds.split(","):
        runs = [
            one_run(kind, args.senders, args.listen, not args.no_signing) for _ in range(args.runs)
        ]
        factors = [got / sent for sent, got, _ in runs]
        rates = [got / args.listen for _, got, _ in runs]
        kbps = [nbytes / args.listen / 1000 for _, _, nbytes in runs]
        print(
            f"  {kind:<9} amplification {statistics.median(factors):8.1f} datagrams out per "
            f"datagram in (runs {', '.join(f'{f:.1f}' for f in factors)}); "
            f"{statistics.median(rates):8.0f} datagrams/s, {statistics.median(kbps):7.1f} kB/s"
        )


if __name__ == "__main__":
    main()
