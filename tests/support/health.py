"""Shipped configs on the built-in simulation, for the health tests and bench/bench_health.py.

A shipped config may name a serial adapter, a real autopilot link and a signing key file that
is never shipped; here the autopilot and every bus become the built-in simulation (the
``--mavlink sim`` / ``--port sim`` of ``mavservo run``, for every bus), the key is a fresh one
beside a copy of the file, and the simulated autopilot plays ``profile``. Nothing else of the
file changes: the servos, their limits, channels, slews, rates and health thresholds are its own.
"""

from __future__ import annotations

import secrets
import time
from pathlib import Path
from typing import Any

from mavservo.app.bridge import Bridge
from mavservo.config import Config, load_config_text
from tests.support.paths import REPO

SHIPPED = sorted((REPO / "config").glob("*.yaml"))


def on_simulation(
    path: Path, profile: str, key_dir: Path, replay_file: Path | None = None, speed: float = 1.0
) -> Config:
    """``path`` as shipped, with the autopilot and every bus simulated and ``profile`` played
    (``replay``: the recorded autopilot traffic in ``replay_file``, at ``speed``)."""
    (key_dir / "signing.key").write_text(secrets.token_hex(32) + "\n")
    config = load_config_text(path.read_text(), str(path), base_dir=key_dir)
    buses = [b.model_copy(update={"channel": "sim"}) for b in config.can.buses]
    autopilot = config.simulation.autopilot.model_copy(
        update={"profile": profile, "replay_file": replay_file, "speed": speed}
    )
    return config.model_copy(
        update={
            "mavlink": config.mavlink.model_copy(update={"url": "sim", "monitor_outputs": []}),
            "can": config.can.model_copy(update={"buses": buses}),
            "simulation": config.simulation.model_copy(update={"autopilot": autopilot}),
        }
    )


def quiet_run(config: Config, seconds: float) -> dict[str, Any]:
    """Run the bridge for ``seconds`` with no run log; its ``health`` summary."""
    bridge = Bridge(config, log_dir=False, status=lambda line: None).start()
    try:
        time.sleep(seconds)
    finally:
        summary = bridge.stop()
    return dict(summary["health"])
