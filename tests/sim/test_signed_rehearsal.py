"""A signed configuration can be rehearsed on the built-in simulation: the simulated autopilot
signs with the bridge's key, and the bridge acts on it (and still refuses the unsigned)."""

from __future__ import annotations

from mavservo.app.bridge import Bridge
from mavservo.config import load_config_text
from tests.support.waiting import wait_until

KEY = "6b" * 32
CONFIG = f"""
mavlink: {{url: sim, signing: {{key: "{KEY}"}}}}
can: {{buses: [{{name: bus0, interface: aa55, channel: sim}}]}}
servos:
  - {{name: aileron, profile: rmd-x, can_id: 1, limits_deg: [-30, 30], telemetry_hz: 10}}
channels:
  - {{servo: aileron, source: servo_output, channel: 1, output_deg: [-30, 30]}}
simulation: {{autopilot: {{profile: sweep}}}}
"""


def test_simulated_autopilot_signs_with_the_bridges_key() -> None:
    bridge = Bridge(load_config_text(CONFIG, "signed.yaml"), log_dir=False, status=lambda _: None)
    bridge.start()
    try:
        servo = bridge.emulators["bus0"].servos[0]
        assert wait_until(lambda: servo.commands >= 5)
        # no fixed sleep: 20 signed SERVO_OUTPUT_RAW acted on (1 s of the stream) is the point
        # by which a signing problem would have shown as a rejection
        assert wait_until(lambda: applied(bridge) >= 20)
    finally:
        summary = bridge.stop()
    mav = summary["mavlink"]
    assert mav["mirror"]["applied"] > 0, mav  # signed SERVO_OUTPUT_RAW was acted on
    assert mav["link"].get("signing_rejected", 0) == 0, mav["link"]
    assert servo.commands >= 5


def applied(bridge: Bridge) -> int:
    """SERVO_OUTPUT_RAW values the bridge's MAVLink side acted on."""
    assert bridge.mavlink is not None
    return int(bridge.mavlink.stats()["mirror"].get("applied", 0))
