"""A command flood from 250 spoofed ids while the autopilot keeps sending (issue 40), by hand.

    PYTHONPATH=. python bench/bench_unsigned_flood.py --seconds 60 --runs 3
    PYTHONPATH=. python bench/bench_unsigned_flood.py --backlog --runs 3   # as root
    cd /tmp && PYTHONPATH=/path/to/old/checkout python /path/to/bench/bench_unsigned_flood.py ...

The bridge runs in this process on an unsigned ``udpin`` link (servo component 140 and a
3-axis gimbal 154 of simulated CubeMars servos on the in-process AA-55 emulator, the default
telemetry rates and link budget, ``heartbeat_timeout_s`` 2). Two child processes (their own
interpreters, so neither shares the bridge's GIL):

* the autopilot on 127.0.0.1: HEARTBEAT at 1 Hz and SERVO_OUTPUT_RAW at 20 Hz, and it records
  every byte the bridge sends to its address (with the time);
* the flooder on 127.0.0.66 (another address): ``--rate`` commands a second, paced in 5 ms
  batches, half REQUEST_MESSAGE (of messages the bridge publishes, or not) and half
  SET_MESSAGE_INTERVAL (at the configured rates, so accepted or refused, never a stop), to
  1/140 and 1/154 in turn, each from the next of 250 spoofed system ids.

Each run: one bridge and one autopilot throughout, first ``--baseline`` seconds without the
flooder (the same session's baseline), then ``--seconds`` with it (its first second, the
flooder's start, left out). Reported per phase and run, and the medians over runs:

* ``false_failsafes``: the bridge's failsafe count (the autopilot never stopped);
* ``hb_age_p99_ms`` / ``hb_age_max_ms``: the age of the autopilot's last HEARTBEAT as the
  watchdog sees it, sampled every 10 ms (1 Hz heartbeats: about 1,000 ms when nothing delays
  them; the failsafe fires at 2,000);
* ``gimbal_status_hz_min`` / ``_mean``: GIMBAL_DEVICE_ATTITUDE_STATUS the autopilot received
  per whole second (ArduPilot wants 5 Hz at least);
* ``busiest_window_bytes``: the most bytes the autopilot's address received in any 1-s
  window (sliding, by receipt time), and ``link_budget_bytes_s`` the plan's budget;
* ``udp_shed`` / ``udp_kernel_drops``: stranger datagrams shed by the bridge, datagrams the
  kernel dropped.

Not a test: no thresholds, just figures. The machine's load average goes in the output.
"""

from __future__ import annotations

import argparse
import bisect
import contextlib
import json
import os
import signal
import socket
import statistics
import subprocess
import sys
import threading
import time
from typing import Any

os.environ.setdefault("MAVLINK20", "1")

BATCH_S = 0.005
STRANGER_HOST = "127.0.0.66"
SPOOFED_IDS = 250
REQUEST_MESSAGE = 512
SET_MESSAGE_INTERVAL = 511
#: GIMBAL_DEVICE_ATTITUDE_STATUS, ACTUATOR_OUTPUT_STATUS, ESC_TELEMETRY_1_TO_4, HEARTBEAT,
#: COMPONENT_METADATA, AUTOPILOT_VERSION (not published)
REQUESTED = (285, 375, 11030, 0, 397, 148)
#: (message id, interval in us) at the configured rates: accepted, or refused for rate
INTERVALS = ((285, 100_000), (375, 100_000), (11030, 250_000))
GIMBAL_STATUS = "GIMBAL_DEVICE_ATTITUDE_STATUS"
#: what the flooder sends: "both" (the issue's flood), "request" or "interval" only
KINDS = os.environ.get("FLOOD_KINDS", "both")


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def config_text(port: int) -> str:
    def servo(name: str, can_id: int, limits: str) -> str:
        return (
            f"  - {{name: {name}, profile: cubemars-ak, can_id: {can_id}, limits_deg: {limits},"
            " telemetry_hz: 20, failsafe: {action: neutral, timeout_s: 1.0}}\n"
        )

    return (
        f"mavlink: {{url: 'udpin:127.0.0.1:{port}', system_id: 1, heartbeat_timeout_s: 2.0}}\n"
        "can:\n  buses: [{name: bus0, interface: aa55, channel: sim}]\n"
        "servos:\n"
        "  - {name: throttle, profile: rmd-x, can_id: 3, limits_deg: [0, 90],"
        " failsafe: {action: position, position_deg: 0, timeout_s: 0.5}}\n"
        + servo("gimbal_roll", 1, "[-30, 30]")
        + servo("gimbal_pitch", 2, "[-90, 30]")
        + servo("gimbal_yaw", 3, "[-160, 160]")
        + "channels:\n"
        "  - {servo: throttle, source: servo_output, channel: 3, input: {min: 1000, max: 2000}}\n"
        "gimbals:\n"
        "  - {name: gimbal, component_id: 154, roll: gimbal_roll, pitch: gimbal_pitch,"
        " yaw: gimbal_yaw, limits_deg: {roll: [-30, 30], pitch: [-90, 30], yaw: [-160, 160]}}\n"
    )


# ------------------------------------------------------------------ child processes


def autopilot(port: int, seconds: float) -> None:
    """HEARTBEAT 1 Hz + SERVO_OUTPUT_RAW 20 Hz until SIGTERM (or ``seconds``); records what
    arrives (monotonic time, bytes, type) and prints it at the end."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.005)
    encoder = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    decoder = mavlink2.MAVLink(None)
    decoder.robust_parsing = True
    target = ("127.0.0.1", port)
    start = time.monotonic()
    next_beat = next_servo = start
    received: list[tuple[float, int, str]] = []
    stopping: list[int] = []  # SIGTERM: stop, and print what arrived
    signal.signal(signal.SIGTERM, lambda *_: stopping.append(1))
    while (now := time.monotonic()) < start + seconds and not stopping:
        if now >= next_beat:
            sock.sendto(encoder.heartbeat_encode(1, 3, 81, 0, 4).pack(encoder), target)
            next_beat += 1.0
        if now >= next_servo:
            pwm = [1500 + int(400 * ((now * 0.5) % 1.0))] * 16
            msg = encoder.servo_output_raw_encode(int(now * 1e6) & 0xFFFFFFFF, 0, *pwm)
            sock.sendto(msg.pack(encoder), target)
            next_servo += 0.05
        try:
            data = sock.recv(65535)
        except TimeoutError:
            continue
        t = time.monotonic()  # the system-wide monotonic clock: the parent's too
        for msg in decoder.parse_buffer(data) or []:
            received.append((t, len(msg.get_msgbuf()), msg.get_type()))
    print(json.dumps(received))


def flooder(port: int, rate: float, seconds: float) -> None:
    """``rate`` commands/s from 250 spoofed ids on another address, for ``seconds``."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind((STRANGER_HOST, 0))
    encoder = mavlink2.MAVLink(None, srcSystem=2, srcComponent=190)
    target = ("127.0.0.1", port)
    start = time.monotonic()
    sent = 0
    while (now := time.monotonic()) < start + seconds:
        due = int((now - start) * rate)
        while sent < due:
            encoder.srcSystem = 2 + sent % SPOOFED_IDS
            component = 140 if (sent // 2) % 2 else 154
            if KINDS == "interval" or (KINDS == "both" and sent % 2):
                msg_id, interval = INTERVALS[(sent // 2) % len(INTERVALS)]
                msg = encoder.command_long_encode(
                    1, component, SET_MESSAGE_INTERVAL, 0, msg_id, interval, 0, 0, 0, 0, 0
                )
            else:
                msg_id = REQUESTED[(sent // 2) % len(REQUESTED)]
                msg = encoder.command_long_encode(
                    1, component, REQUEST_MESSAGE, 0, msg_id, 0, 0, 0, 0, 0, 0
                )
            with contextlib.suppress(OSError):
                sock.sendto(msg.pack(encoder), target)
            sent += 1
        time.sleep(BATCH_S)
    print(json.dumps({"sent": sent, "seconds": time.monotonic() - start}))


# ------------------------------------------------------------------ measuring


def busiest_window(received: list[tuple[float, int, str]]) -> int:
    times = [t for t, _, _ in received]
    sizes = [n for _, n, _ in received]
    best = total = 0
    left = 0
    for right in range(len(times)):
        total += sizes[right]
        while times[right] - times[left] >= 1.0:
            total -= sizes[left]
            left += 1
        best = max(best, total)
    return best


def gimbal_rates(received: list[tuple[float, int, str]], start: float, end: float) -> list[int]:
    """GIMBAL_DEVICE_ATTITUDE_STATUS per whole second from ``start`` to ``end``."""
    times = sorted(t for t, _, kind in received if kind == GIMBAL_STATUS)
    return [
        bisect.bisect_left(times, start + s + 1.0) - bisect.bisect_left(times, start + s)
        for s in range(int(end - start))
    ]


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))] if ordered else float("nan")


def figures(
    received: list[tuple[float, int, str]],
    ages: list[tuple[float, float]],
    start: float,
    end: float,
) -> dict[str, Any]:
    """The figures of one phase, ``start`` to ``end`` (monotonic seconds)."""
    inside = [r for r in received if start <= r[0] < end]
    phase_ages = [age for t, age in ages if start <= t < end]
    rates = gimbal_rates(received, start, end)
    return {
        "hb_age_p99_ms": round(percentile(phase_ages, 0.99) * 1e3, 1),
        "hb_age_max_ms": round(max(phase_ages) * 1e3, 1) if phase_ages else None,
        "gimbal_status_hz_min": min(rates) if rates else 0,
        "gimbal_status_hz_mean": round(statistics.fmean(rates), 2) if rates else 0,
        "busiest_window_bytes": busiest_window(inside),
    }


def run_once(seconds: float, baseline: float, rate: float) -> dict[str, Any]:
    """One bridge, one autopilot for the whole run; the flooder after ``baseline`` seconds."""
    from mavservo.app.bridge import Bridge
    from mavservo.config.loader import load_config_text

    port = free_udp_port()
    bridge = Bridge(load_config_text(config_text(port)), log_dir=False).start()
    side = bridge.mavlink
    ages: list[tuple[float, float]] = []
    stop = threading.Event()

    def sample() -> None:
        while not stop.wait(0.01):
            last = side.core.watchdog.last_heartbeat
            if last is not None:
                now = time.monotonic()
                ages.append((now, now - last))

    sampler = threading.Thread(target=sample, daemon=True)
    total = baseline + seconds + 2.0
    try:
        time.sleep(1.0)  # servos online
        pilot = subprocess.Popen(
            [sys.executable, __file__, "--autopilot", str(port), str(total + 30.0)],
            stdout=subprocess.PIPE,
            text=True,
        )
        for _ in range(3000):  # bounded: the autopilot's first heartbeat (its start is slow)
            if side.core.watchdog.last_heartbeat is not None:
                break
            time.sleep(0.01)
        failsafes0 = side.stats()["failsafe_count"]
        sampler.start()
        quiet_start = time.monotonic()
        time.sleep(baseline)
        flood_start = time.monotonic()
        flood = subprocess.run(
            [sys.executable, __file__, "--flooder", str(port), str(rate), str(seconds)],
            capture_output=True,
            text=True,
            timeout=seconds + 60,
            check=True,
        )
        flood_end = time.monotonic()
        stats = side.stats()
        pilot.terminate()
        output = pilot.communicate(timeout=30)[0]
    finally:
        stop.set()
        bridge.stop()
    received = json.loads(output.strip().splitlines()[-1]) if output.strip() else []
    sent = json.loads(flood.stdout.strip().splitlines()[-1])
    return {
        "baseline": figures(received, ages, quiet_start, flood_start),
        "flood": {
            **figures(received, ages, flood_start + 1.0, flood_end),  # flooder's own start
            "false_failsafes": stats["failsafe_count"] - failsafes0,
            "flood_sent_per_s": round(sent["sent"] / sent["seconds"], 1),
            "udp_shed": stats["link"].get("udp_shed"),
            "udp_kernel_drops": stats["link"].get("udp_kernel_drops"),
            "link_budget_bytes_s": stats["link_budget"]["budget_bytes_s"],
        },
    }


def backlog_once(datagrams: int = 10_000, frames: int = 4) -> dict[str, Any]:
    """``datagrams`` stranger datagrams (``frames`` commands each, 250 spoofed ids, anyone
    may command) queued in the socket while the MAVLink side is held, then the autopilot's
    HEARTBEAT: how long after the release the heartbeat is handled. Needs SO_RCVBUFFORCE
    (root) for a socket buffer that holds them all."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    from mavservo.app.bridge import Bridge
    from mavservo.config.loader import load_config_text

    port = free_udp_port()
    bridge = Bridge(load_config_text(config_text(port)), log_dir=False).start()
    side = bridge.mavlink
    pilot = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    stranger.bind((STRANGER_HOST, 0))
    try:
        force = getattr(socket, "SO_RCVBUFFORCE", 33)
        side.link._conn._sock.setsockopt(socket.SOL_SOCKET, force, 64 << 20)  # noqa: SLF001
        ap = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        spoof = mavlink2.MAVLink(None, srcSystem=2, srcComponent=190)
        target = ("127.0.0.1", port)
        pilot.sendto(ap.heartbeat_encode(1, 3, 81, 0, 4).pack(ap), target)
        for _ in range(500):  # bounded: the first heartbeat armed the watchdog
            if side.core.watchdog.last_heartbeat is not None:
                break
            time.sleep(0.01)
        with side._lock:  # noqa: SLF001 - both MAVLink threads wait: an exact backlog
            for n in range(datagrams):
                data = b""
                for k in range(frames):
                    spoof.srcSystem = 2 + (n * frames + k) % SPOOFED_IDS
                    command = SET_MESSAGE_INTERVAL if k % 2 else REQUEST_MESSAGE
                    msg = spoof.command_long_encode(1, 140, command, 0, 375, 1e5, 0, 0, 0, 0, 0)
                    data += msg.pack(spoof)
                stranger.sendto(data, target)
            pilot.sendto(ap.heartbeat_encode(1, 3, 81, 0, 4).pack(ap), target)
            before = side.core.watchdog.last_heartbeat
            released = time.monotonic()
        handled = None
        for _ in range(3000):  # bounded: 30 s
            if side.core.watchdog.last_heartbeat != before:
                handled = time.monotonic() - released
                break
            time.sleep(0.01)
        time.sleep(0.5)
        link = side.stats()["link"]
    finally:
        pilot.close()
        stranger.close()
        bridge.stop()
    return {
        "heartbeat_handled_after_s": None if handled is None else round(handled, 3),
        "udp_shed": link.get("udp_shed"),
        "udp_kernel_drops": link.get("udp_kernel_drops"),
    }


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--autopilot":
        autopilot(int(sys.argv[2]), float(sys.argv[3]))
        return
    if len(sys.argv) > 1 and sys.argv[1] == "--flooder":
        flooder(int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4]))
        return
    import logging

    logging.basicConfig(level=logging.ERROR)
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--baseline", type=float, default=10.0)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument(
        "--backlog",
        action="store_true",
        help="10,000 stranger datagrams queued ahead of a heartbeat",
    )
    args = parser.parse_args()
    import mavservo

    print(f"mavservo from {os.path.dirname(mavservo.__file__)}; load {os.getloadavg()}")
    if args.backlog:
        for n in range(args.runs):
            print(f"backlog run {n + 1}: {json.dumps(backlog_once())}", flush=True)
        return
    runs = []
    for n in range(args.runs):
        result = run_once(args.seconds, args.baseline, args.rate)
        runs.append(result)
        print(f"run {n + 1}: {json.dumps(result)}", flush=True)
    for part in ("baseline", "flood"):
        medians = {
            key: statistics.median(r[part][key] for r in runs)
            for key in runs[0][part]
            if all(isinstance(r[part][key], int | float) for r in runs)
        }
        print(f"median {part}: {json.dumps(medians)}")
    print(f"false failsafes in all: {sum(r['flood']['false_failsafes'] for r in runs)}")
    print(f"load at the end {os.getloadavg()}")


if __name__ == "__main__":
    main()
