"""DO_REPEAT_SERVO with a cycle shorter than the command loop can carry is DENIED, with a reason
counter, over real UDP against the whole Bridge.

Why: nothing bounded the cycle from below. A 1 ms cycle with count 1000 queued 1,999 steps that
all fell due at the next tick of the MAVLink side: 2,000 setpoints at once, of which the servo
got whichever the scheduler's next command slot found. The shortest cycle accepted is two
command periods (``scheduler.command_period_s``; each half cycle gets a slot of its own), and
never below two ticks of the MAVLink side.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from mavservo.app.bridge import Bridge
from mavservo.config.loader import load_config_text
from tests.redteam.test_bridge_security import GCS, Rig, acks, config_text
from tests.support.waiting import free_udp_port, wait_until

DO_REPEAT_SERVO = 184
DENIED, ACCEPTED = 2, 0


class RigWith(Rig):
    """test_bridge_security's rig (unsigned), its config extended by ``extra`` YAML."""

    def __init__(self, extra: str = "") -> None:
        self.port = free_udp_port()
        text = config_text(self.port, signing=False) + extra
        self.bridge = Bridge(load_config_text(text), log_dir=False)
        self.bridge.start()
        self.peers: list[Any] = []


@pytest.fixture
def rig() -> Iterator[RigWith]:
    rig = RigWith()
    yield rig
    rig.close()


@pytest.fixture
def slow_rig() -> Iterator[RigWith]:
    rig = RigWith("scheduler: {command_period_s: 0.2, refresh_interval_s: 0.4}\n")
    yield rig
    rig.close()


def repeat_servo(conn: Any, channel: int, pwm: float, count: float, cycle_s: float) -> None:
    conn.mav.command_long_send(1, 140, DO_REPEAT_SERVO, 0, channel, pwm, count, cycle_s, 0, 0, 0)


def results(conn: Any) -> list[int]:
    return [a.result for a in acks(conn, DO_REPEAT_SERVO, 1.0)]


def commands(rig: RigWith) -> dict[str, int]:
    return dict(rig.stats()["commands"])


def test_a_one_millisecond_cycle_is_denied_with_a_reason_and_nothing_moves(rig: RigWith) -> None:
    gcs = rig.peer(GCS)
    repeat_servo(gcs, 1, 2000, 1000, 0.001)
    assert results(gcs) == [DENIED]
    assert commands(rig).get("reason_cycle_too_short") == 1
    assert rig.setpoint("left") is None
    assert rig.sim_target(1) == pytest.approx(0.0)
    assert rig.bridge.mavlink is not None
    assert rig.bridge.mavlink.core.commands.repeating_channels() == set()


def test_two_command_periods_is_the_shortest_cycle_accepted(rig: RigWith) -> None:
    gcs = rig.peer(GCS)
    repeat_servo(gcs, 1, 2000, 2, 0.099)  # default command period 0.05 s: 0.1 s is the least
    assert results(gcs) == [DENIED]
    repeat_servo(gcs, 1, 2000, 2, 0.1)
    assert results(gcs) == [ACCEPTED]
    assert wait_until(lambda: rig.setpoint("left") == pytest.approx(0.0))  # ends on trim
    assert commands(rig).get("reason_cycle_too_short") == 1


def test_the_shortest_cycle_follows_the_configured_command_period(slow_rig: RigWith) -> None:
    gcs = slow_rig.peer(GCS)
    repeat_servo(gcs, 1, 2000, 1, 0.3)  # fine at 50 ms slots, too fast for 200 ms ones
    assert results(gcs) == [DENIED]
    repeat_servo(gcs, 1, 2000, 1, 0.4)
    assert results(gcs) == [ACCEPTED]
    assert commands(slow_rig).get("reason_cycle_too_short") == 1
