"""Promise 1: datagrams from unverified senders (many 127.0.0.x addresses) draw nothing back,
are never counted as received, never reach the tlog, and cost no log line per frame.

Usage: python attack/a1_strangers.py [signed|open] [n_addresses]
"""

from __future__ import annotations

import select
import socket
import sys
import time

from harness import KEY, BridgeProc, encoder, pack, peer

UNKNOWN_V2 = bytes.fromhex("FD 03 00 00 00 42 42 DE BC 0A 01 02 03 00 00")
UNKNOWN_V1 = bytes.fromhex("FE 03 00 42 42 FF 01 02 03 00 00")
BLINDING = bytes.fromhex("FD FF 00 00 00 01 01 4C 00 00")


def payloads(signed: bool) -> dict[str, bytes]:
    p = {
        "unknown_v2": UNKNOWN_V2,
        "unknown_v1": UNKNOWN_V1,
        "blinding": BLINDING,
        "garbage": bytes(range(256)),
        # unknown id with the "signed" flag and 13 junk signature bytes
        "unknown_v2_signedflag": bytes.fromhex("FD 03 01 00 00 42 42 DE BC 0A 01 02 03 00 00")
        + bytes(13),
    }
    if signed:
        hb = encoder((66, 190)).heartbeat_encode(6, 8, 0, 0, 4)
        p["unsigned_heartbeat"] = pack(encoder((66, 190)), hb)
        wrong = encoder((66, 190), key=bytes(32))
        p["wrong_key_heartbeat"] = pack(wrong, wrong.heartbeat_encode(6, 8, 0, 0, 4))
        v1 = mavlink2.MAVLink(None, srcSystem=66, srcComponent=190)
        v1.WIRE_PROTOCOL_VERSION = "1.0"
    return p


import pymavlink.dialects.v20.ardupilotmega as mavlink2  # noqa: E402


def main() -> None:
    mode = sys.argv[1] if len(sys.argv) > 1 else "signed"
    n = int(sys.argv[2]) if len(sys.argv) > 2 else 200
    signed = mode == "signed"
    bridge = BridgeProc("cfg_signed.yaml" if signed else "cfg_open.yaml", duration=14)
    bridge.wait_ready()
    # one legitimate peer so the bridge is actively sending (heartbeats, telemetry)
    gcs = peer(bridge.port, key=KEY if signed else None)
    gcs.mav.heartbeat_send(6, 8, 0, 0, 4)
    socks = []
    for i in range(n):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind((f"127.0.{i // 250}.{2 + i % 250}", 0))
        s.setblocking(False)
        socks.append(s)
    kinds = payloads(signed)
    sent = 0
    for _rnd in range(3):
        for s in socks:
            for data in kinds.values():
                s.sendto(data, ("127.0.0.1", bridge.port))
                sent += 1
        time.sleep(0.2)
    back = 0
    deadline = time.monotonic() + 5.0
    for _ in range(100_000):
        rem = deadline - time.monotonic()
        if rem <= 0:
            break
        r, _, _ = select.select(socks, [], [], min(rem, 0.2))
        for s in r:
            try:
                s.recv(65535)
                back += 1
            except BlockingIOError:
                pass
    gcs_got = len([m for m in [gcs.recv_match(blocking=False) for _ in range(5000)] if m])
    rc = bridge.finish()
    link = bridge.mavlink_stats()["link"]
    tlog = (bridge.run_dir() / "mavlink.tlog").read_bytes()
    from pymavlink import mavutil

    mlog = mavutil.mavlink_connection(str(bridge.run_dir() / "mavlink.tlog"))
    srcs: dict[tuple, int] = {}
    for _ in range(1_000_000):
        m = mlog.recv_msg()
        if m is None:
            break
        k = (m.get_srcSystem(), m.get_srcComponent(), m.get_type())
        srcs[k] = srcs.get(k, 0) + 1
    lines = bridge.log_lines()
    print(f"mode={mode} addresses={n} kinds={list(kinds)} datagrams_in={sent}")
    print(f"datagrams back to strangers={back}  ratio={back / sent:.4f}")
    print(f"legit gcs got ~{gcs_got} msgs; exit={rc}")
    print("link counters:", link)
    print(
        "tlog frames from 0x42 sys (66) / unknown payload bytes present:",
        {k: v for k, v in srcs.items() if k[0] in (0x42, 66)},
        UNKNOWN_V2[10:13] in tlog,
    )
    print("tlog sources:", sorted(srcs.items())[:20])
    print(f"log lines: {len(lines)}")
    for ln in lines[:40]:
        print("   ", ln)


if __name__ == "__main__":
    main()
