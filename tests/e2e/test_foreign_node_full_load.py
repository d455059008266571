"""A foreign CAN node at 100 % bus load, end to end (short version of bench_faults canflood).

The whole Bridge (simulated autopilot in this process) talks through the real ``aa55`` bus to
the adapter emulator and three servos in a child process, at 125 kbit/s so that the flood
(about 925 frames/s, every one forwarded over the serial line: the bridge leaves the
adapter's filter open) stays light for a loaded test machine. Behaviour only:

* a lowest-priority flood (0x7FF) loses every arbitration: our commands keep reaching the
  servos and every servo stays online;
* a highest-priority flood (0x000) starves everyone: the bridge measures the bus as full,
  marks every servo offline with NO_REPLY, and they come back once the flood stops.

Every wait is bounded and only asks "did it happen".
"""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest

from mavservo.app.bridge import Bridge, free_udp_port
from mavservo.config.loader import load_config_text
from mavservo.sim import simulator_for
from mavservo.sim.child import SimulatorProcess
from tests.support.waiting import wait_until

SERVOS = 3
BITRATE = 125_000
WAIT_S = 6.0


def _config(channel: str, port: int) -> str:
    # the bus is a pty (to the bridge, a real serial device): the simulated autopilot runs here
    # and sends to the bridge, which would refuse `url: sim` on it (issue 37)
    lines = [
        f"mavlink: {{url: 'udpin:127.0.0.1:{port}', heartbeat_timeout_s: 30}}",
        "can:",
        "  buses:",
        f"    - {{name: bus0, interface: aa55, channel: '{channel}', bitrate: {BITRATE}}}",
        "servos:",
    ]
    lines += [
        f"  - {{name: s{i}, profile: rmd-x, can_id: {i}, limits_deg: [-45, 45],"
        " telemetry_hz: 10, failsafe: {action: hold, timeout_s: 5}}"
        for i in range(1, SERVOS + 1)
    ]
    lines.append("channels:")
    lines += [
        f"  - {{servo: s{i}, source: servo_output, channel: {i}, input: {{min: 1000, max: 2000}}}}"
        for i in range(1, SERVOS + 1)
    ]
    lines.append(
        "simulation: {autopilot: {profile: sweep, servo_output_rate_hz: 50, gimbal: false}}"
    )
    return "\n".join(lines) + "\n"


@pytest.fixture
def rig() -> Iterator[tuple[Bridge, SimulatorProcess]]:
    sim = SimulatorProcess(SERVOS, bitrate=BITRATE)
    port = free_udp_port()
    config = load_config_text(_config(sim.path, port))
    bridge = Bridge(config, log_dir=False)
    autopilot = simulator_for(config.simulation.autopilot, f"udpout:127.0.0.1:{port}")
    try:
        bridge.start()
        autopilot.start()
        # online and heard from (a servo that never answered has no state to flag)
        assert wait_until(
            lambda: all(r["online"] and r["position_deg"] is not None for r in bridge.status_rows())
        )
        yield bridge, sim
    finally:
        autopilot.stop()
        bridge.stop()
        sim.stop()


def _commands_arriving(sim: SimulatorProcess) -> int:
    """Frames from the host that reached the bus since the last call."""
    return sum(sim.request("arrivals")["arrivals"].values())


def test_lowest_priority_flood_does_not_stop_our_commands(rig):
    bridge, sim = rig
    sim.request("flood", arbitration_id=0x7FF)
    time.sleep(1.0)  # a full load window under the flood
    _commands_arriving(sim)
    time.sleep(1.0)
    assert _commands_arriving(sim) > 50  # 3 servos at 50 Hz plus polls: they still get on
    stats = sim.request("stats")
    assert stats["flood_frames"] > 500 and stats["load_1s"] > 0.95
    assert all(r["online"] for r in bridge.status_rows())
    assert bridge.schedulers["bus0"].load_ratio() > 0.9  # the bridge sees the flood too


def test_highest_priority_flood_starves_every_servo_and_the_bridge_says_so(rig):
    bridge, sim = rig
    sim.request("flood", arbitration_id=0x000)
    assert wait_until(lambda: not any(r["online"] for r in bridge.status_rows()))
    assert all("NO_REPLY" in r["faults"] for r in bridge.status_rows())
    # the bridge receives every flood frame (open filter): its load figure fills its window
    assert wait_until(lambda: bridge.schedulers["bus0"].load_ratio() > 0.9)
    sim.request("flood", arbitration_id=None)
    assert wait_until(lambda: all(r["online"] for r in bridge.status_rows()))
