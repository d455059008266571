"""Servo health bench (issue 33): how fast each simulated fault is found, and that nothing is
found where nothing is wrong.

Sections (``--only`` picks one; both run by default):

* ``detect``: the whole bridge on its simulated adapter, one servo per family kind (an RMD-X,
  polled at 11 Hz like config/sim.yaml's surfaces, reporting its supply every 10th poll; a
  CubeMars AK pushing at 20 Hz like the gimbal axes). Each fault is injected ``--trials``
  times on a fresh bridge and timed from the moment the fault exists physically to the
  bridge's health event (its console/event time, the moment the STATUSTEXT is queued):
  ``jammed`` from the output reaching the obstruction (the simulated servo's ``blocked``),
  ``slipping`` from the command the slipped motor cannot carry out, ``supply`` from the sag,
  ``overheated`` from the winding crossing the limit. Medians, min and max, in seconds.
* ``recorded``: config/ardupilot-sitl.yaml mirroring a real ArduPlane SITL session (the
  recorded tests/data/plane-servos.tlog, replayed in real time, 90 s): health events (must
  be 0). The stand-in for a live ArduPlane run where no SITL binary is built.
* ``quiet``: every shipped config on the built-in simulation (tests/support/health.py), the
  simulated autopilot's ``sweep`` and ``steps`` for ``--seconds`` each (60 by default), three
  bridges at a time: the health events (must be 0) and the states judged.

Run by hand; prints one JSON document::

    python bench/bench_health.py --trials 5 --seconds 60
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mavservo.app.bridge import Bridge, free_udp_port  # noqa: E402
from mavservo.config.loader import load_config_text  # noqa: E402
from mavservo.sim.servo import SimServo  # noqa: E402
from tests.support.health import SHIPPED, on_simulation, quiet_run  # noqa: E402

BODY = """
mavlink:
  url: udpin:127.0.0.1:{port}
  mirror: {{servo_output_raw: false}}
servos:
  - {{name: surface, profile: rmd-x, can_id: 1, limits_deg: [-60, 60], telemetry_hz: 11,
     health: {{temperature_warning_c: 40, temperature_limit_c: 50}}}}
  - {{name: axis, profile: cubemars-ak, can_id: 1, limits_deg: [-60, 60], telemetry_hz: 20,
     health: {{temperature_warning_c: 40, temperature_limit_c: 50}}}}
channels:
  - {{servo: surface, source: actuator, index: 1, output_deg: [-60, 60]}}
  - {{servo: axis, source: actuator, index: 2, output_deg: [-60, 60]}}
"""
ACTUATOR = {"surface": 1, "axis": 2}
FAULTS = ("jammed", "slipping", "supply", "overheated")
POLL_S = 0.002
TIMEOUT_S = 10.0


def sim_servo(bridge: Bridge, name: str) -> SimServo:
    cfg = bridge.config.servo(name)
    for servo in bridge.emulators[bridge.config.bus_of(cfg).name].servos:
        if servo.profile == cfg.profile and servo.can_id == cfg.can_id:
            return servo
    raise KeyError(name)


def wait_for(predicate: Callable[[], bool], timeout: float = TIMEOUT_S) -> float | None:
    """The monotonic time ``predicate`` first held (polled every 2 ms), None on timeout."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return time.monotonic()
        time.sleep(POLL_S)
    return None


def onset(sim: SimServo, condition: Callable[[SimServo], bool], timeout: float) -> float | None:
    """When ``condition`` of the simulated servo began: the servo's physics are integrated
    when a frame reaches it, so the last simulated time it did not hold is taken (an upper
    bound on the detection time, by at most one frame interval); None on timeout."""
    last_false: float | None = None
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        sim_time = sim.time
        if condition(sim):
            return last_false if last_false is not None else sim_time
        last_false = sim_time
        time.sleep(POLL_S)
    return None


def event_time(bridge: Bridge, fragment: str, after: float) -> float | None:
    """When the bridge noted an event containing ``fragment`` (its own monotonic stamp)."""
    found = wait_for(lambda: any(fragment in text for t, text in bridge.events if t >= after))
    if found is None:
        return None
    return min(t for t, text in bridge.events if t >= after and fragment in text)


def one_detection(servo_name: str, fault: str) -> float | None:
    """Seconds from the fault existing to the bridge's event; None if it never came."""
    port = free_udp_port()
    config = load_config_text(BODY.format(port=port), "<bench>")
    bridge = Bridge(config, log_dir=False, status=lambda line: None).start()
    try:
        backend = bridge.backend
        assert backend is not None
        sim = sim_servo(bridge, servo_name)
        if wait_for(lambda: all(s.online for s in backend.servo_statuses())) is None:
            return None
        _goal(bridge, servo_name, 0.0)
        wait_for(lambda: abs(sim.position_deg) < 0.5 and abs(sim.velocity_dps) < 1.0)
        time.sleep(0.5)
        start = time.monotonic()
        if fault == "jammed":
            sim.faults.jammed_at_deg = 20.0
            _goal(bridge, servo_name, 40.0)
            began = onset(sim, lambda s: s.blocked, TIMEOUT_S)
            fragment = f"{servo_name}: jammed"
        elif fault == "slipping":
            sim.faults.slipping = True
            began = time.monotonic()
            _goal(bridge, servo_name, 40.0)
            fragment = f"{servo_name}: slipping"
        elif fault == "supply":
            began = time.monotonic()
            sim.faults.supply_v = 18.0
            fragment = f"{servo_name}: supply"
        else:
            sim.physics.load_current = 2.0
            sim.physics.heating_c_per_a2s = 2.0  # 8 degC/s at 2 A
            began = onset(sim, lambda s: s.temperature_c >= 50.0, 30.0)
            fragment = f"{servo_name}: overheated"
        if began is None:
            return None
        found = event_time(bridge, fragment, start)
        return None if found is None else found - began
    finally:
        bridge.stop()


def _goal(bridge: Bridge, name: str, angle: float) -> None:
    """Send ``name`` to ``angle`` as a DO_SET_ACTUATOR does (the backend, minus the link)."""
    backend = bridge.backend
    assert backend is not None
    result = backend.apply_actuator(ACTUATOR[name], angle / 60.0, "bench", time.monotonic())
    assert result.ok, result


def detect(trials: int) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for servo in ("surface", "axis"):
        for fault in FAULTS:
            if servo == "axis" and fault == "supply":
                continue  # a CubeMars servo-mode reply carries no voltage
            times = [one_detection(servo, fault) for _ in range(trials)]
            found = [t for t in times if t is not None]
            out[f"{servo}/{fault}"] = {
                "trials": trials,
                "found": len(found),
                "median_s": statistics.median(found) if found else None,
                "min_s": min(found) if found else None,
                "max_s": max(found) if found else None,
                "all_s": [round(t, 3) for t in found],
            }
            print(fault, servo, out[f"{servo}/{fault}"], file=sys.stderr)
    return out


def quiet(seconds: float) -> dict[str, Any]:
    runs = [(path, profile) for path in SHIPPED for profile in ("sweep", "steps")]
    with tempfile.TemporaryDirectory() as tmp:

        def run(k: int) -> dict[str, Any]:
            path, profile = runs[k]
            key_dir = Path(tmp) / str(k)
            key_dir.mkdir()
            health = quiet_run(on_simulation(path, profile, key_dir), seconds)
            print(path.name, profile, health["episodes"], file=sys.stderr)
            return health

        with ThreadPoolExecutor(3) as pool:
            results = list(pool.map(run, range(len(runs))))
    out: dict[str, Any] = {}
    for (path, profile), health in zip(runs, results, strict=True):
        out[f"{path.name}/{profile}"] = {
            "episodes": health["episodes"],
            "events": [e["text"] for e in health["events"]],
            "judged_min": min(health["judged"].values()),
            "judged_total": sum(health["judged"].values()),
        }
    out["total_events"] = sum(
        sum(sum(checks.values()) for checks in health["episodes"].values()) for health in results
    )
    return out


def recorded() -> dict[str, Any]:
    tlog = Path(__file__).resolve().parents[1] / "tests" / "data" / "plane-servos.tlog"
    config_path = Path(__file__).resolve().parents[1] / "config" / "ardupilot-sitl.yaml"
    with tempfile.TemporaryDirectory() as tmp:
        config = on_simulation(config_path, "replay", Path(tmp), replay_file=tlog)
        health = quiet_run(config, 92.0)
    return {
        "episodes": health["episodes"],
        "events": [e["text"] for e in health["events"]],
        "judged_total": sum(health["judged"].values()),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", choices=("detect", "recorded", "quiet"))
    parser.add_argument("--trials", type=int, default=5)
    parser.add_argument("--seconds", type=float, default=60.0)
    args = parser.parse_args()
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=False
    ).stdout.strip()
    result: dict[str, Any] = {
        "machine": f"{platform.machine()} {platform.processor() or ''} {os.cpu_count()} CPUs",
        "python": platform.python_version(),
        "commit": commit,
        "load": os.getloadavg(),
    }
    if args.only in (None, "detect"):
        result["detect"] = detect(args.trials)
    if args.only in (None, "recorded"):
        result["recorded"] = recorded()
    if args.only in (None, "quiet"):
        result["quiet"] = quiet(args.seconds)
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    threading.current_thread().name = "bench-health"
    raise SystemExit(main())
