"""The bridge's MAVLink side against the simulated PX4 (mavservo/sim/autopilot/px4.py), over real
pymavlink UDP on 127.0.0.1: PX4's ACTUATOR_OUTPUT_STATUS (``active`` = 16, a count) mirrored on
every output, the gimbal found and its setpoints asked at the command rate, nothing sent that
PX4 drops as unknown, and no old demand driven after PX4 restarts (issue 39).

Each run is bounded (a few seconds) and asserts behaviour, never a timing threshold.
"""

from __future__ import annotations

import dataclasses
import math

import pytest

from mavservo.config.autopilot_script import Event, SetActuator
from mavservo.mavlink.gimbal import GimbalDevice
from mavservo.mavlink.gimbal_settings import GimbalSettings
from mavservo.mavlink.settings import MavlinkSettings, StreamRequestSettings
from mavservo.mavlink.side import MavlinkSide
from mavservo.sim.autopilot.motion_scripts import SweepProfile
from mavservo.sim.autopilot.px4 import Px4Stream
from tests.support.mavlink_doubles import ACTUATOR_INDICES, RecordingBackend, state
from tests.support.waiting import free_udp_port, wait_until

COMMAND_PERIOD_S = 0.05


def _settings(port: int, *, gimbals: bool = False) -> MavlinkSettings:
    return MavlinkSettings(
        url=f"udpin:127.0.0.1:{port}",
        system_id=1,
        mirror_servo_output_raw=False,
        mirror_actuator_output_status=True,
        command_period_s=COMMAND_PERIOD_S,
        stream_request=StreamRequestSettings.for_mirror(
            ("ACTUATOR_OUTPUT_STATUS",), COMMAND_PERIOD_S, gimbals=gimbals
        ),
        link_budget_bytes_s=None,
    )


def _applied(backend: RecordingBackend, index: int) -> list[float]:
    return [c[2] for c in backend.servo_calls("actuator") if c[1] == index]


def test_px4_actuator_output_status_is_mirrored_on_every_output() -> None:
    """PX4 puts the number of outputs in ``active``; read as a bitmask (the code before issue
    39) 16 selects output 5 alone and output 1 is never mirrored. Every change PX4 sent on a
    mapped output (1: the sweep, 5: a peripheral actuator) reaches the servos, in order."""
    port = free_udp_port()
    script = [Event(0.5 + 0.4 * i, SetActuator((v,))) for i, v in enumerate((0.5, -0.5, 0.25))]
    backend = RecordingBackend()
    with MavlinkSide(_settings(port), backend) as side:
        with Px4Stream(f"udpout:127.0.0.1:{port}", SweepProfile(), script).start() as px4:
            assert wait_until(
                lambda: len(px4.commanded_log("actuator")) == 3 and len(_applied(backend, 5)) >= 3,
                timeout=8,
            )
            assert wait_until(lambda: len(_applied(backend, 1)) >= 10, timeout=5)
        stream = side.stats()["stream"]["streams"]["ACTUATOR_OUTPUT_STATUS"]
    assert px4.error is None
    assert px4.interval_s("ACTUATOR_OUTPUT_STATUS") == pytest.approx(COMMAND_PERIOD_S)
    assert stream["answer"] == "accepted"
    for index in sorted(set(ACTUATOR_INDICES)):
        sent = [
            (c.value - 1500.0) / 500.0
            for c in px4.commanded_log("actuator_output")
            if c.key == index and c.value != 0
        ]
        applied = _applied(backend, index)
        assert applied, f"output {index} never mirrored"
        start = sent.index(applied[0])
        mismatches = [
            (a, s) for a, s in zip(applied, sent[start:], strict=False) if not math.isclose(a, s)
        ]
        assert mismatches == [], f"output {index}: {mismatches[:5]}"
        assert len(applied) >= len(sent[start:]) - 1  # the last one may be in flight


def _gimbal(backend: RecordingBackend) -> GimbalDevice:
    settings = GimbalSettings(
        name="cam",
        component_id=154,
        axis_servos={"pitch": "aileron", "yaw": "drop"},
        limits_deg={"pitch": (-90.0, 30.0), "yaw": (-160.0, 160.0)},
        system_id=1,
    )
    return GimbalDevice(settings, backend)


def test_px4_finds_the_gimbal_is_asked_for_setpoints_and_gets_no_unknown_message() -> None:
    """PX4 asks every component for GIMBAL_DEVICE_INFORMATION (target 0/0) until the gimbal
    answers; the bridge asks PX4 for the setpoints at its command rate (PX4's onboard default
    is 5 Hz); nothing the bridge sends is dropped by PX4's parser (no ESC_TELEMETRY), while
    the ESC view (ESC_INFO/ESC_STATUS) goes."""
    port = free_udp_port()
    backend = RecordingBackend()
    backend.states["aileron"] = state(1.0)
    with MavlinkSide(_settings(port, gimbals=True), backend, gimbals=[_gimbal(backend)]) as side:
        with Px4Stream(f"udpout:127.0.0.1:{port}", SweepProfile(), gimbal=True).start() as px4:
            px4.set_gimbal(pitch=-90.0)
            assert wait_until(lambda: px4.gimbal_device_info is not None, timeout=5)
            assert wait_until(
                lambda: px4.interval_s("GIMBAL_DEVICE_SET_ATTITUDE") == COMMAND_PERIOD_S,
                timeout=6,
            )
            assert wait_until(lambda: px4.received_raw[291] >= 2, timeout=5)
            assert wait_until(lambda: px4.received_raw[290] >= 1, timeout=5)  # ESC_INFO, 1 Hz
            assert wait_until(
                lambda: any(c[3] == pytest.approx(-90.0) for c in backend.servo_calls("gimbal")),
                timeout=5,
            )
            px4.set_gimbal(pitch=-60.0, yaw=30.0)
            assert wait_until(
                lambda: any(c[3] == pytest.approx(-60.0) for c in backend.servo_calls("gimbal")),
                timeout=5,
            )
        stats = side.stats()
    assert px4.error is None
    assert px4.sent["COMMAND_LONG"] >= 1  # the discovery requests, broadcast
    assert stats["gimbal_discovery"]["found"] == [154]
    assert stats["autopilot_flavour"]["in_force"] == "px4"
    assert "GIMBAL_DEVICE_SET_ATTITUDE" in stats["stream"]["streams"]
    assert px4.dropped_unknown == {}, "PX4 would count these frames as lost"
    call = next(c for c in backend.servo_calls("gimbal") if c[3] == pytest.approx(-60.0))
    assert call[4] == pytest.approx(30.0)  # the yaw PX4 asked, in the vehicle frame


def test_after_px4_restarts_the_old_gimbal_demand_is_not_driven_again() -> None:
    """PX4 restarts (silent 2.5 s, the bridge fails safe, then a new boot that sends no gimbal
    demand until it has found the gimbal again): its ATTITUDE stream must not drive the
    gimbal back to the old PX4's earth-frame demand (mavlink/gimbal.py, ATTITUDE branch)."""
    port = free_udp_port()
    backend = RecordingBackend()
    settings = dataclasses.replace(_settings(port, gimbals=True), heartbeat_timeout_s=1.0)
    side = MavlinkSide(settings, backend, gimbals=[_gimbal(backend)])
    px4 = Px4Stream(f"udpout:127.0.0.1:{port}", SweepProfile(), gimbal=True)
    with side, px4.start():
        px4.set_gimbal(pitch=-45.0, yaw=20.0, flags=16)  # yaw lock: earth frame
        assert wait_until(
            lambda: any(c[3] == pytest.approx(-45.0) for c in backend.servo_calls("gimbal")),
            timeout=6,
        )
        px4.reboot(2.5)
        px4.link.yaw_rad = 0.6  # the new boot's estimator heads elsewhere
        assert wait_until(lambda: backend.failsafe_events == ["enter"], timeout=5)
        before = len(backend.servo_calls("gimbal"))
        assert wait_until(lambda: backend.failsafe_events == ["enter", "leave"], timeout=6)
        assert wait_until(lambda: px4.sent["ATTITUDE"] > 0 and px4.reboots == 1, timeout=2)
        # the new boot's ATTITUDE flows; the gimbal is found again, then new setpoints
        assert wait_until(lambda: px4.gimbal_device_info is not None, timeout=5)
        px4.set_gimbal(pitch=-10.0)
        assert wait_until(
            lambda: any(c[3] == pytest.approx(-10.0) for c in backend.servo_calls("gimbal")),
            timeout=5,
        )
    after_restart = backend.servo_calls("gimbal")[before:]
    old = [c for c in after_restart if c[3] == pytest.approx(-45.0)]
    assert not old, f"the old demand was driven after the restart: {old[:3]}"


def test_the_built_in_simulation_can_be_a_px4() -> None:
    """``simulation.autopilot.autopilot: px4`` (``mavlink.url: sim``) runs the simulated PX4."""
    from mavservo.sim.autopilot.factory import simulator_from_config

    px4 = simulator_from_config({"autopilot": "px4", "gimbal": True}, "udpout:127.0.0.1:9")
    assert isinstance(px4, Px4Stream)
    assert px4.interval_s("GIMBAL_DEVICE_SET_ATTITUDE") == pytest.approx(0.2)  # PX4's 5 Hz
    assert px4.interval_s("AUTOPILOT_STATE_FOR_GIMBAL_DEVICE") is None  # gimbal mode only
    assert px4.interval_s("ACTUATOR_OUTPUT_STATUS") is None  # until asked
