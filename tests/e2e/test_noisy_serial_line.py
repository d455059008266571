"""A noisy serial line between the bridge and the USB-CAN adapter: no wrong command applied.

The adapter emulator flips bits on the serial line in both directions (seeded). With the fixed
(20-byte, checksummed) AA-55 protocol every command a simulated servo acts on must be one the
bridge actually sent: its frame bytes are among the frames written, its angle among the
setpoints. With the variable protocol (no checksum) corruption can change values, but no
structurally impossible frame (oversized payload, DLC disagreeing with the data, an 11-bit id
beyond 0x7FF) may ever reach a servo, and the bridge keeps running.
"""

from __future__ import annotations

import pytest

from mavservo.sim.adapter import LineCorrupter, LineFaults
from mavservo.sim.autopilot.stream import AutopilotStream
from tests.support.bridge import Recorder, ServoSpy, running, sim_servo
from tests.support.waiting import wait_until

# a bridge thread dying (an exception nobody catches) fails the test, not just warns
pytestmark = pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")

RUN_S = 4.0
FLIP_PROB = 5e-3  # per byte, both directions: several percent of frames hit


def config(protocol: str) -> str:
    return f"""
can:
  buses: [{{name: bus0, interface: aa55, channel: sim, protocol: {protocol}}}]
servos:
  - {{name: rmd, profile: rmd-x, can_id: 1, limits_deg: [-60, 60], telemetry_hz: 10}}
  - {{name: ak, profile: cubemars-ak, can_id: 2, limits_deg: [-60, 60], telemetry_hz: 20}}
channels:
  - {{servo: rmd, source: servo_output, channel: 1, output_deg: [-60, 60]}}
  - {{servo: ak, source: servo_output, channel: 2, output_deg: [-60, 60]}}
scheduler: {{reply_timeout_s: 0.5}}
"""


def run_noisy(protocol: str, seed: int) -> tuple[Recorder, dict[str, ServoSpy], dict, object]:
    recorder = Recorder()
    with running(config(protocol), observers=[recorder]) as (bridge, port):
        emulator = bridge.emulators["bus0"]
        spies = {name: ServoSpy(sim_servo(bridge, name)) for name in ("rmd", "ak")}
        emulator.line = LineCorrupter(LineFaults(flip_prob=FLIP_PROB, direction="both"), seed)
        stream = AutopilotStream(f"udpout:127.0.0.1:{port}", "sweep", duration_s=RUN_S)
        stream.start()
        try:
            assert wait_until(lambda: not stream.running, RUN_S + 10)
        finally:
            stream.stop()
        summary = bridge.stop()
        assert emulator.error is None
        line = emulator.line
    return recorder, spies, summary, line


def test_fixed_protocol_never_applies_a_command_the_bridge_did_not_send() -> None:
    recorder, spies, summary, line = run_noisy("fixed", seed=7)
    assert line.flipped > 10, "the line was not noisy enough to test anything"
    rejected = summary["buses"]["bus0"]["bus_rejected"]
    assert rejected > 0, "corruption toward the host was never detected"
    for name, spy in spies.items():
        sent = {(arb, data) for _, arb, data in recorder.frames(name)}
        acted_on = {(arb, data) for arb, data, _ in spy.frames}
        # every frame the servo acted on (commands and requests) is byte for byte one the
        # bridge wrote
        assert acted_on <= sent, f"{name}: a corrupted frame reached the servo"
        # ... and every angle it moved to is a setpoint the bridge accepted
        setpoints = recorder.angles(name)
        assert len(spy.targets) > 10
        for target in spy.targets:
            assert min(abs(target - s) for s in setpoints) <= 0.006, (name, target)


def test_variable_protocol_lets_no_impossible_frame_reach_a_servo() -> None:
    recorder, spies, summary, line = run_noisy("variable", seed=11)
    assert line.flipped > 10
    for name, spy in spies.items():
        assert spy.malformed == [], f"{name}: structurally impossible frames arrived"
        assert len(spy.frames) > 10, name
        # the servo kept being commanded and answering through the noise
        frames = summary["servos"][name]["frames"]
        assert frames["received"] > 0, name
    # the bridge noticed some of the noise (bytes discarded or frames rejected)
    transport = summary["buses"]["bus0"]["transport"]
    noticed = (
        summary["buses"]["bus0"]["bus_rejected"]
        + transport.get("bytes_discarded", 0)
        + sum(summary["servos"][n]["frames"]["rejected"] for n in spies)
    )
    assert noticed > 0, transport
