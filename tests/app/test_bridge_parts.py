"""The bridge's parts, each alone: its event outlets, its health reporting, its identity line and
its buses (the whole bridge goes through them in tests/e2e and tests/app/test_*bridge*)."""

from __future__ import annotations

from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import can

from mavservo.app.bridge_buses import BridgeBuses
from mavservo.app.bridge_events import (
    MAV_SEVERITY_CRITICAL,
    MAV_SEVERITY_NOTICE,
    MAV_SEVERITY_WARNING,
    BridgeEvents,
)
from mavservo.app.bridge_identity import BridgeIdentity
from mavservo.app.health_reporting import HealthReporter
from mavservo.config import load_config_text
from mavservo.control import HealthEvent, HealthWatch, health_limits
from mavservo.mavlink import Health
from tests.support.mavlink_doubles import RecordingBackend, make_mavlink_core, wire

CONFIG = """
mavlink: {url: "udpin:127.0.0.1:14599"}
can: {buses: [{name: bus0, interface: virtual, channel: parts-bus0}]}
servos:
  - {name: elevator, profile: rmd-x, can_id: 1, health: {temperature_warning_c: 60,
     temperature_limit_c: 70, temperature_action: hold}}
"""


@dataclass
class RecordingAnnouncer:
    said: list[tuple[str, int]] = field(default_factory=list)
    fail: bool = False

    def announce(self, text: str, severity: int) -> None:
        if self.fail:
            raise RuntimeError("link gone")
        self.said.append((text, severity))


def _events(kept: int = 1000) -> tuple[BridgeEvents, list[str], RecordingAnnouncer]:
    console: list[str] = []
    events = BridgeEvents(console.append, clock=lambda: 5.0, kept=kept)
    announcer = RecordingAnnouncer()
    events.announcer = announcer
    return events, console, announcer


def test_an_event_goes_to_the_console_the_list_and_statustext_a_note_not_to_statustext() -> None:
    events, console, announcer = _events()
    events.note("identity")
    events.event("bus0: adapter lost")
    assert console == ["identity", "bus0: adapter lost"]
    assert events.events == [(5.0, "identity"), (5.0, "bus0: adapter lost")]
    assert announcer.said == [("bus0: adapter lost", MAV_SEVERITY_WARNING)]
    assert events.recent(1) == ["bus0: adapter lost"]


def test_the_event_list_is_bounded_and_a_failing_link_never_raises_into_the_reporter() -> None:
    events, _, announcer = _events(kept=10)
    announcer.fail = True
    for n in range(100):
        events.event(f"#{n}")
    assert len(events.events) <= 20 and events.events[-1][1] == "#99"
    events.announcer = None
    events.event("before the MAVLink side exists")  # said on the console, nowhere else


@dataclass
class HealthActions:
    """The servo backend as health reporting drives it."""

    actions: list[tuple[str, str | None]] = field(default_factory=list)

    def servo_statuses(self) -> list[Any]:
        return []

    def set_health_action(
        self, name: str, action: str | None, now: float, slow_factor: float = 0.5
    ) -> None:
        self.actions.append((name, action))


def test_health_onsets_are_warned_or_critical_clearings_noticed_and_overheating_acted_on() -> None:
    config = load_config_text(CONFIG, "parts.yaml")
    watch = HealthWatch(health_limits(config))
    backend = HealthActions()
    events, console, announcer = _events()
    reporter = HealthReporter(watch, backend, events, runlog=None)  # type: ignore[arg-type]
    reporter.report(HealthEvent("elevator", Health.HOT, True, 1.0, "elevator: hot"))
    reporter.report(HealthEvent("elevator", Health.JAMMED, True, 1.1, "elevator: jammed"))
    reporter.report(HealthEvent("elevator", Health.JAMMED, False, 2.0, "elevator: moves"))
    reporter.report(HealthEvent("elevator", Health.HOT, True, 2.1, "quiet", announce=False))
    reporter.report(HealthEvent("elevator", Health.OVERHEATED, True, 3.0, "elevator: 71 C"))
    assert announcer.said == [
        ("elevator: hot", MAV_SEVERITY_WARNING),
        ("elevator: jammed", MAV_SEVERITY_CRITICAL),
        ("elevator: moves", MAV_SEVERITY_NOTICE),
        ("elevator: 71 C", MAV_SEVERITY_CRITICAL),
    ]
    # an episode inside its text spacing: in the run log, not said on either output (the
    # console says what the ground station is told, issue 37)
    assert "quiet" not in console
    # the watch has not seen the servo overheat: no action in force yet, and it is asked
    assert backend.actions == [("elevator", None)]


def test_the_identity_line_is_said_at_start_and_again_when_the_esc_numbers_move() -> None:
    core, backend = make_mavlink_core(RecordingBackend())
    servos = len(backend.servo_statuses())
    events, console, _ = _events()
    side = SimpleNamespace(core=core)
    identity = BridgeIdentity(side, servos=servos, notes=events)  # type: ignore[arg-type]
    first = core.telemetry.esc_first
    identity.note_change()
    identity.note_change()
    assert len(console) == 1 and f"servos as ESC {first}-{first + servos - 1}," in console[0]
    group = (first - 1) // 4
    core.telemetry.heard_esc((1, 1), group, yield_to=True)  # the autopilot publishes them
    moved = core.telemetry.esc_first
    assert moved != first
    identity.note_change()
    assert len(console) == 2 and f"servos as ESC {moved}-{moved + servos - 1}," in console[1]
    assert identity.shown == console[1]


def test_the_buses_are_opened_from_the_config_by_name_and_closed() -> None:
    config = load_config_text(CONFIG, "parts.yaml")
    buses = BridgeBuses(config, on_event=lambda text: None, on_reject=lambda *args: None)
    buses.open_all(runlog=None)
    try:
        with can.Bus(interface="virtual", channel="parts-bus0") as peer:
            peer.send(can.Message(arbitration_id=0x141, data=b"\x9c" + bytes(7)))
            got = buses.buses["bus0"].recv(1.0)
        assert got is not None and got.arbitration_id == 0x141
        assert buses.transport_stats("bus0")["connected"] is True  # reconnecting wrapper
        assert buses.emulators == {}  # no simulated adapter on a virtual bus
    finally:
        buses.close()


def test_a_failsafe_is_one_statustext_per_event_never_cut() -> None:
    """Issue 37: each failsafe transition sent two STATUSTEXTs, the servo side's
    "failsafe cleared: servos move again on fresh commands" chunked mid-word. The servo side's
    words go to the console; the MAVLink side says each transition once, in one message."""
    from mavservo.control.servo_backend import ServoBackend
    from tests.control.test_servo_backend import CONFIG as BACKEND_CONFIG
    from tests.control.test_servo_backend import RecordingSink

    events, console, announcer = _events()
    config = load_config_text(BACKEND_CONFIG, "backend.yaml")
    sink = RecordingSink()
    backend = ServoBackend(config, {s.name: sink for s in config.servos}, on_event=events.event)
    backend.enter_failsafe("autopilot heartbeat lost", 1.0)
    backend.leave_failsafe(2.0)
    assert any(line.startswith("failsafe: ") for line in console)
    assert any(line.startswith("failsafe cleared: ") for line in console)
    assert not any("failsafe" in text for text, _ in announcer.said)

    core, _ = make_mavlink_core(heartbeat_timeout_s=2.0)
    core.on_message(wire(_heartbeat(), (1, 1)), 10.0)
    out = core.tick(12.5)
    core.on_message(wire(_heartbeat(), (1, 1)), 14.0)
    out += core.tick(14.1)
    texts = [m for _, m in out if m.get_type() == "STATUSTEXT"]
    assert [m.text for m in texts] == [
        "servo bridge: autopilot lost, servos in failsafe",
        "servo bridge: autopilot back, waiting for commands",
    ]
    assert [m.id for m in texts] == [0, 0]  # one message each, no chunks


def _heartbeat() -> Any:
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    return mavlink2.MAVLink_heartbeat_message(1, 3, 0, 0, 4, 3)


def test_the_summary_takes_the_reply_outcomes_the_stop_booked() -> None:
    """The summary is taken before the schedulers stop; replies still in the bus then were
    read as lost. After the stop the scheduler booked them late: the summary says so, counts
    them received, and keeps its frames sent (the stop frames are counted apart)."""
    from mavservo.app.bridge import reply_outcomes_at_stop

    before = {"s1": {"frames": {"sent": 100, "received": 96, "timed_out": 4, "late": 0, "lost": 4}}}
    after = {"s1": {"frames": {"sent": 102, "received": 102, "timed_out": 4, "late": 4, "lost": 0}}}
    after["gone"] = {"frames": {"timed_out": 9, "late": 0, "lost": 9}}  # not in the summary
    reply_outcomes_at_stop(before, after)
    assert before == {
        "s1": {"frames": {"sent": 100, "received": 100, "timed_out": 4, "late": 4, "lost": 0}}
    }
