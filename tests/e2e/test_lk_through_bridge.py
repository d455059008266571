"""LK-Tech motors through the whole bridge, on the servos of ``config/lk.yaml``.

A GCS-side pymavlink peer sends DO_SET_SERVO over UDP; the bridge drives the aa55 interface on
the adapter emulator's pty; simulated LK motors (written from LK's document: off after 0x80
until 0x88) move and answer. Checked: at rest the reported position equals the commanded angle
within the encoder's resolution, current and voltage are plausible for the model, no fault is
reported; after a ``release`` failsafe a new command goes out after motor on (0x88) and the
motor moves (the simulated motor refuses to without it). The shipped config's own run:
``tests/app/test_run_family_configs.py``.
"""

from __future__ import annotations

import math

import pytest
import yaml

from mavservo.servos import Fault
from tests.app.test_run_cli import REPO
from tests.support.bridge import (
    MAV_CMD_DO_SET_SERVO,
    MAV_RESULT_ACCEPTED,
    Peer,
    Recorder,
    ServoSpy,
    pwm_to_angle,
    running,
    sim_servo,
    status,
)
from tests.support.waiting import wait_until

pytestmark = pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")

#: servo -> (channel, input range, output range, encoder bits, full-scale current A)
SERVOS = {
    "pan": (1, (1100, 1900), (-90, 90), 14, 16.5),
    "tilt": (2, (1100, 1900), (-60, 60), 16, 33.0),
}


def lk_body() -> str:
    """``config/lk.yaml`` without its MAVLink and simulation sections (the test is the GCS),
    a short heartbeat timeout, and replies counted lost only when they never come."""
    document = yaml.safe_load((REPO / "config" / "lk.yaml").read_text())
    for key in ("mavlink", "simulation", "logging"):
        document.pop(key)
    document["scheduler"]["reply_timeout_s"] = 0.5
    return yaml.safe_dump(document)


def _at_rest_on(bridge, name: str, target: float) -> bool:
    servo = sim_servo(bridge, name)
    return abs(servo.position_deg - target) < 0.01 and abs(servo.velocity_dps) < 0.01


def test_lk_motors_report_what_they_were_told_and_come_back_after_release() -> None:
    recorder = Recorder()
    with running(lk_body(), extra_mavlink="  heartbeat_timeout_s: 0.6\n", observers=[recorder]) as (
        bridge,
        port,
    ):
        peer = Peer(port)
        spy = ServoSpy(sim_servo(bridge, "tilt"))
        try:
            peer.start_heartbeats(0.1)
            targets = {}
            for name, (channel, (low, high), out, _, _) in SERVOS.items():
                pwm = 1317 if name == "pan" else 1733  # fractional angles
                targets[name] = pwm_to_angle(pwm, low, high, out)
                assert peer.command(MAV_CMD_DO_SET_SERVO, [channel, pwm]) == MAV_RESULT_ACCEPTED
            for name, target in targets.items():
                assert wait_until(lambda n=name, t=target: _at_rest_on(bridge, n, t), 8), name
            # a 9A and a few 9C polls after coming to rest: every field is fresh
            scheduler = bridge.schedulers["bus0"]
            for name, (_, _, _, bits, full_scale) in SERVOS.items():
                rest = scheduler.state(name).timestamp
                assert wait_until(lambda n=name, r=rest: scheduler.state(n).timestamp > r + 1.2, 5)
                state = status(bridge, name).state
                assert abs(state.position_deg - targets[name]) <= 360 / 2**bits, (name, state)
                assert math.isfinite(state.current_a) and abs(state.current_a) <= full_scale
                assert state.voltage_v is not None and 10.0 <= state.voltage_v <= 60.0, state
                assert state.faults == Fault(0), state
                assert 0 <= state.temperature_c < 80
            # release failsafe on the tilt: motor off; then a new command
            tilt = sim_servo(bridge, "tilt")
            peer.stop_heartbeats()
            assert wait_until(lambda: not tilt.enabled, 5)
            frames_before = len(spy.frames)
            peer.start_heartbeats(0.1)
            new_pwm = 1200
            new_target = pwm_to_angle(new_pwm, 1100, 1900, (-60, 60))
            assert peer.command(MAV_CMD_DO_SET_SERVO, [2, new_pwm]) == MAV_RESULT_ACCEPTED
            assert wait_until(lambda: _at_rest_on(bridge, "tilt", new_target), 8), tilt.position_deg
            commands = [data[0] for _, data, _ in spy.frames[frames_before:]]
            first_move = commands.index(0xA4)
            assert 0x88 in commands[:first_move], [hex(c) for c in commands[: first_move + 1]]
        finally:
            peer.close()
        summary = bridge.stop()
    sent = recorder.frames("tilt")
    offs = [i for i, (_, _, data) in enumerate(sent) if data[0] == 0x80]
    assert offs, "the release sent motor off"
    after = [data[0] for _, _, data in sent[offs[0] :]]
    assert after.index(0x88) < after.index(0xA4)
    for name in SERVOS:
        assert summary["servos"][name]["frames"]["rejected"] == 0, name
