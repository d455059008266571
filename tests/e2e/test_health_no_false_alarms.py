"""No false alarms (issue 33): every shipped config, on the built-in simulation, follows the
simulated autopilot's sweeps and steps without one health event.

Short runs here (CI: three bridges at a time, about 20 s in all); bench/bench_health.py
``quiet`` runs each for 60 s (docs/benchmarks.md). A run counts only if every servo's
states were judged: a monitor that saw nothing is not quiet.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from tests.support.health import SHIPPED, on_simulation, quiet_run

SECONDS = 2.5
AT_ONCE = 3


def test_every_shipped_config_runs_sweeps_and_steps_with_no_health_event(tmp_path: Path) -> None:
    assert len(SHIPPED) >= 9
    runs = [(path, profile) for path in SHIPPED for profile in ("sweep", "steps")]

    def run(k: int) -> tuple[set[str], dict[str, Any]]:
        path, profile = runs[k]
        key_dir = tmp_path / str(k)
        key_dir.mkdir()
        config = on_simulation(path, profile, key_dir)
        return {s.name for s in config.servos}, quiet_run(config, SECONDS)

    with ThreadPoolExecutor(AT_ONCE) as pool:
        results = list(pool.map(run, range(len(runs))))
    noisy = {}
    for (path, profile), (names, health) in zip(runs, results, strict=True):
        judged = health["judged"]
        assert set(judged) == names
        assert min(judged.values()) >= 5, (path.name, profile, judged)
        if health["episodes"]:
            noisy[(path.name, profile)] = [e["text"] for e in health["events"]]
    assert noisy == {}
