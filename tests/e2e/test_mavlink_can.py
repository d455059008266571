"""Servos on the autopilot's own CAN port, end to end: the bridge's ``mavlink-can`` bus over a
real UDP MAVLink link to the simulated autopilot, whose CAN forward (ArduPilot's, as
:mod:`mavservo.sim.autopilot.can_forward` models it) sits on a python-can ``virtual`` channel
with simulated RMD-X servos. Every wait is bounded; no timing threshold is asserted.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from typing import Any

import can
import pytest

from mavservo.app.bridge import Bridge, free_udp_port
from mavservo.config import load_config_text
from mavservo.sim.autopilot.can_forward import CanForwardLink, SerialRoom
from mavservo.sim.autopilot.stream import AutopilotStream
from mavservo.sim.servo import SimServo
from mavservo.sim.virtual import VirtualServoBus
from tests.support.waiting import wait_until

pytestmark = pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")

BODY = """
can:
  buses: [{name: fc, interface: mavlink-can, channel: 1}]
servos:
  - {name: a, profile: rmd-x, can_id: 1, telemetry_hz: 10}
  - {name: b, profile: rmd-x, can_id: 2, telemetry_hz: 10}
channels:
  - {servo: a, source: servo_output, channel: 1, output_deg: [-90, 90]}
"""


@contextlib.contextmanager
def flight_controller(
    body: str, *, room: Any = None
) -> Iterator[tuple[Bridge, AutopilotStream, CanForwardLink, list[SimServo]]]:
    port = free_udp_port()
    config = load_config_text(f'mavlink: {{url: "udpin:127.0.0.1:{port}"}}\n{body}', "<fc>")
    channel = f"fc-can-{port}"
    servos = [SimServo("rmd-x", 1), SimServo("rmd-x", 2)]
    with contextlib.ExitStack() as stack:
        stack.enter_context(VirtualServoBus(servos, channel=channel).start())
        autopilot_can = can.Bus(interface="virtual", channel=channel)
        stack.callback(autopilot_can.shutdown)
        link = CanForwardLink(autopilot_can, clock=time.monotonic, room=room)
        autopilot = AutopilotStream(f"udpout:127.0.0.1:{port}", can_forward=link)
        bridge = Bridge(config, log_dir=False).start()
        stack.callback(bridge.stop)
        autopilot.start()
        stack.callback(autopilot.stop)
        yield bridge, autopilot, link, servos


def online(bridge: Bridge) -> dict[str, bool]:
    assert bridge.backend is not None
    return {s.name: s.online for s in bridge.backend.servo_statuses()}


def statuses(bridge: Bridge) -> list[Any]:
    assert bridge.backend is not None
    return list(bridge.backend.servo_statuses())


def events(bridge: Bridge) -> list[str]:
    return [text for _, text in bridge.events]


def test_servos_on_the_autopilots_can_port_follow_and_survive_its_restart() -> None:
    with flight_controller(BODY) as (bridge, autopilot, link, servos):
        assert wait_until(lambda: all(online(bridge).values()), 10.0), online(bridge)
        # SERVO_OUTPUT_RAW channel 1 (the autopilot's sweep) drives servo a through the tunnel
        assert wait_until(lambda: servos[0].commands > 10, 10.0)
        stats = bridge.bus_set.transport_stats("fc")
        assert stats["sent"] > 0 and stats["received"] > 0 and stats["outages"] == 0
        assert link.forwarder.counters["forwarded"] > 0

        autopilot.reboot(3.0)  # silent 3 s, then boots with no forward
        lost_said = "fc: the autopilot stopped forwarding CAN bus 1"
        assert wait_until(lambda: any(t.startswith(lost_said) for t in events(bridge)))
        assert wait_until(lambda: not any(online(bridge).values()), 10.0)
        # the operator hears it: STATUSTEXT from the bridge reaches the autopilot's link
        back_said = "fc: the autopilot's CAN port is back after"
        assert wait_until(lambda: back_said in " ".join(events(bridge)), 15.0), events(bridge)
        assert wait_until(lambda: all(online(bridge).values()), 10.0)
        commands = servos[0].commands
        assert wait_until(lambda: servos[0].commands > commands + 5, 10.0)
        stats = bridge.bus_set.transport_stats("fc")
        assert stats["disconnects"] == 1 and stats["reconnects"] == 1 and stats["outages"] == 1
        texts = [m.text for _, m in autopilot.received.messages("STATUSTEXT")]
        assert any(" offline" in t for t in texts), texts
        # the bus kind's words, wherever the event goes: STATUSTEXT (a first chunk holds the
        # start), the event list of the run log and the summary; never a USB adapter's
        for said in (lost_said, back_said):
            assert any(t.startswith(said[:50]) for t in texts), texts
        summary = bridge.stop()
    said = [t for t in summary["events"] if t.startswith("fc: ")]
    assert any(t.startswith(lost_said) for t in said), said
    assert any(t.startswith(back_said) for t in said), said
    assert not any("adapter" in t for t in said + texts), said + texts


def test_replies_the_autopilots_port_has_no_room_for_are_counted_lost_never_silent() -> None:
    """A 57,600-baud port carrying 2 x 200 Hz: ArduPilot drops forwarded frames silently
    (AP_MAVLinkCAN.cpp l. 315); the bridge counts every one it missed as a lost reply."""
    body = BODY + "scheduler: {command_period_s: 0.005, reply_timeout_s: 0.1}\n"
    room = SerialRoom(57_600, time.monotonic, buffer_bytes=256, background_bytes_s=2000)
    with flight_controller(body, room=room) as (bridge, _autopilot, link, _servos):
        assert wait_until(lambda: link.forwarder.counters["no_room"] >= 50, 15.0)
        dropped_before = link.forwarder.counters["no_room"]
        summary = bridge.stop()
        dropped_after = link.forwarder.counters["no_room"]
    lost = sum(s["frames"]["lost"] for s in summary["servos"].values())
    # nothing else loses a reply here: every lost one was dropped by the port; not every drop
    # is a lost one (a servo's next reply of the same kind answers what it still owes)
    assert 0 < lost <= dropped_after, (lost, dropped_before, dropped_after)
    assert summary["buses"]["fc"]["transport"]["received"] > lost
    assert summary["buses"]["fc"]["transport"]["outages"] == 0  # the forward itself lived


def test_the_built_in_simulation_has_a_flight_controller_can_port() -> None:
    """``mavlink.url: sim`` with a ``mavlink-can`` bus: the simulated autopilot forwards a CAN
    port with the bus's simulated servos, out of the box."""
    config = load_config_text("mavlink: {url: sim}\n" + BODY, "<sim>")
    bridge = Bridge(config, log_dir=False).start()
    try:
        port = bridge.sim_can_port
        assert port is not None
        assert wait_until(lambda: port.link.forwarder.counters["forwarded"] > 20, 10.0)
        assert wait_until(lambda: all(s.state is not None for s in statuses(bridge)), 10.0)
        assert all(online(bridge).values())
    finally:
        summary = bridge.stop()
    assert summary["buses"]["fc"]["transport"]["received"] > 0


def test_a_full_autopilot_buffer_is_counted_and_the_servos_offline_are_said() -> None:
    """The autopilot's CAN transmit slots stay full (a bus-off port): its 20-frame buffer fills
    and every further frame is lost (AP_MAVLinkCAN.cpp l. 112), counted there; the bridge sees
    the forward alive (ACKs) but no reply: each servo goes offline with a STATUSTEXT, never
    silently, and comes back when the port drains again."""
    with flight_controller(BODY) as (bridge, autopilot, link, _servos):
        forwarder = link.forwarder
        assert wait_until(lambda: forwarder.counters["forwarded"] > 20, 10.0)
        write = forwarder._write
        forwarder._write = lambda *frame: False  # the CAN port takes nothing
        assert wait_until(lambda: forwarder.counters["buffer_full"] > 20, 10.0)
        assert wait_until(lambda: not any(online(bridge).values()), 10.0)

        def said() -> list[str]:
            return [m.text for _, m in autopilot.received.messages("STATUSTEXT")]

        assert wait_until(lambda: sum(" offline" in t for t in said()) >= 2, 10.0), said()
        assert bridge.bus_set.transport_stats("fc")["outages"] == 0  # the forward itself lived
        forwarder._write = write
        assert wait_until(lambda: all(online(bridge).values()), 10.0)
        assert wait_until(lambda: all(s.state is not None for s in statuses(bridge)), 10.0)


def test_a_stranger_claiming_the_autopilot_feeds_the_tunnel_nothing() -> None:
    """Issue 40 on the tunnel: CAN_FRAMEs claiming the autopilot's ids from another address
    (unsigned link) would be servo replies the bridge believed; they are refused and counted,
    while the real autopilot's frames keep the servos online."""
    from mavservo.mavlink import open_connection

    with flight_controller(BODY) as (bridge, _autopilot, _link, _servos):
        assert wait_until(lambda: all(online(bridge).values()), 10.0), online(bridge)
        assert bridge.can_tunnel is not None
        port = int(bridge.config.mavlink.url.rsplit(":", 1)[1])
        spoofer = open_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1)
        try:
            reply = bytes([0x9C, 40, 0, 0, 0, 0, 0x10, 0x27])  # RMD-X 0x9C status of servo 1
            for _ in range(20):
                spoofer.mav.can_frame_send(1, 140, 0, 8, 0x241, reply)
            assert wait_until(
                lambda: bridge.can_tunnel.stats().get("claimed_elsewhere", 0) >= 20, 10.0
            ), bridge.can_tunnel.stats()
        finally:
            spoofer.close()
        assert all(online(bridge).values())
