"""Several bridges behind a router, as docs/multiple-bridges.md sets them up.

* ``mavservo check a.yaml b.yaml`` names each clash between two bridges' configs;
* the mavlink-router example of docs/multiple-bridges.md, read from the page, runs in a small Python
  router that behaves like mavlink-router where it matters here: a message addressed to a
  component goes only to the endpoints that component was seen on (broadcasts to all), and a
  TCP server is opened unless ``[General] TcpServerPort = 0``. Two bridges and a simulated
  autopilot run behind it: no TCP server is open, and when the second bridge asks the
  autopilot's port for a lower rate, the first asks again and gets its rate back.
"""

from __future__ import annotations

import configparser
import contextlib
import io
import re
import select
import socket
import threading
from pathlib import Path
from typing import Any

import pytest

from mavservo.app.bridge import Bridge
from mavservo.app.check import EXIT_INVALID, EXIT_OK, check_main
from mavservo.app.console import event_level
from mavservo.config import load_config_text
from mavservo.mavlink.connection import mavlink2
from mavservo.sim.autopilot.stream import AutopilotStream
from tests.support.paths import REPO
from tests.support.waiting import free_udp_port, wait_until

README = REPO / "docs" / "multiple-bridges.md"  # the router example users copy
#: mavlink-router's TCP server port when [General] does not set one
MAVLINK_ROUTER_DEFAULT_TCP_PORT = 5760


def bridge_yaml(
    port: int, component: int, prefix: str, channels: tuple[int, ...], **kw: Any
) -> str:
    rate = kw.get("rate_hz", 20)
    servos = "\n".join(f"  - {{name: s{c}, profile: rmd-x, can_id: {c}}}" for c in channels)
    mapped = "\n".join(f"  - {{source: servo_output, channel: {c}, servo: s{c}}}" for c in channels)
    return (
        f"mavlink:\n  url: udpin:127.0.0.1:{port}\n  servo_component_id: {component}\n"
        f"  link_budget_bytes_s: 500\n  telemetry: {{name_prefix: {prefix}}}\n"
        f"  request_streams: {{rate_hz: {rate}, min_rate_hz: 5}}\n"
        f"servos:\n{servos}\nchannels:\n{mapped}\n"
    )


# ------------------------------------------------------------------------ mavservo check


def test_check_names_each_clash_between_two_bridges(tmp_path: Path) -> None:
    a, b = tmp_path / "a.yaml", tmp_path / "b.yaml"
    a.write_text(bridge_yaml(14551, 140, "s", (1, 2)))
    b.write_text(bridge_yaml(14561, 140, "s", (2, 3)))  # same component, prefix; channel 2
    out, err = io.StringIO(), io.StringIO()
    assert check_main(["--one-vehicle", str(a), str(b)], out=out, err=err) == EXIT_INVALID
    text = err.getvalue()
    # unrelated files checked together: the same clashes, named as a warning
    warned = io.StringIO()
    assert check_main([str(a), str(b)], out=io.StringIO(), err=warned) == EXIT_OK
    named = warned.getvalue().replace("warning:", "error:").split("  (--one-vehicle")[0]
    assert named == text
    assert f"{a} and {b}: both use MAVLink component 140" in text
    assert "both name their values 's1_pos'" in text
    assert "servo output channel 2 is mapped on both" in text
    assert "channel 1 " not in text and "channel 3 " not in text  # only what both map

    b.write_text(bridge_yaml(14561, 141, "t", (3,)))
    out, err = io.StringIO(), io.StringIO()
    assert check_main(["--one-vehicle", str(a), str(b)], out=out, err=err) == EXIT_OK, (
        err.getvalue()
    )
    assert "no clash between the 2 configs" in out.getvalue()
    # each plans within its 500 B/s, and check adds them up for the radio both share
    total = re.search(r"together: 2 bridges put ([\d,]+) B/s", out.getvalue())
    each = re.findall(r"autopilot link: ([\d,]+) B/s of periodic", out.getvalue())
    assert total and len(each) == 2
    summed = sum(int(n.replace(",", "")) for n in each)  # each rounded on its own
    assert abs(int(total.group(1).replace(",", "")) - summed) <= len(each)
    assert all(0 < int(n.replace(",", "")) <= 500 for n in each)


# ------------------------------------------------------------------------ the router


def readme_router_config() -> configparser.ConfigParser:
    """The guide's mavlink-router main.conf, as a user would copy it."""
    text = README.read_text()
    match = re.search(r"```ini\n(# mavlink-router: [^\n]*\n.*?)```", text, re.S)
    assert match, "docs/multiple-bridges.md has no mavlink-router example"
    parser = configparser.ConfigParser(inline_comment_prefixes=("#",))
    parser.read_string(match.group(1))
    return parser


class TargetRouter:
    """A loopback MAVLink router that routes like mavlink-router: it learns on which endpoint
    each (system, component) is heard, sends a message with a target only there (broadcast:
    everywhere but its source), and opens a TCP server unless TcpServerPort is 0."""

    def __init__(self, conf: configparser.ConfigParser, ports: dict[str, int]) -> None:
        tcp_port = conf.getint("General", "TcpServerPort", fallback=MAVLINK_ROUTER_DEFAULT_TCP_PORT)
        self.tcp: socket.socket | None = None
        if tcp_port != 0:  # a test never binds 5760 for real: an ephemeral port stands in
            self.tcp = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            self.tcp.bind(("127.0.0.1", 0))
            self.tcp.listen()
        self.endpoints: dict[str, socket.socket] = {}
        self.peer: dict[str, tuple[str, int] | None] = {}
        self.listen_ports: dict[str, int] = {}
        for section in conf.sections():
            if section == "General":
                continue
            kind, name = section.split(maxsplit=1)
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.bind(("127.0.0.1", 0))
            self.endpoints[name] = sock
            if kind == "UdpEndpoint" and conf.get(section, "Mode") == "Normal":
                self.peer[name] = ("127.0.0.1", ports[name])  # it sends to a bridge's udpin
            else:  # the serial autopilot and a GCS server: learnt from their first datagram
                self.peer[name] = None
                self.listen_ports[name] = sock.getsockname()[1]
        self.seen: dict[tuple[int, int], str] = {}
        self.parser = {name: mavlink2.MAVLink(None) for name in self.endpoints}
        for parser in self.parser.values():
            parser.robust_parsing = True
        self.counts: dict[str, int] = {"targeted": 0, "broadcast": 0}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        by_socket = {sock: name for name, sock in self.endpoints.items()}
        while not self._stop.is_set():
            ready, _, _ = select.select(list(by_socket), [], [], 0.05)
            for sock in ready:
                with contextlib.suppress(OSError):
                    data, sender = sock.recvfrom(65536)
                    self._route(by_socket[sock], data, sender)

    def _route(self, source: str, data: bytes, sender: tuple[str, int]) -> None:
        if self.peer[source] is None or source in self.listen_ports:
            self.peer[source] = sender
        for msg in self.parser[source].parse_buffer(data) or []:
            if msg.get_type() == "BAD_DATA":
                continue
            self.seen[(msg.get_srcSystem(), msg.get_srcComponent())] = source
            target = (getattr(msg, "target_system", 0), getattr(msg, "target_component", 0))
            if target[0] != 0 and target[1] != 0 and target in self.seen:
                self.counts["targeted"] += 1
                destinations = [self.seen[target]] if self.seen[target] != source else []
            else:
                self.counts["broadcast"] += 1
                destinations = [name for name in self.endpoints if name != source]
            frame = bytes(msg.get_msgbuf())
            for name in destinations:
                address = self.peer[name]
                if address is not None:
                    with contextlib.suppress(OSError):
                        self.endpoints[name].sendto(frame, address)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        for sock in self.endpoints.values():
            sock.close()
        if self.tcp is not None:
            self.tcp.close()


@pytest.mark.timeout(90)
def test_the_readme_router_example_runs_two_bridges_with_no_tcp_server_and_rates_reasked() -> None:
    conf = readme_router_config()
    assert conf.getint("General", "TcpServerPort") == 0
    endpoints = {s.split(maxsplit=1)[1] for s in conf.sections() if s != "General"}
    assert {"autopilot", "bridge_a", "bridge_b", "gcs"} <= endpoints
    ports = {"bridge_a": free_udp_port(), "bridge_b": free_udp_port()}
    first = Bridge(
        load_config_text(bridge_yaml(ports["bridge_a"], 140, "s", (1, 2)), "<a>"), log_dir=False
    ).start()
    # the second bridge asks for a lower rate: what the README tells users not to do
    second_yaml = bridge_yaml(ports["bridge_b"], 141, "t", (3,), rate_hz=10)
    second = Bridge(load_config_text(second_yaml, "<b>"), log_dir=False)
    router = TargetRouter(conf, ports)
    autopilot = AutopilotStream(
        f"udpout:127.0.0.1:{router.listen_ports['autopilot']}", "hold", servo_output_rate_hz=1.0
    ).start()
    try:
        assert router.tcp is None  # the README's [General] section: no TCP server at all
        assert wait_until(lambda: autopilot.interval_s("SERVO_OUTPUT_RAW") == 0.05, 15.0)
        second.start()
        assert wait_until(lambda: autopilot.interval_s("SERVO_OUTPUT_RAW") == 0.1, 15.0)
        # the first bridge's accepted 20 Hz stays at 10: it asks again and gets it back
        assert wait_until(
            lambda: (
                first.mavlink.stats()["stream"]["streams"]["SERVO_OUTPUT_RAW"]["asked_again"] >= 1
            ),
            25.0,
        )
        assert wait_until(lambda: autopilot.interval_s("SERVO_OUTPUT_RAW") == 0.05, 10.0)
        # the router routed by target: the autopilot's ACKs went only to the bridge that asked
        assert router.counts["targeted"] > 0
        assert router.seen[(1, 140)] == "bridge_a" and router.seen[(1, 141)] == "bridge_b"
        # the second bridge moved above the first one's ESC 17-18: what it says follows
        assert wait_until(lambda: second.mavlink.core.telemetry.esc_first == 21, 10.0)
        assert wait_until(lambda: "servos as ESC 21-21" in (second.summary()["identity"] or ""))
        assert any("servos as ESC 21-21" in e for e in second.summary()["events"])
        assert event_level(second.summary()["identity"]) == "INFO"
    finally:
        autopilot.stop()
        router.close()
        second.stop()
        first.stop()
