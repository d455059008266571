"""The worst-case bus load counts what each servo really puts on the bus."""

from __future__ import annotations

from mavservo.config import bus_loads, load_config_text
from mavservo.config.budget import servo_flows


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
