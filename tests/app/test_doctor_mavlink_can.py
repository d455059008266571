"""``mavservo doctor`` on a ``mavlink-can`` bus: it opens a MAVLink link of its own to the
autopilot (the simulated one, whose CAN forward has simulated RMD-X servos on its bus) and
diagnoses the servos behind the autopilot's CAN port as on any bus."""

from __future__ import annotations

import time
from pathlib import Path

import can

from mavservo.app.bridge import free_udp_port
from mavservo.app.doctor import FrameLog, diagnose_bus
from mavservo.config import load_config_text
from mavservo.sim.autopilot.can_forward import CanForwardLink
from mavservo.sim.autopilot.stream import AutopilotStream
from mavservo.sim.servo import SimServo
from mavservo.sim.virtual import VirtualServoBus


def test_doctor_finds_the_servos_behind_the_autopilot_and_a_wrong_id(tmp_path: Path) -> None:
    port = free_udp_port()
    config = load_config_text(
        f'mavlink: {{url: "udpin:127.0.0.1:{port}"}}\n'
        "can:\n  buses: [{name: fc, interface: mavlink-can, channel: 1}]\n"
        "servos:\n  - {name: a, profile: rmd-x, can_id: 1}\n"
        "  - {name: b, profile: rmd-x, can_id: 2}\n",
        "<doctor>",
    )
    channel = f"doctor-fc-{port}"
    servos = VirtualServoBus([SimServo("rmd-x", 1), SimServo("rmd-x", 3)], channel=channel)
    servos.start()
    autopilot_can = can.Bus(interface="virtual", channel=channel)
    link = CanForwardLink(autopilot_can, clock=time.monotonic)
    autopilot = AutopilotStream(f"udpout:127.0.0.1:{port}", can_forward=link).start()
    try:
        findings, verdicts = diagnose_bus(
            config,
            0,
            FrameLog(tmp_path / "d.asc"),
            listen_s=0.5,
            allow_enable=False,
            try_bitrates=False,
        )
    finally:
        autopilot.stop()
        autopilot_can.shutdown()
        servos.stop()
    by_servo = {v.servo.name: v for v in verdicts}
    assert by_servo["a"].ok
    assert not by_servo["b"].ok and "can_id: 3" in by_servo["b"].fix
    assert link.forwarder.counters["forwarded"] > 0
