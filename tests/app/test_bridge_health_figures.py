"""Bridge health figures: bus loads and the wire round trip L over every bus, in ms; and a long
bridge event reaching the MAVLink side whole.

The figures: real schedulers on python-can ``virtual`` buses (not started: their latency
windows are filled directly) handed to ``health_figures``, the function ``Bridge`` computes its
telemetry figures with. The event: a started bridge whose adapter is unplugged, heard by a
MAVLink peer over UDP.
"""

from __future__ import annotations

import uuid
from collections.abc import Iterator

import can
import pytest

from mavservo.app.bridge import health_figures
from mavservo.mavlink.telemetry import STATUSTEXT_LENGTH, join_statustext_chunks
from mavservo.scheduling.runner import Scheduler, ServoSpec
from mavservo.servos import RmdX
from tests.support.bridge import MAV_CMD_DO_SET_SERVO, MAV_RESULT_ACCEPTED, Peer, running
from tests.support.waiting import wait_until


@pytest.fixture
def buses() -> Iterator[list[can.BusABC]]:
    opened = [can.Bus(interface="virtual", channel=f"health-{uuid.uuid4().hex}") for _ in range(2)]
    yield opened
    for bus in opened:
        bus.shutdown()


def test_health_has_the_round_trip_percentiles_of_every_bus_once(
    buses: list[can.BusABC],
) -> None:
    bus_a = Scheduler(buses[0], [ServoSpec("surface", RmdX(1)), ServoSpec("throttle", RmdX(2))])
    bus_b = Scheduler(buses[1], [ServoSpec("hook", RmdX(3))])
    bus_a.metrics_store.servos["surface"].latency.extend([0.001, 0.002])
    bus_a.metrics_store.servos["throttle"].latency.extend([0.003])
    bus_b.metrics_store.servos["hook"].latency.extend([0.004, 0.005])

    health = health_figures([bus_a, bus_b])

    assert health["bus0_load"] == health["bus1_load"] == 0.0  # nothing on the wire yet
    # percentiles over 1..5 ms, each sample once
    assert health["rtt_p50"] == pytest.approx(3.0)
    assert health["rtt_p95"] == pytest.approx(4.8)
    assert health["rtt_p99"] == pytest.approx(4.96)
    assert "lat_p50" not in health  # no run log, no command -> telemetry traces


def test_health_without_round_trips_has_no_rtt_figures(buses: list[can.BusABC]) -> None:
    assert health_figures([Scheduler(buses[0], [ServoSpec("surface", RmdX(1))])]) == {
        "bus0_load": 0.0
    }


def test_health_has_the_command_to_telemetry_latency_of_the_run_log_in_ms(
    buses: list[can.BusABC],
) -> None:
    total = {"n": 3, "p50": 0.1045, "p95": 0.12, "p99": None}  # seconds, as the tracer has them
    health = health_figures([Scheduler(buses[0], [ServoSpec("s", RmdX(1))])], total)
    assert health["lat_p50"] == pytest.approx(104.5)
    assert health["lat_p95"] == pytest.approx(120.0)
    assert "lat_p99" not in health  # no figure rather than a made-up one


ONE_SERVO = """
servos:
  - {name: s1, profile: rmd-x, can_id: 1, limits_deg: [-90, 90], telemetry_hz: 10}
channels:
  - {servo: s1, source: servo_output, channel: 1, output_deg: [-90, 90]}
"""


def whole_statustexts(messages: list) -> list[str]:
    """STATUSTEXT texts as sent: MAVLink 2 chunks (same nonzero ``id``) joined by
    ``chunk_seq``; a text with ``id`` 0 is one message."""
    texts: list[str] = []
    chunks: dict[int, dict[int, str]] = {}
    for msg in messages:
        if msg.id == 0:
            texts.append(msg.text)
        else:
            chunks.setdefault(msg.id, {})[msg.chunk_seq] = msg.text
    texts += [
        join_statustext_chunks([parts[k] for k in sorted(parts)]) for parts in chunks.values()
    ]
    return texts


def test_a_long_bridge_event_reaches_the_mavlink_side_whole() -> None:
    """Adapter events name the device path; the link chunks long STATUSTEXT, so the bridge must
    not cut them (a trial received "bus0: CAN adapter lost (aa55: the adapter on /tmp/").
    Through public seams only: the adapter emulator is unplugged under a started bridge."""
    with running(ONE_SERVO) as (bridge, port):
        peer = Peer(port)
        try:  # a command first: the bridge then knows where its peer is
            assert peer.command(MAV_CMD_DO_SET_SERVO, [1, 1500]) == MAV_RESULT_ACCEPTED
            mark = peer.count()
            bridge.emulators["bus0"].unplug()
            assert wait_until(lambda: any("adapter lost" in t for _, t in bridge.events), 5)
            text = next(t for _, t in bridge.events if "adapter lost" in t)
            assert len(text) > STATUSTEXT_LENGTH  # the event needs more than one STATUSTEXT
            assert wait_until(
                lambda: text in whole_statustexts(peer.since(mark, "STATUSTEXT")), 5
            ), (text, whole_statustexts(peer.since(mark, "STATUSTEXT")))
        finally:
            peer.close()
