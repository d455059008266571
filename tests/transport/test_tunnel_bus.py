"""The ``mavlink-can`` bus against the simulated autopilot's CAN forward, on a fake clock.

Real parts: the bridge's :class:`CanTunnel`, the bus, ArduPilot's forward as the simulator
models it (:mod:`mavservo.sim.autopilot.can_forward`) on a python-can ``virtual`` channel, and
every MAVLink message packed and parsed by pymavlink; only the clock is a counter, so a minute
of keep-alive costs a second of CPU.
"""

from __future__ import annotations

import itertools
from typing import Any

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mav

from mavservo.mavlink.can_tunnel import CanTunnel
from mavservo.sim.autopilot.can_forward import CanForwardLink
from mavservo.transport.resilient_bus import ResilientBus
from mavservo.transport.tunnel_bus import TunnelledCanBus, tunnel_factory

_channels = itertools.count()
AUTOPILOT = (1, 1)
BRIDGE = (1, 140)


class FakeClock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


class Wire:
    """The bridge's tunnel and the simulated autopilot, joined by pymavlink bytes."""

    def __init__(self, clock: FakeClock, configured: tuple[int, ...] = (0,)) -> None:
        self.clock = clock
        self.channel = f"tunnel-test-{next(_channels)}"
        self.autopilot_can = can.Bus(interface="virtual", channel=self.channel)
        self.node = can.Bus(interface="virtual", channel=self.channel)  # another node on it
        self.link = CanForwardLink(self.autopilot_can, own=AUTOPILOT, clock=clock)
        self.link.forwarder.configured = frozenset(configured)
        self.tunnel = CanTunnel()
        self.alive = True  # False: the autopilot is silent (rebooting)
        self._bridge_out = mav.MAVLink(None, srcSystem=BRIDGE[0], srcComponent=BRIDGE[1])
        self._autopilot_out = mav.MAVLink(None, srcSystem=AUTOPILOT[0], srcComponent=AUTOPILOT[1])
        self._autopilot_in = mav.MAVLink(None)
        self._bridge_in = mav.MAVLink(None)
        self.tunnel.attach(send=self._to_autopilot, autopilot=lambda: AUTOPILOT, own=lambda: BRIDGE)
        self.link.send = self._to_bridge
        self.sent_by_bridge: list[str] = []

    def _to_autopilot(self, msg: Any) -> bool:
        self.sent_by_bridge.append(msg.get_type())
        for parsed in self._autopilot_in.parse_buffer(msg.pack(self._bridge_out)) or []:
            if self.alive:
                self.link.take(parsed)
        return True

    def _to_bridge(self, msg: Any) -> None:
        for parsed in self._bridge_in.parse_buffer(msg.pack(self._autopilot_out)) or []:
            assert self.tunnel.take(parsed, self.clock())

    def inject(self, msg: Any) -> None:
        """A message from the autopilot's side of the link, as is (a hostile sender's too)."""
        for parsed in self._bridge_in.parse_buffer(msg.pack(self._autopilot_out)) or []:
            self.tunnel.take(parsed, self.clock())

    def close(self) -> None:
        self.autopilot_can.shutdown()
        self.node.shutdown()


@pytest.fixture
def clock() -> FakeClock:
    return FakeClock()


@pytest.fixture
def wire(clock: FakeClock):
    made = Wire(clock)
    yield made
    made.close()


def open_bus(wire: Wire, **kwargs: Any) -> TunnelledCanBus:
    return TunnelledCanBus(1, carrier=wire.tunnel, clock=wire.clock, **kwargs)


def drain(bus: can.BusABC) -> list[can.Message]:
    out = []
    for _ in range(10_000):
        msg = bus.recv(timeout=0)
        if msg is None:
            return out
        out.append(msg)
    raise AssertionError("queue never drained")


NODE_STATUS = can.Message(arbitration_id=0x1015501, is_extended_id=True, data=bytes(7))
SERVO_REPLY = can.Message(arbitration_id=0x241, is_extended_id=False, data=bytes(range(8)))


def run(wire: Wire, bus: can.BusABC, seconds: float, frame_every: int = 3) -> int:
    """``seconds`` of fake time in 10 ms steps, the node sending a frame every ``frame_every``
    steps (~33/s, like the autopilot's DroneCAN); returns the frames the bus received."""
    got = 0
    for step in range(round(seconds / 0.01)):
        wire.clock.now += 0.01
        if step % frame_every == 0:
            wire.node.send(SERVO_REPLY)
        wire.link.pump(silent=not wire.alive)
        got += len(drain(bus))
    return got


def test_keep_alive_holds_the_forward_for_60_s(wire: Wire) -> None:
    bus = open_bus(wire)
    got = run(wire, bus, 60.0)
    sent = 2000  # one frame every 3 of 6,000 steps
    assert got == sent  # every frame forwarded, none lost to an expired forward
    assert wire.link.forwarder.counters["forward_expired"] == 0
    assert bus.forwarding and bus.stats()["outages"] == 0
    # re-sent well inside ArduPilot's 5 s: every 0.5 s
    assert 115 <= wire.sent_by_bridge.count("COMMAND_LONG") <= 125
    bus.shutdown()


def test_without_keep_alive_the_forward_stops_and_the_bus_says_so(wire: Wire) -> None:
    """The control: asked once, ArduPilot forwards for 5 s (plus up to 100 frames), then
    stops; the bus does not go on as if the servos were merely silent: it raises."""
    bus = open_bus(wire, keepalive_s=1e9)
    got = 0
    with pytest.raises(can.CanOperationError, match="stopped forwarding CAN bus 1"):
        got = run(wire, bus, 20.0)
    assert wire.link.forwarder.counters["forward_expired"] == 1
    assert bus.stats()["outages"] == 1
    assert not bus.forwarding
    bus.shutdown()
    assert got == 0  # raised before returning


def test_an_autopilot_restart_is_asked_again(wire: Wire) -> None:
    bus = open_bus(wire)
    assert run(wire, bus, 10.0) > 0
    wire.link.reboot()  # the forward is forgotten, nothing else changes
    after = run(wire, bus, 10.0)
    assert after >= 300  # forwarding again within one keep-alive
    assert wire.link.forwarder.counters["forward_requests"] >= 38
    assert bus.forwarding
    bus.shutdown()


def test_a_silent_autopilot_is_an_outage_and_a_reopen_waits_for_its_answer(wire: Wire) -> None:
    factory = tunnel_factory({"channel": 1, "clock": wire.clock}, wire.tunnel)
    first = factory()
    run(wire, first, 1.0)
    wire.alive = False
    with pytest.raises(can.CanOperationError, match="nothing heard for"):
        run(wire, first, 3.0)
    first.shutdown()
    with pytest.raises(can.CanInitializationError, match="no answer to MAV_CMD_CAN_FORWARD"):
        factory()  # the confirm wait is bounded by the real clock (0.3 s), the fake one stands
    wire.alive = True
    wire.link.reboot()
    again = factory()  # answered at once (the ACK comes back synchronously here)
    assert again.forwarding
    assert run(wire, again, 2.0) > 0
    again.shutdown()


def test_a_bus_the_autopilot_has_not_configured_is_refused_with_the_parameter(
    clock: FakeClock,
) -> None:
    wire = Wire(clock, configured=(1,))  # CAN2 only
    try:
        bus = open_bus(wire)
        with pytest.raises(can.CanOperationError, match="CAN_P1_DRIVER"):
            bus.recv(timeout=0)
        assert bus.stats()["forward_refused"] == 1
        bus.shutdown()
    finally:
        wire.close()


def test_the_autopilots_dronecan_traffic_is_counted_and_dropped(wire: Wire) -> None:
    bus = open_bus(wire)
    wire.node.send(NODE_STATUS)
    wire.node.send(SERVO_REPLY)
    wire.link.pump()
    got = drain(bus)
    assert [m.arbitration_id for m in got] == [0x241]
    assert got[0].data == SERVO_REPLY.data and not got[0].is_extended_id
    assert bus.stats()["ignored"] == 1
    bus.shutdown()
    kept = open_bus(wire, keep_extended=True)  # a DroneCAN node on the bus: kept
    wire.node.send(NODE_STATUS)
    wire.link.pump()
    (status,) = drain(kept)
    assert status.is_extended_id and status.arbitration_id == 0x1015501
    kept.shutdown()


def test_frames_reach_the_autopilots_bus_with_their_ids(wire: Wire) -> None:
    bus = open_bus(wire)
    bus.send(can.Message(arbitration_id=0x141, is_extended_id=False, data=b"\xa4\x00"))
    bus.send(can.Message(arbitration_id=0x12345, is_extended_id=True, data=b""))
    first, second = wire.node.recv(0), wire.node.recv(0)
    assert (first.arbitration_id, first.is_extended_id, bytes(first.data)) == (
        0x141,
        False,
        b"\xa4\x00",
    )
    assert (second.arbitration_id, second.is_extended_id, second.dlc) == (0x12345, True, 0)
    assert bus.stats()["sent"] == 2
    with pytest.raises(can.CanError):
        bus.send(can.Message(arbitration_id=1, data=bytes(8), is_error_frame=True))
    assert bus.stats()["refused"] == 1
    bus.shutdown()


def test_a_full_receive_queue_drops_and_counts(wire: Wire) -> None:
    bus = open_bus(wire, rx_queue_frames=5)
    for _ in range(8):
        wire.node.send(SERVO_REPLY)
    wire.link.pump()
    assert len(drain(bus)) == 5
    assert bus.stats()["dropped"] == 3 and bus.stats()["received"] == 5
    bus.shutdown()


def test_before_the_autopilot_is_heard_a_frame_is_refused_not_lost(clock: FakeClock) -> None:
    tunnel = CanTunnel()  # not attached: no link, no autopilot
    bus = TunnelledCanBus(1, carrier=tunnel, clock=clock, startup_grace_s=5.0)
    with pytest.raises(can.CanTimeoutError, match="not heard yet"):
        bus.send(SERVO_REPLY)
    assert bus.stats()["refused"] == 1 and bus.stats().get("sent", 0) == 0
    bus.shutdown()


def test_frames_from_strangers_or_for_others_are_not_taken(wire: Wire) -> None:
    bus = open_bus(wire)
    data = list(range(8))
    spoofed = mav.MAVLink_can_frame_message(*BRIDGE, 0, 8, 0x241, data)
    other_target = mav.MAVLink_can_frame_message(1, 141, 0, 8, 0x241, data)
    too_long = mav.MAVLink_can_frame_message(*BRIDGE, 0, 9, 0x241, data)
    stranger = mav.MAVLink(None, srcSystem=7, srcComponent=1)
    for parsed in mav.MAVLink(None).parse_buffer(spoofed.pack(stranger)) or []:
        assert wire.tunnel.take(parsed, wire.clock())
    wire.inject(other_target)
    wire.inject(too_long)
    assert drain(bus) == []
    assert wire.tunnel.counters["foreign"] == 2 and wire.tunnel.counters["malformed"] == 1
    bus.shutdown()


def test_channel_must_be_a_bus_number() -> None:
    tunnel = CanTunnel()
    for channel in (0, 4, "can0", None, True):
        with pytest.raises(can.CanInitializationError, match="CAN bus number"):
            TunnelledCanBus(channel, carrier=tunnel)
    with pytest.raises(can.CanInitializationError, match="bridge's MAVLink link"):
        TunnelledCanBus(1)


def test_an_autopilot_without_can_forwarding_is_said_so(clock: FakeClock) -> None:
    """PX4 answers MAV_CMD_CAN_FORWARD UNSUPPORTED (its commander's default case)."""
    wire = Wire(clock)
    try:
        bus = open_bus(wire)
        unsupported = mav.MAVLink_command_ack_message(
            mav.MAV_CMD_CAN_FORWARD, mav.MAV_RESULT_UNSUPPORTED, 0, 0, *BRIDGE
        )
        wire.inject(unsupported)
        with pytest.raises(can.CanOperationError, match="does not support CAN forwarding"):
            bus.recv(timeout=0)
        bus.shutdown()
    finally:
        wire.close()


def test_the_autopilot_is_told_to_forward_only_the_servos_replies(wire: Wire) -> None:
    """CAN_FILTER_MODIFY with the keys of the servos' 11-bit reply ids (RMD-X 0x241: key 2):
    the autopilot keeps its own DroneCAN traffic off the link."""
    bus = open_bus(wire, forward_filter_ids=[2])
    assert wire.sent_by_bridge == ["COMMAND_LONG", "CAN_FILTER_MODIFY"]
    wire.node.send(NODE_STATUS)
    wire.node.send(SERVO_REPLY)
    wire.link.pump()
    assert [m.arbitration_id for m in drain(bus)] == [0x241]
    assert wire.link.forwarder.counters["filtered"] == 1 and bus.stats()["ignored"] == 0
    bus.shutdown()
    unfiltered = open_bus(wire, forward_filter_ids=[2], filter_at_autopilot=False)
    assert wire.sent_by_bridge[-1] == "COMMAND_LONG"
    unfiltered.shutdown()


@settings(max_examples=60, deadline=None)
@given(
    extended=st.booleans(),
    can_id=st.integers(0, 0x1FFFFFFF),
    data=st.binary(max_size=8),
    remote=st.booleans(),
)
def test_any_frame_crosses_the_tunnel_both_ways_unchanged(
    extended: bool, can_id: int, data: bytes, remote: bool
) -> None:
    """Through pymavlink's CAN_FRAME and the AP_HAL flag bits, and back."""
    msg = can.Message(
        arbitration_id=can_id & (0x1FFFFFFF if extended else 0x7FF),
        is_extended_id=extended,
        is_remote_frame=remote,
        data=b"" if remote else data,
    )
    wire = Wire(FakeClock())
    try:
        bus = open_bus(wire, keep_extended=True)
        bus.send(msg)
        out = wire.node.recv(0)
        wire.node.send(msg)
        wire.link.pump()
        (back,) = drain(bus)
        bus.shutdown()
    finally:
        wire.close()
    for got in (out, back):
        assert got is not None
        assert (got.arbitration_id, got.is_extended_id, got.is_remote_frame, bytes(got.data)) == (
            msg.arbitration_id,
            msg.is_extended_id,
            msg.is_remote_frame,
            bytes(msg.data),
        )


def test_the_port_lost_and_back_say_what_happened_not_an_adapters_words(wire: Wire) -> None:
    """The events (console, STATUSTEXT, run log, summary: one text) of a ``mavlink-can`` bus
    are the bus kind's: the autopilot stopped forwarding, its CAN port is back; a USB adapter
    keeps its own (python-can's ``virtual`` bus stands for a device here)."""
    events: list[str] = []
    factory = tunnel_factory({"channel": 1, "clock": wire.clock}, wire.tunnel)
    bus = ResilientBus(factory, name="fc", on_event=events.append, clock=wire.clock)
    try:
        run(wire, bus, 1.0)
        wire.alive = False
        run(wire, bus, 3.0)
        wire.alive = True
        wire.link.reboot()
        run(wire, bus, 2.0)
    finally:
        bus.shutdown()
    assert len(events) == 2, events
    lost, back = events
    assert lost.startswith("fc: the autopilot stopped forwarding CAN bus 1: nothing heard for ")
    assert lost.endswith("; asking the autopilot again")
    assert back.startswith("fc: the autopilot's CAN port is back after ")
    assert back.endswith(" s (forwarding CAN bus 1 again)")
    assert not any("adapter" in text or "device" in text for text in events)

    said: list[str] = []
    device = ResilientBus(
        lambda: can.Bus(interface="virtual", channel="words"), name="usb", on_event=said.append
    )
    assert device.inner is not None
    device.inner.shutdown()  # the device goes away: python-can raises on the closed bus
    device.recv(timeout=0)
    device.shutdown()
    assert said == ["usb: CAN adapter lost (Cannot operate on a closed bus); reconnecting"]
