"""Fault injection end to end (short versions of bench/bench_faults.py), through the whole Bridge
on its simulated autopilot, AA-55 adapter (a real pty) and servos.

* serial corruption towards the adapter in the checksummed (fixed) protocol, one flipped byte
  per write: every frame a servo receives was sent by the host, the garbage is counted, commands
  keep flowing;
* serial corruption towards the host in the variable protocol: rejections are counted by the
  host decoder and telemetry keeps arriving;
* USB unplug / replug mid-run: the bridge reconnects by itself and commands reach the servos
  again;
* a silent servo goes offline (NO_REPLY) while the others stay online; a faulted one reports
  its fault by name.

No timing thresholds: every wait is bounded and only asks "did it happen".
"""

from __future__ import annotations

import random
import time
from collections.abc import Iterator

import pytest

from mavservo.app.bridge import Bridge
from mavservo.config.loader import load_config_text
from mavservo.sim.adapter import LineCorrupter, LineFaults
from tests.support.waiting import wait_until

WAIT_S = 6.0


def config(protocol: str, servos: int = 3) -> str:
    lines = [
        "mavlink: {url: sim, heartbeat_timeout_s: 30}",
        "can:",
        "  buses:",
        f"    - {{name: bus0, interface: aa55, channel: sim, protocol: {protocol}}}",
        "servos:",
    ]
    lines += [
        f"  - {{name: s{i}, profile: rmd-x, can_id: {i}, limits_deg: [-45, 45],"
        " telemetry_hz: 10, failsafe: {action: hold, timeout_s: 5}}"
        for i in range(1, servos + 1)
    ]
    lines.append("channels:")
    lines += [
        f"  - {{servo: s{i}, source: servo_output, channel: {i}, input: {{min: 1000, max: 2000}}}}"
        for i in range(1, servos + 1)
    ]
    lines.append(
        "simulation: {autopilot: {profile: sweep, servo_output_rate_hz: 50, gimbal: false}}"
    )
    lines.append("logging: {dir: runs}")
    return "\n".join(lines) + "\n"


class OneFlipPerWrite:
    """Line fault: exactly one random byte of every write flipped (so at most one per frame)."""

    def __init__(self, seed: int) -> None:
        self._rng = random.Random(seed)
        self.flipped = 0

    def applies_to(self, direction: str) -> bool:
        return direction == "to_adapter"

    def corrupt(self, data: bytes) -> bytes:
        out = bytearray(data)
        if out:
            out[self._rng.randrange(len(out))] ^= 1 << self._rng.randrange(8)
            self.flipped += 1
        return bytes(out)


class FrameLog:
    """Frames the host sent and the frames that reached the simulated CAN bus from the host.

    The bridge is already running when the log is installed, so frames written before it may
    still be on their way. The line is first in, first out: once a logged frame has arrived
    (``synced``), every later arrival was written after the log was installed.
    """

    def __init__(self, bridge: Bridge) -> None:
        self.sent: set[tuple] = set()
        self.arrived: list[tuple] = []
        self.synced = False
        bus, canbus = bridge.buses["bus0"], bridge.emulators["bus0"].canbus
        send, submit = bus.send, canbus.submit

        def logged_send(msg, timeout=None):  # noqa: ANN001, ANN202 - python-can signature
            self.sent.add(self.key(msg))
            send(msg, timeout)

        def logged_submit(msg, ready, *rest):  # noqa: ANN001, ANN202
            if not rest:
                key = self.key(msg)
                self.synced = self.synced or key in self.sent
                if self.synced:
                    self.arrived.append(key)
            submit(msg, ready, *rest)

        bus.send = logged_send
        canbus.submit = logged_submit

    @staticmethod
    def key(msg) -> tuple:  # noqa: ANN001
        return (msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame, bytes(msg.data))


def started(protocol: str) -> Iterator[Bridge]:
    bridge = Bridge(load_config_text(config(protocol)), log_dir=False)
    bridge.start()
    try:
        assert wait_until(lambda: all(r["online"] for r in bridge.status_rows()))
        yield bridge
    finally:
        bridge.stop()


@pytest.fixture
def fixed_bridge() -> Iterator[Bridge]:
    yield from started("fixed")


@pytest.fixture
def variable_bridge() -> Iterator[Bridge]:
    yield from started("variable")


def test_checksummed_line_with_flipped_bytes_never_applies_a_command_nobody_sent(
    fixed_bridge: Bridge,
) -> None:
    bridge = fixed_bridge
    log = FrameLog(bridge)
    assert wait_until(lambda: log.synced)  # before the faults: frames in flight are not logged
    emulator = bridge.emulators["bus0"]
    line = OneFlipPerWrite(seed=3)
    emulator.line = line
    assert wait_until(lambda: line.flipped >= 150 and len(log.arrived) >= 30)
    emulator.line = LineCorrupter(LineFaults())
    arrived_under_faults = len(log.arrived)
    assert wait_until(lambda: len(log.arrived) > arrived_under_faults + 10)  # still flowing
    assert [k for k in log.arrived if k not in log.sent] == []
    assert sum(emulator.decoder.rejected.values()) > 0  # the garbage was seen and counted
    assert emulator.frames_from_host > 0


def test_corrupted_replies_are_counted_and_telemetry_keeps_flowing(
    variable_bridge: Bridge,
) -> None:
    bridge = variable_bridge
    emulator = bridge.emulators["bus0"]
    emulator.line = LineCorrupter(LineFaults(flip_prob=0.02, direction="to_host"), seed=5)
    bus = bridge.buses["bus0"]
    assert wait_until(lambda: sum(bus.stats().get("rejected", {}).values()) >= 3)
    emulator.line = LineCorrupter(LineFaults())
    before = bus.stats()["frames"]
    assert wait_until(lambda: bus.stats()["frames"] > before + 20)
    assert wait_until(lambda: all(r["online"] for r in bridge.status_rows()))


def test_usb_unplug_and_replug_mid_run_resumes_commands(variable_bridge: Bridge) -> None:
    bridge = variable_bridge
    log = FrameLog(bridge)
    emulator = bridge.emulators["bus0"]
    bus = bridge.buses["bus0"]
    emulator.unplug()
    assert wait_until(lambda: not bus.stats().get("connected", True))
    time.sleep(0.3)
    arrived = len(log.arrived)
    emulator.replug()
    assert wait_until(lambda: bus.stats().get("connected", False))
    assert wait_until(lambda: len(log.arrived) > arrived)
    assert bus.stats()["reconnects"] >= 1
    assert any("reconnect" in text.lower() or "back" in text.lower() for _, text in bridge.events)
    assert wait_until(lambda: all(r["online"] for r in bridge.status_rows()))


def test_silent_servo_goes_offline_alone_and_a_faulted_one_names_its_fault(
    variable_bridge: Bridge,
) -> None:
    bridge = variable_bridge
    emulator = bridge.emulators["bus0"]
    silent = next(s for s in emulator.servos if s.can_id == 2)
    faulted = next(s for s in emulator.servos if s.can_id == 3)
    with emulator._lock:  # the adapter thread reads faults under this lock
        silent.faults.silent = True
        faulted.faults.over_current = True

    def row(name: str) -> dict:
        return next(r for r in bridge.status_rows() if r["servo"] == name)

    assert wait_until(lambda: not row("s2")["online"])
    assert wait_until(lambda: "OVER_CURRENT" in row("s3")["faults"])
    assert row("s1")["online"] and row("s3")["online"]
    with emulator._lock:
        silent.faults.silent = False
    assert wait_until(lambda: row("s2")["online"])
