"""Issue 32 finding 3 and issue 30 item 5: answers go to the requester only, paced, within the
link budget; a broadcast gets one answer; no 1-second window of the link exceeds the budget.

A real bridge on UDP (127.0.0.1) with config/sim.yaml's servos and gimbal (the default config)
and raw sockets that count every byte the bridge sends them, with its arrival time. On c3ae82c
one PARAM_REQUEST_LIST went to every peer (the autopilot included), a READ flood put tens of
kB/s on the link, a broadcast READ drew two answers and raised rates were never re-planned.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import yaml
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.app.bridge import Bridge
from mavservo.config.loader import load_config_text
from mavservo.records.metrics import peak_window_bytes
from tests.support.paths import REPO
from tests.support.waiting import free_udp_port, wait_until

SIM = REPO / "config" / "sim.yaml"
BUDGET = 1000
#: What the measuring side may add to a window: the bridge admits a frame at time t and the
#: socket sees it a moment later, so one frame can land in the neighbouring window (the
#: largest frame the default config sends: ACTUATOR_OUTPUT_STATUS, 152 bytes).
ARRIVAL_SLACK = 152


class RawPeer:
    """A UDP socket that records every datagram from the bridge (time, bytes, messages)."""

    def __init__(self, port: int, source: tuple[int, int]) -> None:
        self.port = port
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.encoder = mavlink2.MAVLink(None, srcSystem=source[0], srcComponent=source[1])
        self.decoder = mavlink2.MAVLink(None)
        self.decoder.robust_parsing = True
        self.samples: list[tuple[float, int]] = []
        self.messages: list[Any] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        self.sock.settimeout(0.05)
        while not self._stop.is_set():
            try:
                data = self.sock.recv(65536)
            except (TimeoutError, OSError):
                continue
            now = time.monotonic()
            decoded = self.decoder.parse_buffer(data) or []
            with self._lock:
                self.samples.append((now, len(data)))
                self.messages.extend(decoded)

    def send(self, msg: Any, source: tuple[int, int] | None = None) -> None:
        if source is not None:
            self.encoder.srcSystem, self.encoder.srcComponent = source
        self.sock.sendto(msg.pack(self.encoder), ("127.0.0.1", self.port))

    def of(self, kind: str, since: int = 0) -> list[Any]:
        with self._lock:
            return [m for m in self.messages[since:] if m.get_type() == kind]

    def count(self) -> int:
        with self._lock:
            return len(self.messages)

    def peak(self, since: float) -> int:
        with self._lock:
            return peak_window_bytes([s for s in self.samples if s[0] >= since])

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.sock.close()


class Autopilot(RawPeer):
    """The autopilot (1/1): HEARTBEAT every 0.5 s until closed."""

    def __init__(self, port: int) -> None:
        super().__init__(port, (1, 1))
        self._beats = threading.Thread(target=self._beat, daemon=True)
        self._beats.start()

    def _beat(self) -> None:
        while not self._stop.is_set():
            self.send(mavlink2.MAVLink_heartbeat_message(1, 3, 0, 0, 4, 3))
            self._stop.wait(0.5)


@contextmanager
def sim_bridge(**mavlink: Any) -> Iterator[tuple[Bridge, int]]:
    raw = yaml.safe_load(SIM.read_text())
    port = free_udp_port()
    raw["mavlink"].update({"url": f"udpin:127.0.0.1:{port}", "monitor_outputs": [], **mavlink})
    raw["mavlink"].pop("request_streams", None)
    bridge = Bridge(load_config_text(yaml.safe_dump(raw), "<sim>"), log_dir=False).start()
    try:
        yield bridge, port
    finally:
        bridge.stop()


def test_a_strangers_list_goes_to_the_stranger_only() -> None:
    # no budget: the list arrives in about 2 s (per-requester pacing); with the default
    # 1,000 B/s it takes its share of the budget (about 15 s for 90 values)
    with sim_bridge(link_budget_bytes_s=None) as (bridge, port):
        autopilot, stranger = Autopilot(port), RawPeer(port, (255, 77))
        try:
            assert wait_until(lambda: autopilot.of("HEARTBEAT"), 3.0)
            stranger.send(mavlink2.MAVLink_param_request_list_message(1, 140))
            assert bridge.parameters is not None
            count = len(bridge.parameters.names(140))
            assert wait_until(
                lambda: len({m.param_index for m in stranger.of("PARAM_VALUE")}) == count, 10.0
            )
            assert autopilot.of("PARAM_VALUE") == []
        finally:
            autopilot.close()
            stranger.close()


def test_a_read_flood_keeps_every_second_of_the_link_within_the_budget() -> None:
    with sim_bridge(link_budget_bytes_s=BUDGET) as (bridge, port):
        autopilot, stranger = Autopilot(port), RawPeer(port, (255, 77))
        try:
            assert wait_until(lambda: autopilot.of("HEARTBEAT"), 3.0)
            start = time.monotonic()
            read = mavlink2.MAVLink_param_request_read_message(1, 140, b"SRV1_TRIM", -1)
            for sent in range(2000):  # 1,000/s for 2 s, bounded
                stranger.send(read)
                time.sleep(max(0.0, start + sent / 1000 - time.monotonic()))
            time.sleep(1.0)
            assert stranger.of("PARAM_VALUE"), "the stranger is answered (paced)"
            assert autopilot.of("PARAM_VALUE") == []
            for peer in (autopilot, stranger):
                assert peer.peak(start) <= BUDGET + ARRIVAL_SLACK, peer.peak(start)
        finally:
            autopilot.close()
            stranger.close()


def test_a_broadcast_is_answered_once_by_the_owner_and_an_unknown_name_not_at_all() -> None:
    with sim_bridge() as (bridge, port):
        autopilot, gcs = Autopilot(port), RawPeer(port, (255, 190))
        try:
            assert wait_until(lambda: autopilot.of("HEARTBEAT"), 3.0)
            for name, owner in ((b"SRV1_TRIM", 140), (b"GMB1_PIT_MAX", 154)):
                start = gcs.count()
                gcs.send(mavlink2.MAVLink_param_request_read_message(1, 0, name, -1))
                assert wait_until(lambda s=start: gcs.of("PARAM_VALUE", s), 3.0)
                time.sleep(0.5)  # room for a second answer, which must not come
                answers = gcs.of("PARAM_VALUE", start) + gcs.of("PARAM_ERROR", start)
                assert [m.get_srcComponent() for m in answers] == [owner], name
            start = gcs.count()
            gcs.send(mavlink2.MAVLink_param_request_read_message(1, 0, b"NO_SUCH_NAME", -1))
            time.sleep(0.8)
            assert gcs.of("PARAM_VALUE", start) + gcs.of("PARAM_ERROR", start) == []
        finally:
            autopilot.close()
            gcs.close()


def test_rates_raised_by_parameter_and_message_interval_stay_within_the_budget() -> None:
    writer = [{"system": 255, "component": 190}]
    with sim_bridge(link_budget_bytes_s=BUDGET, allowed_sources=writer) as (bridge, port):
        autopilot, gcs = Autopilot(port), RawPeer(port, (255, 190))
        try:
            assert wait_until(lambda: autopilot.of("HEARTBEAT"), 3.0)
            gcs.send(mavlink2.MAVLink_param_set_message(1, 140, b"TEL_NVF_HZ", 100.0, 9))
            gcs.send(mavlink2.MAVLink_param_set_message(1, 140, b"TEL_AOS_HZ", 100.0, 9))
            interval = mavlink2.MAVLink_command_long_message(
                1, 140, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 11030, 10_000, 0, 0, 0, 0, 0
            )
            gcs.send(interval)  # ESC_TELEMETRY_1_TO_4 at 100 Hz
            assert wait_until(
                lambda: bridge.mavlink.stats()["link_budget"].get("replans", 0) >= 2, 3.0
            )
            start = time.monotonic()
            time.sleep(3.0)
            for peer in (autopilot, gcs):
                assert peer.peak(start) <= BUDGET + ARRIVAL_SLACK, peer.peak(start)
            stats = bridge.mavlink.stats()["link_budget"]
            assert stats["planned_bytes_s"] <= BUDGET
        finally:
            autopilot.close()
            gcs.close()


def test_the_default_config_keeps_every_second_within_the_budget() -> None:
    """Issue 30 item 5, the loopback equivalent of bench/bench_link_budget.py --windows (60 s):
    6 s of the default config's output, every 1-second window at or under the budget."""
    with sim_bridge() as (bridge, port):
        autopilot = Autopilot(port)
        try:
            assert wait_until(lambda: autopilot.of("HEARTBEAT"), 3.0)
            start = time.monotonic()
            time.sleep(6.0)
            assert autopilot.peak(start) <= BUDGET + ARRIVAL_SLACK, autopilot.peak(start)
            assert bridge.mavlink.stats()["link_budget"]["budget_bytes_s"] == BUDGET
        finally:
            autopilot.close()
