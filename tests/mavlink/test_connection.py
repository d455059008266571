"""One pymavlink opener, and no process-wide side effects (issue 16, item 5).

pymavlink keeps the wire version in ``os.environ["MAVLINK20"]`` and the dialect in module globals
of ``mavutil``; the bridge, the monitor and the simulated autopilot share one process in tests
(and an integrator's process in production), so none of them may change either. Each test
starts from a state none of the openers would choose (no ``MAVLINK20``, the ``common`` dialect)
so a change is visible. Real UDP connections on 127.0.0.1.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Iterator
from typing import Any

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as v20_common

from mavservo.app import monitor
from mavservo.mavlink import connection
from mavservo.mavlink.connection import mavlink2, open_connection
from mavservo.mavlink.link import MavlinkLink
from tests.support.waiting import free_udp_port

RECV_ATTEMPTS = 200
RECV_WAIT_S = 0.05


@pytest.fixture
def foreign_pymavlink_state(monkeypatch: pytest.MonkeyPatch) -> Iterator[dict[str, object]]:
    """pymavlink as another part of the process left it; yields the snapshot to compare with."""
    monkeypatch.delenv("MAVLINK20", raising=False)
    monkeypatch.setattr(mavutil, "mavlink", v20_common)
    monkeypatch.setattr(mavutil, "current_dialect", "common")
    yield {"environ": environ(), "mavlink": v20_common, "dialect": "common"}


def environ() -> dict[str, str]:
    """The environment, without the variable pytest itself rewrites per phase."""
    return {k: v for k, v in os.environ.items() if k != "PYTEST_CURRENT_TEST"}


def assert_untouched(snapshot: dict[str, object]) -> None:
    assert environ() == snapshot["environ"]
    assert mavutil.mavlink is snapshot["mavlink"]
    assert mavutil.current_dialect == snapshot["dialect"]


def receive(conn: Any, kind: str) -> Any:
    for _ in range(RECV_ATTEMPTS):
        msg = conn.recv_match(type=kind, blocking=True, timeout=RECV_WAIT_S)
        if msg is not None:
            return msg
    raise AssertionError(f"no {kind} within {RECV_ATTEMPTS} attempts")


def test_a_mavlink2_exchange_leaves_the_process_state_alone(
    foreign_pymavlink_state: dict[str, object],
) -> None:
    """MAVLink 2 both ways (servo16 needs the v2 extension fields), and the first v2 byte does
    not make pymavlink switch the whole process over."""
    port = free_udp_port()
    server = open_connection(f"udpin:127.0.0.1:{port}", source_system=1, source_component=1)
    client = open_connection(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190)
    try:
        client.mav.servo_output_raw_send(0, 0, *([1500] * 8), *([1000] * 7), 1999)
        msg = receive(server, "SERVO_OUTPUT_RAW")
        assert msg.servo16_raw == 1999
        assert msg.get_srcComponent() == 190
        assert isinstance(server.mav, mavlink2.MAVLink)
    finally:
        server.close()
        client.close()
    assert_untouched(foreign_pymavlink_state)


def test_dialect_cannot_be_passed_to_the_opener() -> None:
    with pytest.raises(TypeError, match="dialect"):
        open_connection("udpout:127.0.0.1:9", dialect="common")


def test_the_bridge_link_and_its_monitor_output_open_without_side_effects(
    foreign_pymavlink_state: dict[str, object],
) -> None:
    link = MavlinkLink(
        f"udpout:127.0.0.1:{free_udp_port()}",
        lambda msg, now: None,
        monitor_outputs=[f"udpout:127.0.0.1:{free_udp_port()}"],
    )
    link.start()
    link.stop()
    assert_untouched(foreign_pymavlink_state)


def test_the_monitor_opens_without_side_effects(
    foreign_pymavlink_state: dict[str, object], capsys: pytest.CaptureFixture[str]
) -> None:
    url = f"udpin:127.0.0.1:{free_udp_port()}"
    assert monitor.main([url, "--duration", "0", "--plain", "--no-heartbeat"]) == 0
    capsys.readouterr()
    assert_untouched(foreign_pymavlink_state)


def _refusing_tcp_port() -> int:
    """A 127.0.0.1 port nobody listens on (bound for its number, then closed)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def test_a_refused_tcp_connect_prints_nothing_and_raises_once(
    capfd: pytest.CaptureFixture[str],
) -> None:
    """pymavlink's mavtcp printed "[Errno 111] Connection refused sleeping" to stdout for every
    refused attempt before the bridge's own error (issue 37): now the error is raised, once,
    and nothing is printed."""
    with pytest.raises(ConnectionRefusedError):
        open_connection(f"tcp:127.0.0.1:{_refusing_tcp_port()}", reconnect_delay=0.01)
    out, err = capfd.readouterr()
    assert "sleeping" not in out + err and "refused" not in out + err


def test_a_refused_tcp_connect_is_still_retried_like_pymavlink_does(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The attempts are still made (a peer that is starting gets pymavlink's time), silently."""
    pauses: list[float] = []
    monkeypatch.setattr(connection.time, "sleep", pauses.append)
    with pytest.raises(ConnectionRefusedError):
        open_connection(f"tcp:127.0.0.1:{_refusing_tcp_port()}")
    assert pauses == [connection.TCP_RECONNECT_DELAY_S] * (connection.TCP_CONNECT_ATTEMPTS - 1)


def test_a_tcp_client_still_connects_to_a_listening_peer() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as server:
        server.bind(("127.0.0.1", 0))
        server.listen(1)
        port = server.getsockname()[1]
        client = open_connection(f"tcp:127.0.0.1:{port}", source_system=255, source_component=190)
        peer, _ = server.accept()
        with peer:
            client.mav.heartbeat_send(6, 8, 0, 0, 0)
            peer.settimeout(5.0)
            assert peer.recv(1) == b"\xfd"  # a MAVLink 2 frame's start byte
        client.close()
