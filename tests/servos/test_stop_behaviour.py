"""Each family's own stop behaviour (``ServoProfile.stop_behaviour``), as ``check``'s failsafe
plan prints it: "hold" is never promised for a servo that goes limp by itself."""

from __future__ import annotations

import io

from mavservo.app.check import check_main
from mavservo.servos import registry
from mavservo.servos.dronecan.profile import DroneCanServo
from tests.app.test_run_cli import REPO


def test_every_family_says_what_it_does_when_frames_stop() -> None:
    texts = {}
    for name, entry in registry.profiles().items():
        cls = entry.profile
        texts[name] = cls(cls.min_id).stop_behaviour()
        assert texts[name], name
    assert "holds" not in DroneCanServo(1, firmware="ardupilot", command="pwm").stop_behaviour()
    assert "200 ms" in DroneCanServo(1, firmware="ardupilot", command="pwm").stop_behaviour()
    assert "TIMEOUT register" in texts["damiao-dm"]
    assert "ms after the last frame" in texts["damiao-dm"]  # its configured timeout, in ms


def test_check_prints_the_stop_behaviour_of_every_servo() -> None:
    out, err = io.StringIO(), io.StringIO()
    assert check_main(["config/damiao.yaml"], out, err) == 0, err.getvalue()
    text = out.getvalue()
    assert "when the bridge's frames stop (stopped, bus or adapter gone), each servo:" in text
    assert "disables its motor past its TIMEOUT register" in text


def test_check_prints_the_actuator_id_convention_warning(tmp_path) -> None:  # type: ignore[no-untyped-def]
    source = (REPO / "config" / "dronecan.yaml").read_text()
    path = tmp_path / "px4-numbered.yaml"
    path.write_text(source.replace("actuator_id: 1 ", "actuator_id: 0 ", 1))
    out, err = io.StringIO(), io.StringIO()
    assert check_main([str(path)], out, err) == 0, err.getvalue()
    text = out.getvalue()
    assert "actuator_id 0: PX4 numbers actuators from 0" in text
    assert "px4-numbered.yaml:" in text  # at the servo's line
    assert "SafetyState: not sent (safety_state: none)" in text
