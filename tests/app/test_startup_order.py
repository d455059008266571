"""Start-up order: the command clock starts once the rest of the bridge is up.

Why it matters: a scheduler anchors its first command slot when it starts. Start-up work done
after that anchor (opening the MAVLink link imports pymavlink's large dialect module while
holding the interpreter lock) ran while the first slots were due and delayed them
(docs/engineering/reliability.md, "Start-up"). Behaviour only, no timing thresholds: the order of
events is checked, with the clocks the code itself uses.
"""

from __future__ import annotations

import importlib.util
import socket
import sys
import threading
import time
import uuid
from types import ModuleType
from typing import Any

import can
import pytest

from mavservo.app.bridge import Bridge
from mavservo.config.loader import load_config_text
from mavservo.mavlink.side import MavlinkSide
from mavservo.scheduling.runner import Scheduler, SchedulerObserver, ServoSpec, TimingConfig
from mavservo.servos import RmdX
from tests.support.paths import REPO
from tests.support.waiting import free_udp_port, wait_until

BENCH_FAULTS = REPO / "bench" / "bench_faults.py"
WAIT_LIMIT_S = 5.0


class FirstFrames(SchedulerObserver):
    """Records what the scheduler sent, in order (append only: it runs in the loop)."""

    def __init__(self) -> None:
        self.tx: list[tuple[str, str, Any, float]] = []

    def on_tx(self, bus: str, msg: Any, t: float, kind: str, servo: str, seq: Any) -> None:
        self.tx.append((servo, kind, seq, t))


def bridge_config(port: int, channel: str) -> str:
    return f"""
mavlink: {{url: "udpin:127.0.0.1:{port}", system_id: 1}}
can:
  buses: [{{name: bus0, interface: virtual, channel: {channel}}}]
servos:
  - {{name: s1, profile: rmd-x, can_id: 1, limits_deg: [-30, 30]}}
channels:
  - {{servo: s1, source: servo_output, channel: 1, input: {{min: 1000, max: 2000}}}}
"""


def test_the_command_clock_starts_only_after_the_mavlink_side_is_up(monkeypatch) -> None:
    events: list[tuple[str, float]] = []
    real_mavlink_start = MavlinkSide.start
    real_scheduler_start = Scheduler.start

    def mavlink_start(self: MavlinkSide) -> None:
        real_mavlink_start(self)
        events.append(("mavlink up", time.monotonic()))

    def scheduler_start(self: Scheduler) -> None:
        events.append(("scheduler start", time.monotonic()))
        real_scheduler_start(self)

    monkeypatch.setattr(MavlinkSide, "start", mavlink_start)
    monkeypatch.setattr(Scheduler, "start", scheduler_start)
    frames = FirstFrames()
    config = load_config_text(bridge_config(free_udp_port(), f"startup-{uuid.uuid4().hex}"))
    bridge = Bridge(config, log_dir=False, status=lambda line: None, observers=[frames])
    bridge.start()
    try:
        before = time.monotonic()
        uptime = bridge.schedulers["bus0"].metrics()["info"]["uptime_s"]
        assert wait_until(lambda: frames.tx), "the scheduler sent nothing"
    finally:
        bridge.stop()
    assert [name for name, _ in events] == ["mavlink up", "scheduler start"]
    mavlink_up = events[0][1]
    # uptime = (when metrics() read the clock) - anchor, and that read came after `before`,
    # so `before - uptime` is a lower bound of the anchor: the first slot came after start-up
    assert before - uptime >= mavlink_up
    assert frames.tx[0][3] >= mavlink_up


def test_a_setpoint_queued_before_the_scheduler_starts_goes_out_in_its_first_slot() -> None:
    # What the start-up order relies on: a command the MAVLink side accepts while the
    # schedulers are not started yet is kept, not dropped, and sent in the first command slot.
    channel = f"startup-{uuid.uuid4().hex}"
    bus = can.Bus(interface="virtual", channel=channel)
    listener = can.Bus(interface="virtual", channel=channel)
    frames = FirstFrames()
    timing = TimingConfig(command_period_s=0.02, telemetry_period_s=0.1, reply_timeout_s=0.05)
    scheduler = Scheduler(bus, [ServoSpec("s1", RmdX(1))], timing, observer=frames)
    try:
        queued = scheduler.set_setpoint("s1", 12.5, "mavlink")
        assert queued.accepted
        assert not frames.tx, "nothing goes out before the scheduler starts"
        scheduler.start()
        assert wait_until(lambda: frames.tx)
        scheduler.stop()
        # the profile's start-up frame (RMD-X 0xB3) goes right before it, in the same slot
        startup = [f for f in frames.tx if f[1] == "lifecycle"]
        servo, kind, seq, _ = frames.tx[len(startup)]
        assert (servo, kind, seq) == ("s1", "command", queued.seq)
        assert [f[:3] for f in startup] == [("s1", "lifecycle", None)]
        first = listener.recv(timeout=WAIT_LIMIT_S)
        assert first is not None and first.data[0] == 0xB3
        command = listener.recv(timeout=WAIT_LIMIT_S)
        assert command is not None
        assert command.data == RmdX(1).position_command(12.5).data
    finally:
        scheduler.stop()
        bus.shutdown()
        listener.shutdown()


@pytest.fixture(scope="module")
def bench_faults() -> ModuleType:
    """bench/bench_faults.py imported as a module (bench/ is not a package)."""
    sys.path.insert(0, str(BENCH_FAULTS.parent))
    try:
        spec = importlib.util.spec_from_file_location("bench_faults", BENCH_FAULTS)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module
    finally:
        sys.path.remove(str(BENCH_FAULTS.parent))


def test_the_deployed_rig_waits_for_the_autopilot_to_talk(bench_faults: ModuleType) -> None:
    port = free_udp_port()
    stop = threading.Event()

    def autopilot() -> None:  # as `udpout` does: sends whether anyone listens or not
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            for _ in range(int(WAIT_LIMIT_S / 0.05)):
                if stop.is_set():
                    return
                sock.sendto(b"\xfd heartbeat", ("127.0.0.1", port))
                time.sleep(0.05)

    sender = threading.Thread(target=autopilot, daemon=True)
    sender.start()
    try:
        assert bench_faults.wait_for_datagram(port, WAIT_LIMIT_S)
    finally:
        stop.set()
        sender.join(WAIT_LIMIT_S)
    # the port is free again for the bridge to bind
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", port))


def test_the_deployed_rig_gives_up_on_a_silent_autopilot(bench_faults: ModuleType) -> None:
    assert not bench_faults.wait_for_datagram(free_udp_port(), 0.2)
