"""The parameter owner and where its sets take effect, without a link or a thread.

:class:`LiveParameters` gets a request the MAVLink side has checked; one validated rebuild of the
config, applied by :class:`ConfigTargets` to the real running pieces (the servo backend on a
recording sink, the health watch, a gimbal device, the MAVLink core's telemetry), then handed to
the overlay's saver. A refused value reaches none of them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from mavservo.config import Config, gimbal_settings, load_config_text
from mavservo.control.config_targets import ConfigTargets
from mavservo.control.health_thresholds import health_limits
from mavservo.control.health_watch import HealthWatch
from mavservo.control.live_parameters import LiveParameters
from mavservo.control.servo_backend import ServoBackend
from mavservo.mavlink.backend import Outcome
from mavservo.mavlink.gimbal import GimbalDevice
from tests.support.mavlink_doubles import make_mavlink_core

CONFIG = """
mavlink: {url: "udpin:127.0.0.1:14599", telemetry: {named_value_float_hz: 5}}
can: {buses: [{name: bus0, interface: virtual, channel: t}]}
servos:
  - {name: surface, profile: rmd-x, can_id: 1, limits_deg: [-30, 30]}
  - {name: pitch, profile: rmd-x, can_id: 2, limits_deg: [-90, 30]}
  - {name: yaw, profile: rmd-x, can_id: 3, limits_deg: [-160, 160]}
channels:
  - {servo: surface, source: servo_output, channel: 1, input: {min: 1000, max: 2000},
     output_deg: [-30, 30]}
gimbals:
  - {name: camera, component_id: 154, pitch: pitch, yaw: yaw}
"""
GCS = (255, 190)
MAV_CMD_DO_MOUNT_CONTROL = mav.MAV_CMD_DO_MOUNT_CONTROL
TARGETING = mav.MAV_MOUNT_MODE_MAVLINK_TARGETING


@dataclass
class RecordingSink:
    """The scheduler below the backend: what it was told."""

    sent: list[tuple[str, float]] = field(default_factory=list)

    def set_setpoint(self, servo: str, angle_deg: float, source: str, t: float | None = None):
        self.sent.append((servo, angle_deg))
        return type("Result", (), {"accepted": True, "seq": len(self.sent), "reason": ""})()

    def release(self, servo: str) -> None: ...

    def mark_failsafe(self, servo: str) -> None: ...

    def state(self, servo: str) -> None:
        return None

    def is_online(self, servo: str) -> bool:
        return True


@dataclass
class RecordingSaver:
    submitted: list[dict[str, float]] = field(default_factory=list)

    def submit(self, values: Any) -> None:
        self.submitted.append(dict(values))


class RecordingTarget:
    def __init__(self) -> None:
        self.applied: list[Config] = []

    def apply(self, config: Config, now: float) -> None:
        self.applied.append(config)


def _running(config: Config) -> tuple[LiveParameters, ServoBackend, GimbalDevice, Any, Any]:
    sink = RecordingSink()
    backend = ServoBackend(config, {s.name: sink for s in config.servos})
    watch = HealthWatch(health_limits(config))
    [settings] = gimbal_settings(config)
    gimbal = GimbalDevice(settings, backend)
    targets = ConfigTargets(backend, health=watch, gimbals=[gimbal])
    core, _ = make_mavlink_core(gimbals=(gimbal,))
    targets.attach_telemetry(core)
    owner, saver = _owner(config, targets)
    return owner, backend, gimbal, core, saver


def _owner(config: Config, target: Any) -> tuple[LiveParameters, RecordingSaver]:
    """The owner of ``config``'s parameters (the file is the envelope) with a recording saver."""
    saver = RecordingSaver()
    owner = LiveParameters(config, base=config, overlay={}, saver=saver, target=target)  # type: ignore[arg-type]
    return owner, saver


def _recorded(config: Config) -> tuple[LiveParameters, RecordingTarget, RecordingSaver]:
    """An owner whose target and saver only record what they were handed."""
    target = RecordingTarget()
    owner, saver = _owner(config, target)
    return owner, target, saver


def test_a_set_takes_effect_in_the_mapping_the_gimbal_and_the_telemetry_at_once() -> None:
    config = load_config_text(CONFIG, "live.yaml")
    owner, backend, gimbal, core, saver = _running(config)
    assert owner.set("SRV1_MAX", 10.0, GCS).accepted
    result = backend.apply_servo_output(1, 2000.0, "servo_output", 2.0)
    assert result.outcome is not Outcome.DENIED
    assert backend.servo_statuses()[0].setpoint_deg == 10.0  # the new limit, not 30
    assert owner.set("GMB1_PIT_MIN", -45.0, GCS).accepted
    assert gimbal.settings.limits_deg["pitch"] == (-45.0, 30.0)
    assert owner.set("TEL_NVF_HZ", 7.0, GCS).accepted
    assert core.telemetry.rates_hz()["named_value_float_hz"] == 7.0
    assert owner.config.mavlink.telemetry.named_value_float_hz == 7.0
    assert saver.submitted[-1] == {"SRV1_MAX": 10.0, "GMB1_PIT_MIN": -45.0, "TEL_NVF_HZ": 7.0}


def test_a_refused_value_reaches_nothing_and_says_why() -> None:
    config = load_config_text(CONFIG, "live.yaml")
    owner, target, saver = _recorded(config)
    result = owner.set("SRV1_MAX", 36_000.0, GCS)
    assert not result.accepted and result.value == 30.0
    assert "SRV1_MAX" in result.reason and "-30..30" in result.reason
    assert owner.config is config and owner.value("SRV1_MAX") == 30.0
    assert target.applied == [] and saver.submitted == []


def test_the_overlay_holds_only_differences_from_the_file() -> None:
    """A value set back to the file's value leaves the overlay (float32 as a ground station
    writes back what it read counts as that value)."""
    config = load_config_text(CONFIG, "live.yaml")
    owner, target, saver = _recorded(config)
    assert owner.set("SRV2_FS_TMO", 2.5, GCS).accepted
    assert owner.overlay == {"SRV2_FS_TMO": 2.5}
    assert owner.set("SRV2_FS_TMO", 1.0, GCS).accepted
    assert owner.overlay == {} and saver.submitted == [{"SRV2_FS_TMO": 2.5}, {}]
    assert len(target.applied) == 2


def test_each_component_serves_its_own_names() -> None:
    config = load_config_text(CONFIG, "live.yaml")
    owner, _, _ = _recorded(config)
    everything = owner.names(config.mavlink.servo_component_id)
    assert "SRV1_TRIM" in everything and "GMB1_YAW_MAX" in everything
    assert owner.names(154) == [name for name in everything if name.startswith("GMB1_")]
    assert owner.names(99) == []


def test_a_gimbal_limit_set_reaches_the_pointing_and_the_report_and_a_slew_the_health_watch() -> (
    None
):
    """The device's settings are read by two parts since the split (issue 31 item 4): the
    pointing clamps with them, the report publishes them. A PARAM_SET must reach both, and the
    health watch must judge with the new slew (review of the split against dc16de4)."""
    config = load_config_text(CONFIG, "live.yaml")
    sink = RecordingSink()
    backend = ServoBackend(config, {s.name: sink for s in config.servos})
    watch = HealthWatch(health_limits(config))
    [settings] = gimbal_settings(config)
    gimbal = GimbalDevice(settings, backend)
    owner, _ = _owner(config, ConfigTargets(backend, health=watch, gimbals=[gimbal]))
    assert owner.set("GMB1_PIT_MIN", -45.0, GCS).accepted
    # the pointing: a demand below the new limit is driven to it, not to the file's -90
    result = gimbal.handle_command(MAV_CMD_DO_MOUNT_CONTROL, (-80.0, 0, 0, 0, 0, 0, TARGETING), 1.0)
    assert result == int(Outcome.ACCEPTED)
    assert ("pitch", -45.0) in sink.sent and ("pitch", -80.0) not in sink.sent
    # the report: what a ground station is told the gimbal can reach
    information = gimbal.report.device_information(1.0)
    assert math.isclose(information.pitch_min, math.radians(-45.0), rel_tol=1e-6)
    # the health watch: the slew set is the speed the tracking allowance expects
    assert watch.servos["surface"].limits.speed_dps != 20.0
    assert owner.set("SRV1_SLEW", 20.0, GCS).accepted
    assert watch.servos["surface"].limits.speed_dps == 20.0
