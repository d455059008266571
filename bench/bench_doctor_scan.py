"""How long ``mavservo doctor --scan FAMILY`` takes over a family's whole id range at 1 Mbit/s.

Each run starts the simulated adapter (AA-55, or LAWICEL/slcan through python-can's ``slcan``)
with one servo of the family at a known id, and times :meth:`BusDoctor.scan` over the family's
full range (safe requests only, in batches of ``session.BATCH`` with ``session.REPLY_WAIT_S``
for the replies), checking that the servo was found. Prints one JSON document with the median
and the spread of ``--runs`` runs per family and adapter. Families whose motors answer no safe
request (CubeMars servo mode and ODrive push, MIT mode answers only when enabled, DroneCAN
nodes send NodeStatus) have nothing to scan: the doctor finds them by listening.

    python bench/bench_doctor_scan.py --runs 5
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from mavservo.app.doctor.session import BATCH, REPLY_WAIT_S, BusDoctor  # noqa: E402
from mavservo.config import load_config_text  # noqa: E402
from mavservo.servos import get_profile  # noqa: E402
from mavservo.sim.bus_simulation import simulator_factory  # noqa: E402
from mavservo.transport.bus_factory import BusRequest, open_bus  # noqa: E402

#: family -> the id its one simulated servo answers on (the middle of the range)
FAMILIES = {"rmd-x": 17, "lk": 17, "damiao-dm": 64}


def one_scan(family: str, can_id: int, interface: str) -> tuple[float, bool, int]:
    options = "options: {sleep_after_open: 0}" if interface == "slcan" else ""
    config = load_config_text(
        f"can: {{buses: [{{name: bus0, interface: {interface}, channel: sim, bitrate: 1000000"
        f"{', ' + options if options else ''}}}]}}\n"
        f"servos:\n  - {{name: s, profile: {family}, can_id: {can_id}}}\n",
        "<bench>",
    )
    bus = config.can.buses[0]
    simulator = simulator_factory(config)(bus.name, bus.interface, bus.bitrate)
    assert simulator is not None
    try:

        def opener(request: BusRequest):  # type: ignore[no-untyped-def]
            return open_bus(
                BusRequest(
                    request.name,
                    request.interface,
                    simulator.path,
                    request.bitrate,
                    request.options,
                    request.listen_only,
                )
            )

        doctor = BusDoctor(bus, config.servos, opener, lambda *a: None)
        cls = get_profile(family)
        started = time.perf_counter()
        doctor.scan(family, range(cls.min_id, cls.max_id + 1), 1_000_000)
        elapsed = time.perf_counter() - started
        found = any(s.can_id == can_id for s in doctor.findings.sightings.values())
        return elapsed, found, doctor.findings.scanned
    finally:
        simulator.stop()


def recognition_rate(frames: int = 20_000) -> dict[str, float]:
    """Frames/s the doctor reads while listening to a busy shared bus: every family's profile
    at every id as candidates (the sim.yaml families), a mix of servo replies and a foreign
    node's frames on 64 ids with changing data."""
    import random

    import can

    from mavservo.app.doctor.recognise import Recogniser

    rng = random.Random(1)
    families = {
        name: []
        for name in (
            "rmd-x",
            "lk",
            "cubemars-ak",
            "cubemars-ak-mit",
            "damiao-dm",
            "odrive",
            "dronecan",
            "robstride",
        )
    }
    started = time.perf_counter()
    recogniser = Recogniser(families)
    build_s = time.perf_counter() - started
    stream = []
    for k in range(frames):
        if k % 4 == 0:
            data = bytes([0x9C]) + bytes(rng.randrange(256) for _ in range(7))
            stream.append(can.Message(arbitration_id=0x241, data=data, is_extended_id=False))
        else:
            data = bytes(rng.randrange(256) for _ in range(8))
            stream.append(
                can.Message(arbitration_id=0x500 + k % 64, data=data, is_extended_id=False)
            )
    started = time.perf_counter()
    for msg in stream:
        recogniser.whose(msg)
    elapsed = time.perf_counter() - started
    return {
        "candidates": len(recogniser.candidates),
        "build_s": round(build_s, 3),
        "frames_per_s": round(frames / elapsed),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--interfaces", default="aa55,slcan")
    args = parser.parse_args()
    results = {}
    for interface in args.interfaces.split(","):
        for family, can_id in FAMILIES.items():
            times, found, ids = [], True, 0
            for _ in range(args.runs):
                elapsed, ok, ids = one_scan(family, can_id, interface)
                times.append(elapsed)
                found &= ok
            cls = get_profile(family)
            results[f"{interface}/{family}"] = {
                "ids": f"{cls.min_id}..{cls.max_id}",
                "candidates": ids,  # ids x modes; a read two modes share is sent once
                "median_s": round(statistics.median(times), 3),
                "min_s": round(min(times), 3),
                "max_s": round(max(times), 3),
                "found_every_run": found,
            }
    recognition = [recognition_rate() for _ in range(args.runs)]
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=False
    ).stdout.strip()
    print(
        json.dumps(
            {
                "bench": "doctor scan, 1 Mbit/s, simulated adapters",
                "batch": BATCH,
                "reply_wait_s": REPLY_WAIT_S,
                "runs": args.runs,
                "machine": f"{platform.machine()} {os.cpu_count()} CPUs, "
                f"Python {platform.python_version()}",
                "commit": commit,
                "results": results,
                "listen_recognition": {
                    "candidates": recognition[0]["candidates"],
                    "build_s_median": statistics.median(r["build_s"] for r in recognition),
                    "frames_per_s_median": statistics.median(
                        r["frames_per_s"] for r in recognition
                    ),
                },
            },
            indent=2,
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
