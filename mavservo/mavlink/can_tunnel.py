"""The bridge's MAVLink link as a carrier of CAN frames to and from the autopilot's CAN port.

What the transport layer's ``mavlink-can`` bus needs of the MAVLink side (its ``FrameCarrier``
Protocol, matched structurally: the MAVLink side imports nothing of the transport) and nothing
more: CAN_FRAME / CANFD_FRAME and MAV_CMD_CAN_FORWARD out, the forwarded frames and that
command's COMMAND_ACK in.

Why its own part, created before the MAVLink side: the bridge opens its buses before the link
(the schedulers, the backend and then the MAVLink side are built on them), so the tunnel exists
first, the buses subscribe to it, and :class:`~mavservo.mavlink.side.MavlinkSide` attaches it to
its link when it is built (``attach``). Until then, and until the autopilot is heard, nothing
can go (``send_frame`` says False and the bus refuses the frame).

Wire facts (ArduPilot 90700977c5):

* Frames go to the autopilot only: addressed to its (system, component), never broadcast.
  ArduPilot's router processes a message addressed to itself locally and forwards it nowhere
  (libraries/GCS_MAVLink/MAVLink_routing.cpp l. 150-172: ``process_locally && !broadcast``
  returns before the forwarding loop), so CAN_FRAME never reaches the ground station's radio.
  Its forwarded frames are written straight to the channel of the requester
  (libraries/AP_CANManager/AP_MAVLinkCAN.cpp l. 298-318, ``mavlink_msg_can_frame_send(chan,
  ...)``), never routed either. So the tunnel bypasses the bridge's link budget (the radio's
  share) and the monitor outputs: its load is the serial link's, which ``check`` plans.
* The forwarded frames are addressed to whoever sent the last MAV_CMD_CAN_FORWARD (l. 62-66):
  the servo component. Only the autopilot's frames addressed to this bridge are taken; any
  other CAN_FRAME (another sender, another target) is counted in ``foreign`` and dropped.
* The 32-bit id carries AP_HAL::CANFrame's flag bits (l. 108: ``CANFrame(p.id, ...)``;
  libraries/AP_HAL/CANIface.h l. 32-34); ``len`` is the data length (l. 305-317).
"""

from __future__ import annotations

import threading
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Protocol

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.mavlink.origin import from_pinned

#: ``MAV_CMD_CAN_FORWARD`` (common.xml 32000): param1 = the bus to forward, 1-based, 0 = stop.
MAV_CMD_CAN_FORWARD = mavlink2.MAV_CMD_CAN_FORWARD
_FRAME_TYPES = ("CAN_FRAME", "CANFD_FRAME")
_DATA_LEN = {"CAN_FRAME": 8, "CANFD_FRAME": 64}
#: CAN_FILTER_MODIFY carries at most this many ids (common.xml: ``uint16_t[16] ids``).
_FILTER_IDS = 16


class _Sink(Protocol):
    """A subscribed bus (the transport's ``CarrierSink``)."""

    def on_frame(self, raw_id: int, data: bytes, fd: bool, t: float) -> None: ...

    def on_forward_ack(self, accepted: bool, result: int, t: float) -> None: ...


class CanTunnel:
    """CAN frames over the bridge's MAVLink link (see the module docstring).

    ``attach(send, autopilot, own)`` is called by the MAVLink side: ``send(msg)`` writes a
    message from the servo component on the link (False: the link is not open, nothing went),
    ``autopilot()`` is the followed autopilot's (system, component) once heard (None before),
    ``own()`` the servo component's address.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._sinks: dict[int, _Sink] = {}
        self._send: Callable[[Any], bool] | None = None
        self._autopilot: Callable[[], tuple[int, int] | None] = lambda: None
        self._own: Callable[[], tuple[int, int]] = lambda: (0, 0)
        self.counters: Counter[str] = Counter()

    def attach(
        self,
        send: Callable[[Any], bool],
        autopilot: Callable[[], tuple[int, int] | None],
        own: Callable[[], tuple[int, int]],
    ) -> None:
        self._send, self._autopilot, self._own = send, autopilot, own

    # ------------------------------------------------------------------ the buses' side

    def subscribe(self, bus_index: int, sink: _Sink) -> None:
        with self._lock:
            self._sinks[bus_index] = sink

    def unsubscribe(self, bus_index: int, sink: _Sink) -> None:
        with self._lock:
            if self._sinks.get(bus_index) is sink:
                del self._sinks[bus_index]

    def send_frame(self, bus_index: int, raw_id: int, data: bytes, fd: bool) -> bool:
        target = self._autopilot()
        send = self._send
        if target is None or send is None:
            return False
        size = 64 if fd else 8
        payload = list(data) + [0] * (size - len(data))
        make = mavlink2.MAVLink_canfd_frame_message if fd else mavlink2.MAVLink_can_frame_message
        if not send(make(target[0], target[1], bus_index, len(data), raw_id, payload)):
            return False
        self.counters["frames_sent"] += 1
        return True

    def request_forward(self, bus_number: int) -> bool:
        target = self._autopilot()
        send = self._send
        if target is None or send is None:
            return False
        request = mavlink2.MAVLink_command_long_message(
            target[0], target[1], MAV_CMD_CAN_FORWARD, 0, float(bus_number), 0, 0, 0, 0, 0, 0
        )
        if not send(request):
            return False
        self.counters["forward_requests"] += 1
        return True

    def set_filter(self, bus_number: int, ids: list[int]) -> bool:
        """CAN_FILTER_MODIFY, replace: forward only frames whose DroneCAN-shaped key is in
        ``ids`` (AP_MAVLinkCAN.cpp l. 167-251; ``bus`` 1-based there, l. 171; at most 16 ids,
        l. 175). Replacing with the same list changes nothing (l. 194-198), so it is re-sent
        with every keep-alive and survives an autopilot restart."""
        target = self._autopilot()
        send = self._send
        if target is None or send is None or len(ids) > _FILTER_IDS:
            return False
        padded = list(ids) + [0] * (_FILTER_IDS - len(ids))
        replace = mavlink2.MAVLink_can_filter_modify_message(
            target[0], target[1], bus_number, mavlink2.CAN_FILTER_REPLACE, len(ids), padded
        )
        if not send(replace):
            return False
        self.counters["filter_requests"] += 1
        return True

    # ------------------------------------------------------------------ the link's side

    def take(self, msg: Any, now: float) -> bool:
        """True when ``msg`` is the tunnel's (consumed here, the core never sees it): a
        CAN_FRAME / CANFD_FRAME from anyone, the COMMAND_ACK of MAV_CMD_CAN_FORWARD."""
        kind = msg.get_type()
        if kind in _FRAME_TYPES:
            self._frame(msg, kind, now)
            return True
        if kind == "COMMAND_ACK" and msg.command == MAV_CMD_CAN_FORWARD:
            if not self._for_us(msg):
                self.counters["foreign"] += 1
                return True
            with self._lock:
                sinks = list(self._sinks.values())
            accepted = msg.result == mavlink2.MAV_RESULT_ACCEPTED
            for sink in sinks:
                sink.on_forward_ack(accepted, int(msg.result), now)
            return True
        return False

    def _frame(self, msg: Any, kind: str, now: float) -> None:
        if not self._for_us(msg):
            self.counters["foreign"] += 1
            return
        length = int(msg.len)
        if length > _DATA_LEN[kind]:
            self.counters["malformed"] += 1
            return
        with self._lock:
            sink = self._sinks.get(int(msg.bus))
        if sink is None:
            self.counters["unsubscribed"] += 1  # a bus no mavlink-can bus is open on
            return
        self.counters["frames_received"] += 1
        sink.on_frame(int(msg.id), bytes(msg.data[:length]), kind == "CANFD_FRAME", now)

    def _for_us(self, msg: Any) -> bool:
        """From the followed autopilot, from the address its identity is pinned to (or signed),
        and addressed to the servo component. Why the address (issue 40): on an unsigned link
        a stranger claiming the autopilot's ids from elsewhere is refused by the core, but the
        tunnel takes its frames before the core sees them: its CAN_FRAMEs would have been
        servo replies (a position, a fault) the bridge believed. Counted as
        ``claimed_elsewhere``."""
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        if source != self._autopilot() or (msg.target_system, msg.target_component) != (
            self._own()
        ):
            return False
        if from_pinned(msg) or getattr(msg, "_signed", False):
            return True
        self.counters["claimed_elsewhere"] += 1
        return False

    def stats(self) -> dict[str, int]:
        return dict(self.counters)


#: Bytes a MAVLink 2 signature adds to a frame (link id 1, timestamp 6, signature 6).
SIGNATURE_BYTES = 13


@dataclass(frozen=True)
class TunnelWireBytes:
    """The largest size on the wire of each message the tunnel sends or gets, in bytes."""

    frame: int
    """CAN_FRAME with 8 data bytes (MAVLink 2 trims trailing zero bytes: never more)."""
    fd_frame: int
    """CANFD_FRAME with 64 data bytes."""
    request: int
    """COMMAND_LONG MAV_CMD_CAN_FORWARD (the keep-alive)."""
    ack: int
    """Its COMMAND_ACK."""


@lru_cache(maxsize=2)
def tunnel_wire_bytes(signed: bool = False) -> TunnelWireBytes:
    """Measured by packing each message with pymavlink's own encoder (header, payload after
    MAVLink 2's zero trimming, CRC), plus the signature on a signed link."""
    encoder = mavlink2.MAVLink(None, srcSystem=255, srcComponent=255)
    full = [0xFF] * 64
    sizes = [
        len(message.pack(encoder))
        for message in (
            mavlink2.MAVLink_can_frame_message(255, 255, 255, 8, 0xFFFFFFFF, full[:8]),
            mavlink2.MAVLink_canfd_frame_message(255, 255, 255, 64, 0xFFFFFFFF, full),
            mavlink2.MAVLink_command_long_message(
                255, 255, MAV_CMD_CAN_FORWARD, 0, 3.0, 0, 0, 0, 0, 0, 0
            ),
            mavlink2.MAVLink_command_ack_message(MAV_CMD_CAN_FORWARD, 0, 0, 0, 255, 255),
        )
    ]
    extra = SIGNATURE_BYTES if signed else 0
    frame, fd_frame, request, ack = (size + extra for size in sizes)
    return TunnelWireBytes(frame, fd_frame, request, ack)
