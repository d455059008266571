"""The typed boundaries between layers do what their contracts say
(docs/engineering/architecture.md).

Each test drives a boundary through its Protocol: the sink's typed result decides what the
backend answers, an observer that implements only some hooks still gets them through the
bridge's fan-out, and the config's AA-55 bitrates are the codec's table, not a copy of it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import can
import pytest

from mavservo.app.bridge import _FanOut
from mavservo.config import BusConfig, ConfigError, load_config_text
from mavservo.control.servo_backend import ServoBackend
from mavservo.mavlink.backend import Outcome
from mavservo.scheduling.runner import SchedulerObserver
from mavservo.scheduling.schedule_core import SetpointResult
from mavservo.servos.base import ServoState
from mavservo.transport.aa55 import codec

CONFIG = """
servos:
  - {name: surface, profile: rmd-x, can_id: 1, limits_deg: [-30, 30]}
channels:
  - {servo: surface, source: servo_output, channel: 1, input: {min: 1100, max: 1900, trim: 1500},
     output_deg: [-30, 30]}
"""


@dataclass
class RefusingSink:
    """A scheduler that refuses every setpoint with its reason (an unknown or stale one)."""

    reason: str = "stale: older than accepted setpoint #3"
    asked: list[float] = field(default_factory=list)

    def set_setpoint(
        self, servo: str, angle_deg: float, source: str, t: float | None = None
    ) -> SetpointResult:
        self.asked.append(angle_deg)
        return SetpointResult(False, None, self.reason)

    def release(self, servo: str) -> None:
        pass

    def mark_failsafe(self, servo: str) -> None:
        pass

    def state(self, servo: str) -> ServoState | None:
        return None

    def is_online(self, servo: str) -> bool:
        return True


def test_a_refused_setpoint_is_denied_with_the_schedulers_reason() -> None:
    sink = RefusingSink()
    backend = ServoBackend(load_config_text(CONFIG), {"surface": sink}, on_event=lambda _: None)
    result = backend.apply_servo_output(1, 1700.0, "do_set_servo", 0.0)
    assert sink.asked == [pytest.approx(15.0)]
    assert result.outcome is Outcome.DENIED
    assert result.reason == sink.reason
    assert backend.servo_statuses()[0].setpoint_deg == pytest.approx(15.0)


def test_a_refusal_without_a_reason_still_says_who_refused() -> None:
    sink = RefusingSink(reason="")
    backend = ServoBackend(load_config_text(CONFIG), {"surface": sink}, on_event=lambda _: None)
    result = backend.apply_servo_output(1, 1700.0, "do_set_servo", 0.0)
    assert result.outcome is Outcome.DENIED
    assert result.reason == "rejected by the scheduler"


class LostCounter(SchedulerObserver):
    """An observer that needs one hook: it inherits no-ops for the others."""

    def __init__(self) -> None:
        self.lost: list[tuple[str, str, float]] = []

    def on_lost(self, bus: str, servo: str, t: float) -> None:
        self.lost.append((bus, servo, t))


def test_the_fan_out_calls_each_observer_and_partial_observers_inherit_no_ops() -> None:
    partial, other = LostCounter(), LostCounter()
    fan_out = _FanOut(None, partial, other)
    msg = can.Message(arbitration_id=0x141, data=bytes(8))
    fan_out.on_setpoint("surface", 1, 10.0, "test", 0.5)
    fan_out.on_tx("bus0", msg, 1.0, "command", "surface", 1)
    fan_out.on_rx("bus0", msg, 1.1, "surface", ServoState.unknown(1.1))
    fan_out.on_reject("bus0", "bad checksum", b"\xaa", 1.2)
    fan_out.on_lost("bus0", "surface", 2.0)
    assert partial.lost == other.lost == [("bus0", "surface", 2.0)]


def _aa55_bus_config(bitrate: int) -> str:
    return f"can:\n  buses:\n    - {{name: bus0, interface: aa55, bitrate: {bitrate}}}\n" + CONFIG


def test_the_config_takes_the_aa55_bitrates_from_the_codec(monkeypatch) -> None:
    """One table: a bitrate the codec learns a code for is one the config accepts."""
    with pytest.raises(ConfigError, match="supports bitrates"):
        load_config_text(_aa55_bus_config(33_333))
    monkeypatch.setitem(codec.BITRATE_CODES, 33_333, 0x0D)
    config = load_config_text(_aa55_bus_config(33_333))
    assert config.can.buses[0].bitrate == 33_333


@pytest.mark.parametrize("bitrate", sorted(codec.BITRATE_CODES))
def test_every_bitrate_the_codec_can_set_is_a_valid_aa55_bus(bitrate: int) -> None:
    """The bus alone (the whole config's load budget refuses the slowest rates for a servo)."""
    assert BusConfig(interface="aa55", bitrate=bitrate).bitrate == bitrate
    assert codec.settings_frame(bitrate)[3] == codec.BITRATE_CODES[bitrate]
