"""Bridge health figures: bus loads and the wire round trip L over every bus, in ms.

Real schedulers on python-can ``virtual`` buses (not started: their latency windows are filled
directly), read through the bridge that owns them, as the telemetry publisher does.
"""

from __future__ import annotations

import uuid
from collections.abc import Iterator

import can
import pytest

from mavservo.app.bridge import Bridge
from mavservo.config import load_config_text
from mavservo.scheduling.runner import Scheduler, ServoSpec
from mavservo.servos import RmdX

CONFIG = """
mavlink: {url: "udpin:127.0.0.1:14599"}
can:
  buses:
    - {name: a, interface: virtual, channel: a}
    - {name: b, interface: virtual, channel: b}
servos:
  - {name: surface, profile: rmd-x, can_id: 1, bus: a}
  - {name: throttle, profile: rmd-x, can_id: 2, bus: a}
  - {name: hook, profile: rmd-x, can_id: 3, bus: b}
"""


@pytest.fixture
def buses() -> Iterator[list[can.BusABC]]:
    opened = [can.Bus(interface="virtual", channel=f"health-{uuid.uuid4().hex}") for _ in range(2)]
    yield opened
    for bus in opened:
        bus.shutdown()


def test_health_has_the_round_trip_percentiles_of_every_bus_once(
    buses: list[can.BusABC],
) -> None:
    bridge = Bridge(load_config_text(CONFIG, "health.yaml"), log_dir=False)
    bus_a = Scheduler(buses[0], [ServoSpec("surface", RmdX(1)), ServoSpec("throttle", RmdX(2))])
    bus_b = Scheduler(buses[1], [ServoSpec("hook", RmdX(3))])
    bus_a.metrics_store.servos["surface"].latency.extend([0.001, 0.002])
    bus_a.metrics_store.servos["throttle"].latency.extend([0.003])
    bus_b.metrics_store.servos["hook"].latency.extend([0.004, 0.005])
    bridge.schedulers = {"a": bus_a, "b": bus_b}

    health = bridge._health()

    assert health["bus0_load"] == health["bus1_load"] == 0.0  # nothing on the wire yet
    # percentiles over 1..5 ms, each sample once
    assert health["rtt_p50"] == pytest.approx(3.0)
    assert health["rtt_p95"] == pytest.approx(4.8)
    assert health["rtt_p99"] == pytest.approx(4.96)
    assert "lat_p50" not in health  # no run log, no command -> telemetry traces


def test_health_without_round_trips_has_no_rtt_figures(buses: list[can.BusABC]) -> None:
    bridge = Bridge(load_config_text(CONFIG, "health.yaml"), log_dir=False)
    bridge.schedulers = {"a": Scheduler(buses[0], [ServoSpec("surface", RmdX(1))])}
    assert bridge._health() == {"bus0_load": 0.0}


def test_a_long_bridge_event_reaches_the_mavlink_side_whole() -> None:
    """Adapter events name the device path; the link chunks long STATUSTEXT, so the bridge must
    not cut them (a trial received "bus0: CAN adapter lost (aa55: the adapter on /tmp/")."""
    from types import SimpleNamespace

    from mavservo.app.bridge import Bridge
    from mavservo.config import default_config_path, load_config

    bridge = Bridge(load_config(default_config_path()), log_dir=False, status=lambda _: None)
    sent: list[str] = []
    capture = SimpleNamespace(announce=lambda text, severity: sent.append(text))
    bridge.mavlink = capture  # type: ignore[assignment]
    text = (
        "bus0: CAN adapter lost (aa55: the adapter on "
        "/dev/serial/by-id/usb-1a86_USB2.0-Ser_-if00 is gone); reconnecting"
    )
    bridge._event(text)
    assert sent == [text]
