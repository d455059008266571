"""How fast an adapter unplug takes pushing servos offline, next to a polled one (baseline).

One bridge on the adapter emulator: a polled RMD-X (``telemetry_hz`` 10, the baseline) and two
uncommanded CubeMars AK that push at 10 Hz and 20 Hz. Each cycle waits until all report, pulls
the adapter, times when each servo reads offline, plugs it back, and times when each is online
again. Before the push-liveness rule the CubeMars servos never went offline (``never`` counts
them). Run by hand; prints one JSON document::

    python bench/bench_push_liveness.py --cycles 10
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import subprocess
import time
from collections.abc import Callable
from typing import Any

from mavservo.app.bridge import Bridge, free_udp_port
from mavservo.config.loader import load_config_text

SERVOS = {
    "polled_rmd_10hz": "{profile: rmd-x, can_id: 1, telemetry_hz: 10}",
    "push_cubemars_10hz": "{profile: cubemars-ak, can_id: 2, telemetry_hz: 10}",
    "push_cubemars_20hz": "{profile: cubemars-ak, can_id: 3, telemetry_hz: 20}",
}
POLL_S = 0.002
WAIT_S = 10.0


def config_text(port: int) -> str:
    servos = "\n".join(
        f"  - {{name: {name}, limits_deg: [-90, 90], {spec[1:]}" for name, spec in SERVOS.items()
    )
    mavlink = f"mavlink:\n  url: udpin:127.0.0.1:{port}\n  heartbeat_timeout_s: 600\n"
    return f"{mavlink}servos:\n{servos}\n"


def online(bridge: Bridge) -> dict[str, bool]:
    return {s.name: s.online for s in bridge.backend.servo_statuses()}


def reporting(bridge: Bridge) -> bool:
    return all(s.online and s.state is not None for s in bridge.backend.servo_statuses())


def times_until(bridge: Bridge, wanted: bool, timeout: float) -> dict[str, float | None]:
    """Seconds until each servo's online flag equals ``wanted`` (None: not within timeout)."""
    start = time.monotonic()
    seen: dict[str, float | None] = {name: None for name in SERVOS}
    while time.monotonic() - start < timeout and any(v is None for v in seen.values()):
        now = time.monotonic() - start
        for name, flag in online(bridge).items():
            if seen[name] is None and flag == wanted:
                seen[name] = now
        time.sleep(POLL_S)
    return seen


def wait(condition: Callable[[], bool], timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.01)
    return condition()


def summary(samples: list[float | None]) -> dict[str, Any]:
    done = [s for s in samples if s is not None]
    return {
        "median_s": round(statistics.median(done), 4) if done else None,
        "max_s": round(max(done), 4) if done else None,
        "never": len(samples) - len(done),
    }


def run(cycles: int, unplug_s: float) -> dict[str, Any]:
    bridge = Bridge(load_config_text(config_text(free_udp_port())), log_dir=False).start()
    emulator = bridge.emulators["bus0"]
    offline: dict[str, list[float | None]] = {name: [] for name in SERVOS}
    back: dict[str, list[float | None]] = {name: [] for name in SERVOS}
    try:
        for _ in range(cycles):
            wait(lambda: reporting(bridge), WAIT_S)
            time.sleep(0.5)
            emulator.unplug()
            for name, t in times_until(bridge, False, max(unplug_s, 3.0)).items():
                offline[name].append(t)
            time.sleep(max(0.0, unplug_s - 3.0))
            emulator.replug()
            for name, t in times_until(bridge, True, WAIT_S).items():
                back[name].append(t)
    finally:
        bridge.stop()
    return {
        "cycles": cycles,
        "unplug_to_offline": {name: summary(v) for name, v in offline.items()},
        "replug_to_online": {name: summary(v) for name, v in back.items()},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=10)
    parser.add_argument("--unplug-s", type=float, default=3.0)
    args = parser.parse_args()
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=False
    ).stdout.strip()
    out = {
        "machine": f"{platform.node()} {platform.processor() or platform.machine()}",
        "python": platform.python_version(),
        "commit": commit,
        **run(args.cycles, args.unplug_s),
    }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
