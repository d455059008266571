"""Fitting the real vehicle: ESC numbers that do not collide, a radio-sized link budget, and two
bridges side by side behind a router, over real UDP sockets on 127.0.0.1."""

from __future__ import annotations

import contextlib
import re
import select
import socket
import threading
from collections.abc import Iterator
from typing import Any

from mavservo.app.bridge import Bridge
from mavservo.app.check import check_main
from mavservo.config import load_config_text
from mavservo.config.loader import default_config_path
from mavservo.mavlink.connection import mavlink2
from mavservo.sim.autopilot.factory import simulator_from_config
from tests.support.bridge import MAV_CMD_DO_SET_SERVO, MAV_RESULT_ACCEPTED, Peer, running
from tests.support.waiting import free_udp_port, wait_until

SERVOS = """\
servos:
  - {name: a, profile: rmd-x, can_id: 1}
  - {name: b, profile: rmd-x, can_id: 2}
  - {name: c, profile: rmd-x, can_id: 3}
channels:
  - {source: servo_output, channel: 1, servo: a}
  - {source: servo_output, channel: 2, servo: b}
  - {source: servo_output, channel: 3, servo: c}
"""


def esc_from(peer: Peer, component: int, start: int = 0) -> set[str]:
    return {
        m.get_type()
        for m in peer.since(start)
        if m.get_type().startswith("ESC_TELEMETRY_") and m.get_srcComponent() == component
    }


def motor_esc(peer: Peer) -> None:
    """What ArduPilot sends for its motors: ESC_TELEMETRY from the autopilot, 17..20 here."""
    zeros = [0] * 4
    peer.send(
        mavlink2.MAVLink_esc_telemetry_17_to_20_message(zeros, zeros, zeros, zeros, zeros, zeros),
        1,
        1,
    )


def test_auto_esc_numbers_start_above_motors_and_move_off_the_autopilots() -> None:
    with running(SERVOS, extra_mavlink="  link_budget_bytes_s: null\n") as (bridge, port):
        peer = Peer(port)
        try:
            peer.start_heartbeats()
            assert wait_until(lambda: esc_from(peer, 140) == {"ESC_TELEMETRY_17_TO_20"})
            motor_esc(peer)
            assert wait_until(lambda: any("moved to ESC 21-23" in t for t in peer.statustexts()))
            mark = peer.count()
            assert wait_until(lambda: "ESC_TELEMETRY_21_TO_24" in esc_from(peer, 140, mark))
            later = peer.count()
            assert wait_until(lambda: len(peer.since(later, "ESC_TELEMETRY_21_TO_24")) >= 2)
            assert esc_from(peer, 140, later) == {"ESC_TELEMETRY_21_TO_24"}
            assert bridge.mavlink.stats()["telemetry"]["esc_moved"] == 1
        finally:
            peer.close()


def test_a_fixed_esc_index_stays_and_warns_once() -> None:
    extra = "  link_budget_bytes_s: null\n  telemetry: {esc_first_index: 17}\n"
    with running(SERVOS, extra_mavlink=extra) as (bridge, port):
        peer = Peer(port)
        try:
            peer.start_heartbeats()
            assert wait_until(lambda: esc_from(peer, 140) == {"ESC_TELEMETRY_17_TO_20"})
            for _ in range(5):
                motor_esc(peer)
            assert wait_until(lambda: any("also come from 1/1" in t for t in peer.statustexts()))
            assert bridge.mavlink.stats()["telemetry"]["esc_collisions"] == 1
            mark = peer.count()
            assert wait_until(lambda: len(peer.since(mark, "ESC_TELEMETRY_17_TO_20")) >= 2)
            assert esc_from(peer, 140, mark) == {"ESC_TELEMETRY_17_TO_20"}
        finally:
            peer.close()


# ------------------------------------------------------------------------------ bandwidth


class Listener:
    """A UDP socket on 127.0.0.1 that decodes what a monitor output sends it."""

    def __init__(self) -> None:
        self.port = free_udp_port()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", self.port))
        self.sock.settimeout(0.05)
        self.decoder = mavlink2.MAVLink(None)
        self.decoder.robust_parsing = True
        self.messages: list[Any] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            with contextlib.suppress(TimeoutError, OSError):
                data = self.sock.recv(65536)
                self.messages.extend(m for m in self.decoder.parse_buffer(data) or [])

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.sock.close()


def telemetry_bytes(messages: list[Any]) -> int:
    periodic = ("NAMED_VALUE_FLOAT", "ESC_TELEMETRY_", "ACTUATOR_OUTPUT_STATUS")
    return sum(len(m.get_msgbuf()) for m in messages if m.get_type().startswith(periodic))


def test_the_link_carries_the_budgeted_share_and_the_monitor_everything() -> None:
    monitor = Listener()
    extra = f"  monitor_outputs: ['udpout:127.0.0.1:{monitor.port}']\n  link_budget_bytes_s: 400\n"
    try:
        with running(SERVOS, extra_mavlink=extra) as (bridge, port):
            peer = Peer(port)
            try:
                peer.start_heartbeats()
                assert wait_until(lambda: len(peer.messages("NAMED_VALUE_FLOAT")) >= 20, 15.0)
                link = [
                    m
                    for m in peer.messages()
                    if m.get_srcSystem() == 1 and m.get_srcComponent() == 140
                ]
                mirrored = [m for m in list(monitor.messages) if m.get_srcComponent() == 140]
                plan = bridge.mavlink.core.budget.plan
                ratio = plan.ratios["NAMED_VALUE_FLOAT"]
            finally:
                peer.close()
    finally:
        monitor.close()
    assert 0 < ratio < 0.5
    on_link = sum(m.get_type() == "NAMED_VALUE_FLOAT" for m in link)
    on_monitor = sum(m.get_type() == "NAMED_VALUE_FLOAT" for m in mirrored)
    # the link got the budget's share of what the monitor got (counts, not time): a few
    # messages of slack for the moment each side's count was taken
    assert on_link <= ratio * on_monitor + 30
    assert on_monitor >= 3 * on_link
    share = telemetry_bytes(link) / max(1, telemetry_bytes(mirrored))
    assert share <= plan.link_bytes_s / plan.full_bytes_s + 0.1
    # every periodic message the link got is also on the monitor: it keeps full rates
    names_link = {m.name for m in link if m.get_type() == "NAMED_VALUE_FLOAT"}
    names_monitor = {m.name for m in mirrored if m.get_type() == "NAMED_VALUE_FLOAT"}
    assert names_link <= names_monitor


def test_check_prints_identity_esc_numbers_and_the_link_estimate(tmp_path: Any) -> None:
    import io

    from mavservo.config import load_config

    servos = len(load_config(default_config_path()).servos)
    out, err = io.StringIO(), io.StringIO()
    assert check_main([str(default_config_path())], out=out, err=err) == 0
    text = out.getvalue()
    assert f"servo ESC numbers: ESC 17-{16 + servos}" in text
    assert "autopilot link: 648 B/s of periodic telemetry within a budget of 1,000 B/s" in text
    assert "no second above 1,000 B/s" in text
    assert "monitor outputs:" in text
    # decimated to fit (the rate depends on every stream of the plan), never dropped to 0
    assert re.search(r"NAMED_VALUE_FLOAT: 0\.\d*[1-9]\d* Hz on the link \(2 Hz configured\)", text)


# ------------------------------------------------------------------------ two bridges


class Router:
    """A tiny MAVLink router on loopback UDP (what mavlink-router or mavp2p do): every datagram
    from one endpoint goes to all the others. ``listen`` endpoints are ports peers send to
    (the autopilot, a GCS); ``targets`` are ``udpin`` ports of bridges it sends to."""

    def __init__(self, targets: list[int], listeners: int) -> None:
        self.sockets: list[socket.socket] = []
        self.addresses: dict[socket.socket, tuple[str, int] | None] = {}
        self.ports: list[int] = []
        for _ in range(listeners):
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.bind(("127.0.0.1", 0))
            self.ports.append(sock.getsockname()[1])
            self.sockets.append(sock)
            self.addresses[sock] = None  # learnt from the first datagram
        for port in targets:
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.bind(("127.0.0.1", 0))
            self.sockets.append(sock)
            self.addresses[sock] = ("127.0.0.1", port)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select(self.sockets, [], [], 0.05)
            for sock in ready:
                with contextlib.suppress(OSError):
                    data, sender = sock.recvfrom(65536)
                    if self.addresses[sock] is None or sock in self.sockets[: len(self.ports)]:
                        self.addresses[sock] = sender
                    for other in self.sockets:
                        address = self.addresses[other]
                        if other is not sock and address is not None:
                            other.sendto(data, address)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        for sock in self.sockets:
            sock.close()


def bridge_on(port: int, component: int, prefix: str) -> Bridge:
    head = (
        f"mavlink:\n  url: udpin:127.0.0.1:{port}\n  servo_component_id: {component}\n"
        f"  link_budget_bytes_s: null\n  telemetry: {{name_prefix: {prefix}}}\n"
    )
    return Bridge(load_config_text(head + SERVOS, f"<bridge {component}>"), log_dir=False)


@contextlib.contextmanager
def two_bridges() -> Iterator[tuple[Bridge, Bridge, Peer]]:
    port_a, port_b = free_udp_port(), free_udp_port()
    first, second = bridge_on(port_a, 140, "s").start(), bridge_on(port_b, 141, "t").start()
    router = Router([port_a, port_b], listeners=2)
    autopilot = simulator_from_config({}, f"udpout:127.0.0.1:{router.ports[0]}").start()
    gcs = Peer(router.ports[1])
    try:
        yield first, second, gcs
    finally:
        gcs.close()
        autopilot.stop()
        router.close()
        second.stop()
        first.stop()


def test_two_bridges_behind_a_router_keep_to_their_own_servos_names_and_esc_numbers() -> None:
    with two_bridges() as (first, second, gcs):
        gcs.send(mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
        for bridge in (first, second):  # both follow the one simulated autopilot
            assert wait_until(lambda b=bridge: b.mavlink.stats()["mirror"].get("applied", 0) > 5)
        # the second bridge heard the first one's ESC 17-19 and moved above them
        assert wait_until(lambda: second.mavlink.core.telemetry.esc_first == 21)
        assert first.mavlink.core.telemetry.esc_first == 17
        mark = gcs.count()
        assert wait_until(
            lambda: (
                esc_from(gcs, 140, mark) == {"ESC_TELEMETRY_17_TO_20"}
                and esc_from(gcs, 141, mark) == {"ESC_TELEMETRY_21_TO_24"}
            )
        )

        def names() -> set[tuple[int, str]]:
            return {(m.get_srcComponent(), m.name) for m in gcs.since(mark, "NAMED_VALUE_FLOAT")}

        assert wait_until(lambda: {(140, "s1_pos"), (141, "t1_pos")} <= names())
        assert not {n for c, n in names() if c == 141 and n.startswith("s")}
        assert wait_until(lambda: {(141, "tbus0_load"), (140, "bus0_load")} <= names())

        before = first.mavlink.stats()["commands"].get("ignored_other_component", 0)
        result = gcs.command(MAV_CMD_DO_SET_SERVO, [1, 1700], target=(1, 141))
        assert result == MAV_RESULT_ACCEPTED
        assert second.mavlink.stats()["commands"]["result_accepted"] >= 1
        assert wait_until(
            lambda: first.mavlink.stats()["commands"].get("ignored_other_component", 0) > before
        )
        assert first.mavlink.stats()["commands"].get("result_accepted", 0) == 0
