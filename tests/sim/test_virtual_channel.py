"""Simulated servos on a python-can ``virtual`` channel (the fast in-process variant)."""

from __future__ import annotations

import time
import uuid

import can
import pytest

from mavservo.servos import CubeMarsAK, RmdX
from mavservo.sim.servo import SimServo
from mavservo.sim.virtual import VirtualServoBus


def test_servos_on_a_virtual_channel_answer_and_converge():
    channel = f"sim-{uuid.uuid4().hex}"
    servos = [SimServo("rmd-x", 1), SimServo("cubemars-ak", 2)]
    rmd, cube = RmdX(1, multi_turn_poll_every=1), CubeMarsAK(2)
    with (
        VirtualServoBus(servos, channel=channel) as sim,
        can.Bus(interface="virtual", channel=channel) as bus,
    ):
        bus.send(rmd.position_command(-25.0, 720))
        bus.send(cube.position_command(-25.0, 720))
        for _ in range(100):
            for request in rmd.telemetry_requests():
                bus.send(request)
            deadline = time.monotonic() + 0.1
            for _ in range(50):
                msg = bus.recv(timeout=max(0.0, deadline - time.monotonic()))
                if msg is None:
                    break
                rmd.decode(msg, time.monotonic()) or cube.decode(msg, time.monotonic())
            states = (rmd.last_state, cube.last_state)
            if all(s is not None and abs(s.position_deg + 25.0) <= 0.05 for s in states):
                break
        assert rmd.last_state.position_deg == pytest.approx(-25.0, abs=0.05)
        assert cube.last_state.position_deg == pytest.approx(-25.0, abs=0.05)
        assert sim.load() > 0
    assert sim.error is None
