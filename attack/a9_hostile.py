"""Promise 9: hostile values in every command and message the bridge handles: exactly one
COMMAND_ACK per addressed command, never a traceback, at most one log line per kind of problem
per interval. Also: the allowed_sources refusal path, floods of STATUSTEXT / PARAM requests.

Commands are sent one at a time from the GCS with a unique (command, params) and the ACKs are
read until the next one goes out; ACKs are matched by the command id and source component.

Usage: python attack/a9_hostile.py [cmds|msgs|allowed]
"""

from __future__ import annotations

import itertools
import math
import sys
import time
from collections import Counter

from harness import BridgeProc, collect, peer

NAN, INF = float("nan"), float("inf")
HOSTILE = [NAN, INF, -INF, 3.4e38, -3.4e38, 1e9, -1e9, -1.0, 0.0, 2.0**31, 2.0**24, 1e-45]
COMMANDS = [183, 184, 187, 511, 512, 205, 1000, 1001, 204, 4242]


def acks_for(conn, first_within: float, then: float) -> list:
    """ACKs until ``first_within`` passes without one, then ``then`` more seconds (bounded)."""
    out = []
    deadline = time.monotonic() + first_within
    for _ in range(1000):
        rem = deadline - time.monotonic()
        if rem <= 0:
            break
        m = conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=rem)
        if m is not None:
            out.append(m)
            deadline = min(deadline, time.monotonic() + then)
    return out


def cmds(targets=(140, 154, 0)) -> None:
    bridge = BridgeProc("cfg_mgr.yaml", duration=110)
    bridge.wait_ready()
    gcs = peer(bridge.port)
    gcs.mav.heartbeat_send(6, 8, 0, 0, 4)
    base = {
        183: [9, 1500, 0, 0, 0, 0, 0],
        184: [10, 1500, 2, 1, 0, 0, 0],
        187: [0.5, NAN, NAN, NAN, NAN, NAN, 0],
        511: [33, 100000, 0, 0, 0, 0, 0],
        512: [33, 0, 0, 0, 0, 0, 0],
        205: [10, 0, 20, 0, 0, 0, 2],
        1000: [10, 20, NAN, NAN, 0, 0, 0],
        1001: [-1, -1, -1, -1, 0, 0, 0],
        204: [2, 0, 0, 0, 0, 0, 0],
        4242: [0] * 7,
    }
    sent = Counter()
    got = Counter()
    extra = []
    n = 0
    for command, target, kind, param, value in itertools.product(
        COMMANDS, targets, ("long", "int"), range(7), HOSTILE
    ):
        p = list(base[command])
        p[param] = value
        if kind == "long":
            gcs.mav.command_long_send(1, target, command, 0, *p)
        else:
            x = p[4] if param != 4 else value
            y = p[5] if param != 5 else value
            xi = int(max(-(2**31), min(2**31 - 1, x if math.isfinite(x) else 0)))
            yi = int(max(-(2**31), min(2**31 - 1, y if math.isfinite(y) else 0)))
            gcs.mav.command_int_send(
                1, target, 0, command, 0, 0, p[0], p[1], p[2], p[3], xi, yi, p[6]
            )
        n += 1
        acks = acks_for(gcs, 0.25 if target else 0.02, 0.02)
        if target and len(acks) != 1:
            print(
                "  !",
                command,
                target,
                kind,
                "param",
                param + 1,
                value,
                "->",
                [(a.command, a.get_srcComponent(), a.result) for a in acks],
            )
        if not target and acks:
            print(
                "  broadcast",
                command,
                kind,
                "param",
                param + 1,
                value,
                "->",
                [(a.command, a.get_srcComponent(), a.result) for a in acks],
            )
        # ACKs may trail into the next slot: collect generously, match by totals below
        for a in acks:
            got[(a.command, a.get_srcComponent())] += 1
        if target != 0:
            sent[(command, target)] += 1
        extra.append(len(acks))
    for a in collect(gcs, 1.0, "COMMAND_ACK"):
        got[(a.command, a.get_srcComponent())] += 1
    rc = bridge.finish()
    print(f"cmds: {n} hostile commands sent (addressed: {sum(sent.values())}); exit={rc}")
    bad = {k: (sent[k], got.get(k, 0)) for k in sent if sent[k] != got.get(k, 0)}
    print("addressed (cmd,comp) with sent != acked:", bad or "none")
    bc = {k: v for k, v in got.items() if k not in sent}
    print("ACKs for (cmd, comp) never addressed (broadcast answers):", bc)
    report_logs(bridge)


def report_logs(bridge: BridgeProc) -> None:
    lines = bridge.log_lines()
    tb = [ln for ln in lines if "Traceback" in ln]
    print(f"log lines: {len(lines)}, traceback lines: {len(tb)}")
    kinds = Counter()
    for ln in lines:
        parts = ln.split(" ", 4)
        if len(parts) >= 5 and parts[2] in ("WARNING", "ERROR", "INFO"):
            kinds[(parts[2], parts[3], " ".join(parts[4].split()[:4]))] += 1
    for k, v in kinds.most_common(25):
        print(f"   {v:6d} {k}")
    for ln in lines:
        if "Traceback" in ln or "Error" in ln:
            print("   !", ln[:300])
            break
    st = bridge.mavlink_stats()
    print("   commands:", st.get("commands"))
    print("   core:", st.get("core"), "link:", st.get("link"))


def msgs() -> None:
    bridge = BridgeProc("cfg_mgr.yaml", duration=40)
    bridge.wait_ready()
    gcs = peer(bridge.port)
    ap = peer(bridge.port, source=(1, 1))  # spoofs the autopilot (signing off)
    gcs.mav.heartbeat_send(6, 8, 0, 0, 4)
    qs = [
        [NAN] * 4,
        [0.0] * 4,
        [INF, 0.0, 0.0, 0.0],
        [3.4e38, 3.4e38, 0.0, 0.0],
        [1.0, 0.0, 0.0, 0.0],
        [1e-30, 0.0, 0.0, 0.0],
        [-INF, NAN, 1.0, 0.0],
        [0.5, 0.5, 0.5, 0.5],
        [1e19, 1e19, 1e19, 1e19],
    ]
    n = 0
    for _rnd in range(20):
        for q in qs:
            for v in HOSTILE:
                for tgt in (154, 0):
                    gcs.mav.gimbal_device_set_attitude_send(1, tgt, 0, q, v, v, v)
                    gcs.mav.gimbal_manager_set_attitude_send(1, tgt, 0, 0, q, v, v, v)
                    gcs.mav.gimbal_manager_set_pitchyaw_send(1, tgt, 0, 0, v, v, v, v)
                ap.mav.autopilot_state_for_gimbal_device_send(
                    1, 154, 0, q, 0, v, v, v, 0, v, 0, 0, v
                )
                ap.mav.attitude_send(0, v, v, v, v, v, v)
                pw = int(v) & 0xFFFF if math.isfinite(v) and abs(v) < 1e18 else 65535
                ap.mav.servo_output_raw_send(0, 0, *[pw] * 8, *[pw] * 8)
                ap.mav.actuator_output_status_send(0, 0xFFFFFFFF, [v] * 32)
                n += 9
            time.sleep(0.02)
        gcs.mav.statustext_send(6, b"x" * 50)
        gcs.mav.param_request_list_send(1, 0)
        gcs.mav.param_request_read_send(1, 140, b"SERVO1_MIN", -1)
        collect(gcs, 0.01)
    # the bridge still answers
    gcs.mav.command_long_send(1, 140, 183, 0, 9, 1900, 0, 0, 0, 0, 0)
    ok = [a.result for a in collect(gcs, 1.0, "COMMAND_ACK")]
    rc = bridge.finish()
    print(f"msgs: {n} hostile messages; ACK of a command afterwards={ok}; exit={rc}")
    report_logs(bridge)


def allowed() -> None:
    """allowed_sources set, signing off: frames from a source not in the list."""
    bridge = BridgeProc("cfg_allowed.yaml", duration=10)
    bridge.wait_ready()
    rogue = peer(bridge.port, source=(66, 190))
    n = 0
    for i in range(2000):
        rogue.mav.param_request_list_send(1, 0)
        n += 1
        if i % 200 == 0:
            time.sleep(0.05)
    time.sleep(1.0)
    rc = bridge.finish()
    lines = [ln for ln in bridge.log_lines() if "allowed_sources" in ln]
    st = bridge.mavlink_stats()
    print(
        f"allowed: {n} PARAM_REQUEST_LIST from 66/190 (not allowed); exit={rc}; "
        f"rejected_source={st['core'].get('rejected_source')}; log lines about it={len(lines)}"
    )
    for ln in lines[:3]:
        print("   ", ln)


if __name__ == "__main__":
    todo = {
        "cmds": cmds,
        "msgs": msgs,
        "allowed": allowed,
        "addressed": lambda: cmds((140, 154)),
        "broadcast": lambda: cmds((0,)),
    }
    for name in sys.argv[1:] or list(todo):
        todo[name]()
