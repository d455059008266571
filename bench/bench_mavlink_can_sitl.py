"""Servos on ArduPlane SITL's own CAN port through MAVLink (``mavlink-can``), against the same
servos on an AA-55 adapter (the baseline), in one run; then an autopilot restart mid-run.

Run by hand, as root, in a network namespace that has only loopback (SITL binds 0.0.0.0 and
sends multicast)::

    unshare -n sh -c 'ip link set lo up; ip link set lo multicast on; \\
        ip route add 239.0.0.0/8 dev lo; \\
        python bench/bench_mavlink_can_sitl.py --arduplane /path/to/build/sitl/bin/arduplane'

Parts, all real: ArduPlane SITL (``CAN_P1_DRIVER 1``, ``CAN_D1_PROTOCOL 1``, SERIAL1 and SERIAL2
on UDP to 127.0.0.1:14551/14552), the project's simulated RMD-X servos on SITL's multicast CAN
(``sitl-mcast`` channel 0 = CAN_P1) and, for the baseline, the same servos behind the AA-55
adapter emulator on a pty; two ``mavservo run`` processes (A: ``mavlink-can`` channel 1 on
SERIAL1; B: ``aa55`` on the pty, MAVLink on SERIAL2), each mirroring SERVO_OUTPUT_RAW 1-4 to its
4 servos at the default rates. Phase 1: both for ``--seconds``. Phase 2: A alone; SITL killed at
``--restart-at`` s and started again ``--down-s`` later; the times from the kill to A's "stopped
forwarding" and "autopilot heartbeat lost" events, and from the relaunch to "back after".

Prints JSON: per bridge the frames lost, command interval sigma, round trip p50/p95 (ms), CPU
seconds (user+system from wait4) and CPU %, the ratios A/B; the restart times.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from mavservo.app.bridge import Bridge
from mavservo.config import load_config
from mavservo.sim.adapter import AdapterEmulator
from mavservo.sim.servo import SimServo
from mavservo.sim.virtual import VirtualServoBus

HERE = Path(__file__).resolve().parent
PACKAGE = HERE.parent / "mavservo" / "sim" / "autopilot"
SERVOS = 4
CAN_PARAMS = """CAN_P1_DRIVER 1
CAN_D1_PROTOCOL 1
SERIAL1_PROTOCOL 2
SERIAL2_PROTOCOL 2
"""


def config(url: str, bus: str, count: int = SERVOS, scheduler: str = "") -> str:
    servos = "\n".join(
        f"  - {{name: s{i}, profile: rmd-x, can_id: {i}}}" for i in range(1, count + 1)
    )
    channels = "\n".join(
        f"  - {{servo: s{i}, source: servo_output, channel: {i}, output_deg: [-90, 90]}}"
        for i in range(1, count + 1)
    )
    extra = f"scheduler: {scheduler}\n" if scheduler else ""
    return (
        f'mavlink: {{url: "{url}"}}\ncan:\n  buses: [{bus}]\n'
        f"servos:\n{servos}\nchannels:\n{channels}\n{extra}"
    )


def sitl_command(
    arduplane: str, home: Path, parm: Path, wipe: bool, serial1_tcp: bool = False
) -> list[str]:
    defaults = [
        home / "Tools/autotest/models/plane.parm",
        PACKAGE / "arduplane-companion.parm",
        parm,
    ]
    command = [
        arduplane,
        "--model",
        "plane",
        "--speedup",
        "1",
        "--defaults",
        ",".join(str(p) for p in defaults if p.exists()),
        "--serial0",
        "tcp:0",
        "--serial1",
        # SIM_BAUDLIMIT_EN on a UDP port: a datagram must hold whole MAVLink packets, and the
        # limiter allows only the bytes since its last call (libraries/AP_HAL/utility/
        # DataRateLimit.cpp l. 6-24; AP_HAL_SITL/UARTDriver.cpp l. 840-857), ~6 B a 1 ms
        # call at 57,600 baud: never a packet. A TCP port writes what the limit allows
        # (tcp:N listens on 5760 + N).
        "tcp:2" if serial1_tcp else "udpclient:127.0.0.1:14551",
        "--serial2",
        "udpclient:127.0.0.1:14552",
        "-I0",
    ]
    return command + (["-w"] if wipe else [])


def start_bridge(path: Path, logs: Path, seconds: float) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "mavservo",
            "run",
            str(path),
            "--duration",
            str(seconds),
            "--log-dir",
            str(logs),
            "-q",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


def wait_cpu(process: subprocess.Popen[bytes], timeout: float) -> float:
    """CPU seconds (user + system) of a finished child, from wait4."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        pid, status, usage = os.wait4(process.pid, os.WNOHANG)
        if pid:
            process.returncode = os.waitstatus_to_exitcode(status)
            return usage.ru_utime + usage.ru_stime
        time.sleep(0.1)
    process.kill()
    raise RuntimeError("bridge did not end")


def metrics_of(logs: Path) -> dict[str, Any]:
    (run,) = sorted(logs.iterdir())
    return json.loads((run / "metrics.json").read_text())


def metrics_of_after(process: subprocess.Popen[bytes], logs: Path, seconds: float) -> Any:
    """The metrics of a bridge run once it ended (its CPU too, in the figures)."""
    cpu = wait_cpu(process, seconds + 60)
    metrics = metrics_of(logs)
    metrics["_cpu_s"] = cpu
    return metrics


def start_periph(binary: str, home: Path, work: Path) -> subprocess.Popen[bytes]:
    """AP_Periph SITL (-I1: its ports off the vehicle's) on the vehicle's multicast CAN, with
    sim_vehicle's defaults for it; its clock runs on the vehicle's multicast state."""
    scratch = work / "periph"
    scratch.mkdir()
    parm = Path(binary).resolve().parents[3] / "Tools/autotest/default_params/periph.parm"
    if not parm.exists():
        parm = home / "Tools/autotest/default_params/periph.parm"
    command = [binary, "-I1"] + (["--defaults", str(parm)] if parm.exists() else [])
    log = open(work / "periph.log", "ab")  # noqa: SIM115 - kept for the child's life
    return subprocess.Popen(
        command, cwd=scratch, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT
    )


def link_rates(metrics: dict[str, Any]) -> dict[str, float]:
    """Frames per second on the MAVLink link for the mavlink-can bus: CAN_FRAME from the
    autopilot (every frame it forwarded: the servos' replies, and the 29-bit frames the bus
    ignored), and to it (the bridge's frames), over the run."""
    bus = next(iter(metrics["buses"].values()))
    transport = bus.get("transport", {})
    uptime = metrics["uptime_s"] or 1.0
    forwarded = transport.get("received", 0) + transport.get("ignored", 0)
    return {
        "from_autopilot": round(forwarded / uptime, 1),
        "of_them_29_bit": round(transport.get("ignored", 0) / uptime, 1),
        "to_autopilot": round(transport.get("sent", 0) / uptime, 1),
    }


def _print(out: dict[str, Any]) -> int:
    print(json.dumps(out, indent=1))
    return 0


def figures(metrics: dict[str, Any], cpu_s: float) -> dict[str, Any]:
    """The bridge's figures: replies lost, the command loop's period sigma (its ticks), the
    servos' round trip (frame written -> reply decoded, median over servos of each p50/p95),
    its CPU, the load stalls seen (longest command gap) and its bus events."""
    servos = metrics["servos"].values()
    bus = next(iter(metrics["buses"].values()))
    tick = bus["command_tick"]["interval"]
    p50 = statistics.median(s["latency_s"]["p50"] or math.nan for s in servos) * 1e3
    p95 = statistics.median(s["latency_s"]["p95"] or math.nan for s in servos) * 1e3
    uptime = metrics["uptime_s"]
    cpu_s = metrics.get("_cpu_s", cpu_s)
    return {
        "frames_sent": sum(s["frames"]["sent"] for s in servos),
        "replies": sum(s["frames"]["received"] for s in servos),
        "lost": sum(s["frames"]["lost"] for s in servos),
        "late": sum(s["frames"]["late"] for s in servos),
        "command_period_sigma_ms": round(tick["sigma"] * 1e3, 2),
        "command_period_p50_ms": round(tick["p50"] * 1e3, 2),
        "longest_command_gap_ms": round(bus["longest_command_gap_s"] * 1e3, 1),
        "round_trip_p50_ms": round(p50, 2),
        "round_trip_p95_ms": round(p95, 2),
        "cpu_s": round(cpu_s, 2),
        "cpu_percent": round(100 * cpu_s / uptime, 1),
        "events": metrics["events"],
        "transport": bus.get("transport", {}),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--arduplane", required=True)
    parser.add_argument("--seconds", type=float, default=120.0)
    parser.add_argument("--restart-at", type=float, default=15.0)
    parser.add_argument("--down-s", type=float, default=2.0)
    parser.add_argument("--restart-run-s", type=float, default=45.0)
    parser.add_argument("--servos", type=int, default=SERVOS)
    parser.add_argument("--scheduler", default="", help="YAML flow map for scheduler:")
    parser.add_argument(
        "--baud-limit",
        type=int,
        default=0,
        help="SERIAL1_BAUD (ArduPilot's code: 57 = 57,600) with SIM_BAUDLIMIT_EN 1",
    )
    parser.add_argument(
        "--tunnel-only", action="store_true", help="bridge A only: no baseline, no restart"
    )
    parser.add_argument(
        "--periph",
        default="",
        help="an AP_Periph SITL binary to put on the bus too (DroneCAN traffic of another node)",
    )
    parser.add_argument(
        "--no-autopilot-filter",
        action="store_true",
        help="bridge A's bus with options.filter_at_autopilot false (no CAN_FILTER_MODIFY)",
    )
    args = parser.parse_args()
    home = Path(args.arduplane).resolve().parents[3]
    work = Path(tempfile.mkdtemp(prefix="mavcan-bench-"))
    parm = work / "can.parm"
    # SERIAL1 on TCP then (see sitl_command): the limit applies from the start
    limit = f"SERIAL1_BAUD {args.baud_limit}\nSIM_BAUDLIMIT_EN 1\n" if args.baud_limit else ""
    parm.write_text(CAN_PARAMS + limit)
    out: dict[str, Any] = {"machine": os.uname().nodename, "cpus": os.cpu_count()}
    out["servos"], out["scheduler"], out["baud_limit"] = args.servos, args.scheduler, limit

    def launch(wipe: bool) -> subprocess.Popen[bytes]:
        log = open(work / "sitl.log", "ab")  # noqa: SIM115 - kept for the child's life
        return subprocess.Popen(
            sitl_command(args.arduplane, home, parm, wipe, serial1_tcp=bool(args.baud_limit)),
            cwd=work,
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
        )

    sitl = launch(wipe=True)
    periph = start_periph(args.periph, home, work) if args.periph else None
    mcast_servos = VirtualServoBus(
        [SimServo("rmd-x", i) for i in range(1, args.servos + 1)],
        channel=0,
        interface="sitl-mcast",
    ).start()
    emulator = AdapterEmulator([SimServo("rmd-x", i) for i in range(1, args.servos + 1)]).start()
    try:
        time.sleep(5.0)  # SITL boots
        a_cfg, b_cfg = work / "a.yaml", work / "b.yaml"
        a_cfg.write_text(
            config(
                "tcp:127.0.0.1:5762" if args.baud_limit else "udpin:127.0.0.1:14551",
                "{name: fc, interface: mavlink-can, channel: 1"
                + (", options: {filter_at_autopilot: false}}" if args.no_autopilot_filter else "}"),
                args.servos,
                args.scheduler,
            )
        )
        b_cfg.write_text(
            config(
                "udpin:127.0.0.1:14552",
                f'{{name: usb, interface: aa55, channel: "{emulator.path}"}}',
                args.servos,
                args.scheduler,
            )
        )
        if args.tunnel_only:
            a = start_bridge(a_cfg, work / "a", args.seconds)
            metrics = metrics_of_after(a, work / "a", args.seconds)
            out["mavlink_can"] = figures(metrics, 0.0)
            out["link_frames_per_s"] = link_rates(metrics)
            out["filter_at_autopilot"] = not args.no_autopilot_filter
            out["periph"] = bool(args.periph)
            return _print(out)
        a = start_bridge(a_cfg, work / "a", args.seconds)
        b = start_bridge(b_cfg, work / "b", args.seconds)
        a_cpu = wait_cpu(a, args.seconds + 60)
        b_cpu = wait_cpu(b, 30)
        fa = figures(metrics_of(work / "a"), a_cpu)
        fb = figures(metrics_of(work / "b"), b_cpu)
        out["mavlink_can"], out["aa55"] = fa, fb
        out["ratios_mavlink_can_over_aa55"] = {
            key: round(fa[key] / fb[key], 2) if fb[key] else None
            for key in (
                "round_trip_p50_ms",
                "round_trip_p95_ms",
                "command_period_sigma_ms",
                "cpu_s",
            )
        }
        # phase 2: the autopilot restarts under bridge A (in this process: event times)
        bridge = Bridge(load_config(a_cfg), log_dir=False).start()
        try:
            assert bridge.backend is not None
            backend = bridge.backend

            def all_online() -> bool:
                return all(s.online for s in backend.servo_statuses())

            start = time.monotonic()
            while not all_online() and time.monotonic() - start < 30:
                time.sleep(0.05)
            time.sleep(args.restart_at)
            killed_at = time.monotonic()
            sitl.send_signal(signal.SIGTERM)
            sitl.wait(10)
            offline_at = None
            while time.monotonic() - killed_at < args.down_s:
                if offline_at is None and not any(s.online for s in backend.servo_statuses()):
                    offline_at = time.monotonic()
                time.sleep(0.02)
            relaunched_at = time.monotonic()
            sitl = launch(wipe=False)
            online_at = None
            while time.monotonic() - relaunched_at < args.restart_run_s:
                if offline_at is None and not any(s.online for s in backend.servo_statuses()):
                    offline_at = time.monotonic()
                if all_online():
                    online_at = time.monotonic()
                    break
                time.sleep(0.02)
            time.sleep(2.0)
            events = list(bridge.events)
        finally:
            summary = bridge.stop()

        def first(text: str, after: float) -> float | None:
            times = [t for t, e in events if text in e and t >= after]
            return round(min(times) - after, 2) if times else None

        out["restart"] = {
            "down_s": args.down_s,
            "outage_detected_after_kill_s": first("stopped forwarding", killed_at),
            "servos_offline_after_kill_s": None
            if offline_at is None
            else round(offline_at - killed_at, 2),
            "failsafe_after_kill_s": first("heartbeat lost", killed_at),
            "bus_back_after_relaunch_s": first("back after", relaunched_at),
            "servos_online_after_relaunch_s": None
            if online_at is None
            else round(online_at - relaunched_at, 2),
            "failsafe_cleared_after_relaunch_s": first("failsafe cleared", relaunched_at),
            "events": [e for t, e in events if t >= killed_at - 1],
            "transport": summary["buses"]["fc"]["transport"],
        }
    finally:
        for child in (sitl, periph):
            if child is None:
                continue
            child.send_signal(signal.SIGTERM)
            try:
                child.wait(10)
            except subprocess.TimeoutExpired:
                child.kill()
        mcast_servos.stop()
        emulator.stop()
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
