"""A simulated autopilot's CAN forwarding, as ArduPilot does it: MAV_CMD_CAN_FORWARD, CAN_FRAME.

Written from ArduPilot 90700977c5, libraries/AP_CANManager/AP_MAVLinkCAN.cpp (cited by line
below), so CI tests the ``mavlink-can`` transport without an ArduPilot build:

* MAV_CMD_CAN_FORWARD's param1 is the bus 1-based, 0 stops (l. 30-41); a bus the board has not
  configured (``CAN_Px_DRIVER`` 0) is refused, MAV_RESULT_FAILED (l. 43-45; GCS_Common.cpp
  l. 4199); asking for another bus moves the forward (l. 47-53); the requester's address and
  the time are kept (l. 62-66). One client, one bus.
* A CAN_FRAME's ``bus`` is 0-based (l. 103); the frame goes into a 20-frame buffer (l. 79),
  which is emptied onto the bus as far as the bus takes frames (l. 141-162); a frame pushed
  into the full buffer is lost (l. 112: ``push`` fails, nothing said), counted here.
* Every frame the bus carries reaches the forward callback (its own sends included,
  AP_HAL/CANIface.cpp l. 80-104); at ``frame_counter++ == 100`` (the 101st frame, then every
  101st) the callback stops forwarding if no request came for 5 s (l. 268-279; the counter is a
  uint8_t, AP_MAVLinkCAN.h l. 56, left at 101 when the forward stops, so after a new request the
  next check comes 255 frames later); a CAN_FILTER_MODIFY list keeps only frames whose
  DroneCAN-shaped id is in it (l. 280-296); a frame the port has no room for is dropped
  silently (l. 315).

:class:`CanForwarder` is that state machine, pure (times in milliseconds handed in, the CAN bus
and the port's room behind callables). :class:`CanForwardLink` puts it between a python-can bus
(the simulated servos' ``virtual`` channel, or SITL's multicast) and the simulated autopilot's
MAVLink link; :class:`SerialRoom` models the port's transmit buffer draining at a baud rate.
"""

from __future__ import annotations

import bisect
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import can

from mavservo.mavlink import mavlink2 as mav

#: ArduPilot's frame buffer (l. 79: "20 is good for firmware upload").
BUFFER_FRAMES = 20
#: The forward stops this long after the last request (l. 273) ...
FORWARD_TIMEOUT_MS = 5000
#: ... checked when the frame counter reaches this (l. 268).
CHECK_EVERY_FRAMES = 100
FLAG_EFF = 1 << 31
FLAG_RTR = 1 << 30
FLAG_ERR = 1 << 29
#: CAN_FILTER_MODIFY operations (common.xml CAN_FILTER_OP).
CAN_FILTER_REPLACE, CAN_FILTER_ADD, CAN_FILTER_REMOVE = 0, 1, 2


@dataclass(frozen=True)
class Forwarded:
    """A CAN_FRAME (CANFD_FRAME) the autopilot sends to the forward's requester."""

    target: tuple[int, int]
    bus: int
    raw_id: int
    data: bytes
    fd: bool


class CanForwarder:
    """AP_MAVLinkCAN's state (see the module docstring).

    ``configured``: the 0-based buses the board has (``hal.can[bus] != nullptr``); ``write(bus,
    raw_id, data, fd)`` puts a frame on a bus, False when its transmit slots are full (the frame
    stays buffered); ``room(nbytes)`` says whether the requester's port has room for a message.
    """

    def __init__(
        self,
        configured: tuple[int, ...] = (0,),
        *,
        write: Callable[[int, int, bytes, bool], bool],
        room: Callable[[int], bool] = lambda nbytes: True,
        frame_bytes: int = 28,
    ) -> None:
        self.configured = frozenset(configured)
        self._write = write
        self._room = room
        self._frame_bytes = frame_bytes
        self.callback_bus: int | None = None
        """The bus whose frames are forwarded (None: no callback registered)."""
        self.frame_counter = 0
        self.last_enable_ms = 0
        self.requester = (0, 0)
        self.filter_ids: list[int] | None = None
        self.buffer: deque[tuple[int, int, bytes, bool]] = deque()
        self.counters: Counter[str] = Counter()

    @property
    def forwarding(self) -> bool:
        return self.callback_bus is not None

    # ------------------------------------------------------------------ MAVLink in

    def handle_can_forward(self, param1: float, requester: tuple[int, int], now_ms: int) -> bool:
        """MAV_CMD_CAN_FORWARD; True: MAV_RESULT_ACCEPTED, False: FAILED (l. 27-69)."""
        bus = _int8(int(param1)) - 1
        if bus == -1:
            self.callback_bus = None  # a request to stop forwarding
            return True
        if bus < 0 or bus not in self.configured:
            return False
        self.callback_bus = bus  # another bus: the forward moves (l. 47-53)
        self.last_enable_ms = now_ms
        self.requester = requester
        self.counters["forward_requests"] += 1
        return True

    def handle_can_frame(self, bus: int, length: int, raw_id: int, data: bytes, fd: bool) -> None:
        """A CAN_FRAME / CANFD_FRAME: buffered, then written as far as the bus takes it."""
        if bus not in self.configured:
            self.counters["frames_for_unknown_bus"] += 1
            return
        if len(self.buffer) >= BUFFER_FRAMES:
            self.counters["buffer_full"] += 1  # ObjectBuffer::push fails: the frame is lost
        else:
            self.buffer.append((bus, raw_id, bytes(data[:length]), fd))
        self.process_frame_buffer()

    def process_frame_buffer(self) -> None:
        """Write buffered frames until the bus has no transmit slot (l. 141-162)."""
        while self.buffer:
            bus, raw_id, data, fd = self.buffer[0]
            if not self._write(bus, raw_id, data, fd):
                break  # no space in the CAN output slots: try again later
            self.buffer.popleft()
            self.counters["written_to_bus"] += 1

    def handle_can_filter_modify(self, bus_number: int, operation: int, ids: list[int]) -> None:
        """CAN_FILTER_MODIFY (l. 167-251): replace, add to or remove from the id list."""
        if _int8(bus_number) - 1 not in self.configured:
            return
        wanted = sorted(set(ids))
        current = self.filter_ids or []
        if operation == CAN_FILTER_REPLACE:
            self.filter_ids = wanted or None
        elif operation == CAN_FILTER_ADD:
            self.filter_ids = sorted(set(current) | set(wanted)) or None
        elif operation == CAN_FILTER_REMOVE:
            self.filter_ids = [i for i in current if i not in wanted] or None

    # ------------------------------------------------------------------ CAN in

    def can_frame_callback(
        self, bus: int, raw_id: int, data: bytes, fd: bool, now_ms: int
    ) -> Forwarded | None:
        """A frame on a bus: the CAN_FRAME to send, or None (l. 257-320)."""
        if self.callback_bus is None:
            return None  # no callback registered
        if bus != self.callback_bus:
            return None
        check = self.frame_counter == CHECK_EVERY_FRAMES
        self.frame_counter = (self.frame_counter + 1) & 0xFF
        if check:
            if now_ms - self.last_enable_ms > FORWARD_TIMEOUT_MS:
                self.callback_bus = None
                self.counters["forward_expired"] += 1
                return None
            self.frame_counter = 0
        if self.filter_ids is not None and (
            not _in_sorted(self.filter_ids, dronecan_filter_id(raw_id))
        ):
            self.counters["filtered"] += 1
            return None
        if not self._room(self._frame_bytes):
            self.counters["no_room"] += 1  # HAVE_PAYLOAD_SPACE fails: nothing sent, nothing said
            return None
        self.counters["forwarded"] += 1
        return Forwarded(self.requester, bus, raw_id, bytes(data), fd)

    def reboot(self) -> None:
        """A restarted autopilot remembers nothing of the forward."""
        self.callback_bus = None
        self.frame_counter = 0
        self.filter_ids = None
        self.buffer.clear()


def dronecan_filter_id(raw_id: int) -> int:
    """The id a CAN_FILTER_MODIFY list is matched against (l. 281-292): 0 for an anonymous
    frame (low byte 0), a service's type id (bits 16-23) when bit 7 is set, else bits 8-23
    (a message's type id). An 11-bit id gives 0..7: its bits 8-10, or 0 with bit 7 set."""
    if raw_id & 0xFF == 0:
        return 0
    if raw_id & 0x80:
        return (raw_id >> 16) & 0xFF
    return (raw_id >> 8) & 0xFFFF


def _in_sorted(values: list[int], value: int) -> bool:
    index = bisect.bisect_left(values, value)
    return index < len(values) and values[index] == value


def _int8(value: int) -> int:
    """C's ``int8_t(x)``: the low byte, signed."""
    value &= 0xFF
    return value - 256 if value >= 128 else value


class SerialRoom:
    """A port's transmit buffer of ``buffer_bytes`` draining at ``baud`` (8N1), plus
    ``background_bytes_s`` of the autopilot's other messages: whether ``nbytes`` more fit now.
    ``baud`` None: a link that always has room (UDP to SITL's companion port)."""

    def __init__(
        self,
        baud: int | None,
        clock: Callable[[], float],
        *,
        buffer_bytes: int = 512,
        background_bytes_s: float = 0.0,
    ) -> None:
        self._rate = None if baud is None else baud / 10.0
        self._clock = clock
        self._limit = buffer_bytes
        self._background = background_bytes_s
        self._queued = 0.0
        self._at: float | None = None

    def __call__(self, nbytes: int) -> bool:
        if self._rate is None:
            return True
        now = self._clock()
        if self._at is not None:
            drained = (now - self._at) * (self._rate - self._background)
            self._queued = max(0.0, self._queued - drained)
        self._at = now
        if self._queued + nbytes > self._limit:
            return False
        self._queued += nbytes
        return True


class CanForwardLink:
    """A :class:`CanForwarder` between a python-can bus (the autopilot's CAN port) and the
    simulated autopilot's MAVLink link (:class:`~mavservo.sim.autopilot.stream.AutopilotStream`
    calls :meth:`take` for each message it receives, :meth:`pump` every loop).

    ``send(msg)`` writes a pymavlink message on the link; ``own`` is the autopilot's (system,
    component); ``clock`` the monotonic time (the forwarder gets it in ms, as AP_HAL::millis).
    """

    def __init__(
        self,
        bus: can.BusABC,
        *,
        own: tuple[int, int] = (1, 1),
        bus_index: int = 0,
        room: Callable[[int], bool] | None = None,
        clock: Callable[[], float],
    ) -> None:
        self.bus = bus
        self.own = own
        self.bus_index = bus_index
        self._clock = clock
        self.forwarder = CanForwarder(
            (bus_index,), write=self._write, room=room or (lambda nbytes: True)
        )
        self.send: Callable[[Any], None] = lambda msg: None

    def _write(self, bus: int, raw_id: int, data: bytes, fd: bool) -> bool:
        extended = bool(raw_id & FLAG_EFF)
        msg = can.Message(
            arbitration_id=raw_id & (0x1FFFFFFF if extended else 0x7FF),
            is_extended_id=extended,
            is_remote_frame=bool(raw_id & FLAG_RTR),
            is_fd=fd,
            data=data,
        )
        try:
            self.bus.send(msg, timeout=0)
        except can.CanError:
            return False
        return True

    def _ms(self) -> int:
        return int(self._clock() * 1000) & 0xFFFFFFFF

    def take(self, msg: Any) -> bool:
        """True when ``msg`` was the forwarder's (CAN_FRAME, CANFD_FRAME, CAN_FILTER_MODIFY,
        MAV_CMD_CAN_FORWARD addressed to this autopilot)."""
        kind = msg.get_type()
        if kind in ("CAN_FRAME", "CANFD_FRAME", "CAN_FILTER_MODIFY"):
            if (msg.target_system, msg.target_component) not in (self.own, (self.own[0], 0)):
                return True  # another vehicle's: routed elsewhere, not written here
            if kind == "CAN_FILTER_MODIFY":
                ids = list(msg.ids[: msg.num_ids])
                self.forwarder.handle_can_filter_modify(msg.bus, msg.operation, ids)
            else:
                data = bytes(msg.data)
                self.forwarder.handle_can_frame(
                    msg.bus, msg.len, msg.id, data, kind == "CANFD_FRAME"
                )
            return True
        if kind in ("COMMAND_LONG", "COMMAND_INT") and msg.command == mav.MAV_CMD_CAN_FORWARD:
            if (msg.target_system, msg.target_component) != self.own:
                return True
            requester = (msg.get_srcSystem(), msg.get_srcComponent())
            accepted = self.forwarder.handle_can_forward(msg.param1, requester, self._ms())
            result = mav.MAV_RESULT_ACCEPTED if accepted else mav.MAV_RESULT_FAILED
            self.send(
                mav.MAVLink_command_ack_message(
                    mav.MAV_CMD_CAN_FORWARD, result, 0, 0, requester[0], requester[1]
                )
            )
            return True
        return False

    def pump(self, *, silent: bool = False, limit: int = 1000) -> int:
        """Forward what the CAN bus received (``silent``: read and lose it, a rebooting
        autopilot); retry the buffered frames. Returns the frames read."""
        self.forwarder.process_frame_buffer()
        count = 0
        while count < limit:
            msg = self.bus.recv(timeout=0)
            if msg is None:
                break
            count += 1
            if silent:
                continue
            raw_id = msg.arbitration_id | (FLAG_EFF if msg.is_extended_id else 0)
            raw_id |= FLAG_RTR if msg.is_remote_frame else 0
            out = self.forwarder.can_frame_callback(
                self.bus_index, raw_id, bytes(msg.data), bool(msg.is_fd), self._ms()
            )
            if out is not None:
                self._send_frame(out)
        return count

    def _send_frame(self, out: Forwarded) -> None:
        size = 64 if out.fd else 8
        payload = list(out.data) + [0] * (size - len(out.data))
        make = mav.MAVLink_canfd_frame_message if out.fd else mav.MAVLink_can_frame_message
        target = out.target
        self.send(make(target[0], target[1], out.bus, len(out.data), out.raw_id, payload))

    def reboot(self) -> None:
        self.forwarder.reboot()


class SimulatedCanPort:
    """The built-in simulation's flight-controller CAN port (``mavlink.url: sim`` with a
    ``mavlink-can`` bus): the bus's simulated servos on a python-can ``virtual`` channel of their
    own, and the :class:`CanForwardLink` the simulated autopilot forwards it with.
    ``start()``/``stop()`` run the servos; the link goes to the autopilot stream."""

    def __init__(self, servos: list[Any], bus_index: int, channel: str) -> None:
        from mavservo.sim.virtual import VirtualServoBus  # the sim layer's own part

        self.servos = VirtualServoBus(servos, channel=channel)
        self._can = can.Bus(interface="virtual", channel=channel)
        self.link = CanForwardLink(self._can, bus_index=bus_index, clock=time.monotonic)

    def start(self) -> SimulatedCanPort:
        self.servos.start()
        return self

    def stop(self) -> None:
        self.servos.stop()
        self._can.shutdown()
