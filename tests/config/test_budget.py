"""The worst-case bus load counts what each servo really puts on the bus."""

from __future__ import annotations

import pytest

from mavservo.config import bus_loads, default_config_path, load_config, load_config_text
from mavservo.config.budget import servo_flows
from mavservo.config.views import servo_specs, timing_config
from mavservo.scheduling.schedule_core import ScheduleCore


def _config(hz: int):
    return load_config_text(
        f"servos:\n  - {{name: g, profile: cubemars-ak, can_id: 1, telemetry_hz: {hz}}}\n"
        "scheduler: {telemetry_period_s: 0.09}\n"
    )


def test_push_style_status_frames_count_at_their_own_rate_not_the_poll_cap() -> None:
    """A CubeMars servo pushes status at ``telemetry_hz`` (as the simulated one does); the
    telemetry loop's 11.1 Hz cap paces only polls, so it must not shrink these frames."""
    slow, fast = _config(20), _config(40)
    status = [f for f in servo_flows(fast.servos[0], fast.scheduler) if f.rate_hz == 40]
    assert len(status) == 1
    assert bus_loads(fast)[0].load > bus_loads(slow)[0].load


def test_check_and_the_running_scheduler_estimate_the_same_worst_case() -> None:
    """``mavservo check`` and the scheduler (the run summary's "worst case") count the same
    frames, push-style status included: config/sim.yaml mixes polled and push-style servos."""
    config = load_config(default_config_path())
    bus = config.can.buses[0]
    specs = servo_specs(config, bus.name)
    assert any(not spec.profile.telemetry_requests() for spec in specs)
    timing = timing_config(config, bus)
    core = ScheduleCore(specs, timing, start=0.0)
    assert core.worst_case_load == pytest.approx(bus_loads(config)[0].load, rel=1e-9)
