"""Promise 10: a 5,000/s DO_SET_SERVO flood (plus distinct-key commands that each make a retry
table entry): the bridge stays responsive (a second GCS's command is ACKed and applied, its
latency measured) and its memory stays bounded (RSS of the bridge process before/after).

Usage: python attack/a10_flood.py [seconds]
"""

from __future__ import annotations

import random
import sys
import time

from harness import BridgeProc, collect, peer


def rss_kb(pid: int) -> int:
    with open(f"/proc/{pid}/status") as status:
        for line in status:
            if line.startswith("VmRSS"):
                return int(line.split()[1])
    return -1


def main() -> None:
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 20
    bridge = BridgeProc("cfg_open.yaml", duration=seconds + 12)
    bridge.wait_ready()
    pid = bridge.proc.pid
    flooder = peer(bridge.port, source=(66, 190))
    flooder.mav.heartbeat_send(6, 8, 0, 0, 4)
    gcs = peer(bridge.port)
    gcs.mav.heartbeat_send(6, 8, 0, 0, 4)
    time.sleep(0.5)
    rss0 = rss_kb(pid)
    rnd = random.Random(1)
    sent = 0
    probes = []
    t_end = time.monotonic() + seconds
    next_probe = time.monotonic() + 1.0
    rss_samples = []
    for _ in range(10_000_000):
        now = time.monotonic()
        if now >= t_end:
            break
        t_batch = now
        for _ in range(50):  # 50 per 10 ms = 5,000/s
            kind = rnd.random()
            if kind < 0.5:
                flooder.mav.command_long_send(
                    1,
                    140,
                    183,
                    0,
                    rnd.choice((1, 2, 3, 4, 9, 10)),
                    rnd.uniform(1100, 1900),
                    0,
                    0,
                    0,
                    0,
                    0,
                )
            else:  # distinct generic keys: (target component, command)
                flooder.mav.command_long_send(
                    1, rnd.choice((0, 140, 154)), rnd.randrange(0, 65536), 0, 0, 0, 0, 0, 0, 0, 0
                )
            sent += 1
        if now >= next_probe:
            next_probe = now + 1.0
            collect(gcs, 0.001)
            t0 = time.monotonic()
            gcs.mav.command_long_send(
                1, 140, 183, 0, 10, 1100 + 800 * (len(probes) % 2), 0, 0, 0, 0, 0
            )
            got = None
            for _ in range(1000):
                rem = t0 + 0.5 - time.monotonic()
                if rem <= 0:
                    break
                m = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=rem)
                if m is not None and m.command == 183 and m.target_system == 255:
                    got = round((time.monotonic() - t0) * 1000, 1)
                    break
            probes.append(got)
            rss_samples.append(rss_kb(pid))
        collect(flooder, 0.0005)
        sleep = 0.01 - (time.monotonic() - t_batch)
        if sleep > 0:
            time.sleep(sleep)
    rss1 = rss_kb(pid)
    rc = bridge.finish()
    st = bridge.mavlink_stats()
    print(f"flood: {sent} commands in {seconds:.0f} s ({sent / seconds:.0f}/s) exit={rc}")
    print(f"probe ACK latency ms (None = no ACK within 0.5 s): {probes}")
    print(f"RSS kB: before {rss0}, per second {rss_samples}, after {rss1}")
    print("commands:", st["commands"])
    print("link:", st["link"])
    print(
        "log lines:",
        len(bridge.log_lines()),
        "tracebacks:",
        sum("Traceback" in ln for ln in bridge.log_lines()),
    )


if __name__ == "__main__":
    main()
