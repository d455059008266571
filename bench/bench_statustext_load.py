"""STATUSTEXTs per servo per minute from the quick start on a loaded machine (issue 37).

Runs ``mavservo run --duration D`` (the quick start: the built-in simulation's ten servos) while
``--busy`` processes spin at nice 0 (a ``stress``-like load: one per core), then counts from the
run's own records what the ground station was sent: every STATUSTEXT the bridge wrote to its
link (``mavlink.tlog``, outgoing, whole texts: a chunked text counts once), per servo it names
and per minute of the run, next to the console's lines about the same servos and the run's
``went_offline`` / ``lost`` / ``late`` counts (metrics.json).

    python bench/bench_statustext_load.py --duration 600 --busy 2
    # the same against another checkout (a baseline; its mavservo package first on the path)
    python bench/bench_statustext_load.py --duration 180 --pythonpath /tmp/old-checkout

Prints one JSON object; docs/engineering/messages.md keeps the numbers. Nothing here is a
pass/fail: the bound (at most 3 texts per servo and kind per 10 s, so at most 18 a minute
for one kind, plus a 20 s reminder while a problem lasts) is what the numbers are read against.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

SERVO_COMPONENT = 140
SERVO_TEXT = re.compile(r"^servo (\S+) ")
CONSOLE_SERVO = re.compile(r"\] \w+\s+\S+: (?:scheduler \S+: )?servo (\S+) (offline|back online)")


def busy_loops(count: int) -> list[subprocess.Popen[bytes]]:
    """``count`` processes spinning at nice 0 until killed."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(count)]


def statustexts(tlog: Path) -> list[tuple[float, int, str]]:
    """(time, severity, text) of every whole STATUSTEXT the bridge's servo component sent."""
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink import mavutil

    from mavservo.mavlink import join_statustext_chunks

    out: list[tuple[float, int, str]] = []
    chunks: dict[int, list[str]] = {}
    log = mavutil.mavlink_connection(str(tlog), dialect="ardupilotmega")
    while True:
        msg = log.recv_match(type="STATUSTEXT")
        if msg is None:
            break
        if msg.get_srcComponent() != SERVO_COMPONENT:
            continue
        when = getattr(msg, "_timestamp", 0.0)
        if not msg.id:
            out.append((when, msg.severity, msg.text))
            continue
        parts = chunks.setdefault(msg.id, [])
        parts.append(msg.text)
        if len(msg.text) < 50:  # the last chunk (its NUL): the text is whole
            out.append((when, msg.severity, join_statustext_chunks(chunks.pop(msg.id))))
    return out


def per_minute(times: list[float], start: float) -> list[int]:
    counts: collections.Counter[int] = collections.Counter(int((t - start) // 60) for t in times)
    return [counts[k] for k in range(max(counts, default=-1) + 1)]


def run(duration: float, busy: int, pythonpath: str | None) -> dict[str, Any]:
    env = dict(os.environ)
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    work = Path(tempfile.mkdtemp(prefix="bench-statustext-"))
    loops = busy_loops(busy)
    started = time.time()
    try:
        done = subprocess.run(
            [sys.executable, "-m", "mavservo", "run", "--duration", f"{duration:g}"]
            + ["--log-dir", str(work / "runs")],
            cwd=work,
            env=env,
            capture_output=True,
            text=True,
            timeout=duration + 120,
            check=False,
        )
    finally:
        for loop in loops:
            loop.kill()
            loop.wait()
    load = os.getloadavg()
    [run_dir] = list((work / "runs").iterdir())
    texts = statustexts(run_dir / "mavlink.tlog")
    first = texts[0][0] if texts else started
    by_servo: dict[str, list[float]] = collections.defaultdict(list)
    for when, _, text in texts:
        match = SERVO_TEXT.match(text)
        if match:
            by_servo[match.group(1)].append(when)
    console: collections.Counter[str] = collections.Counter()
    for line in (done.stdout + done.stderr).splitlines():
        match = CONSOLE_SERVO.search(line)
        if match:
            console[match.group(1)] += 1
    metrics = json.loads((run_dir / "metrics.json").read_text())
    frames = {
        name: {k: servo["frames"].get(k, 0) for k in ("went_offline", "lost", "late")}
        for name, servo in metrics.get("servos", {}).items()
    }
    telemetry = (metrics.get("mavlink") or {}).get("telemetry") or {}
    minutes = duration / 60
    return {
        "returncode": done.returncode,
        "duration_s": duration,
        "busy_loops": busy,
        "loadavg_1_5_15_at_end": [round(x, 2) for x in load],
        "statustext_total": len(texts),
        "statustext_per_minute": round(len(texts) / minutes, 2),
        "servo_texts": {name: len(times) for name, times in sorted(by_servo.items())},
        "servo_texts_per_minute_max": {
            name: max(per_minute(times, first), default=0)
            for name, times in sorted(by_servo.items())
        },
        "console_servo_lines": dict(sorted(console.items())),
        "frames": frames,
        "statustext_repeats_counted": telemetry.get("statustext_repeats_counted"),
        "statustext_dropped": telemetry.get("statustext_dropped", 0),
        "first_texts": [text for _, _, text in texts[:12]],
        "run_dir": str(run_dir),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=600.0)
    parser.add_argument("--busy", type=int, default=2, help="busy loops at nice 0 (one a core)")
    parser.add_argument("--pythonpath", help="run another checkout's mavservo (a baseline)")
    args = parser.parse_args()
    print(json.dumps(run(args.duration, args.busy, args.pythonpath), indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
