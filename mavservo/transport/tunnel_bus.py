"""python-can ``mavlink-can``: the flight controller's own CAN port, through MAVLink.

ArduPilot forwards every frame of one of its CAN buses to the MAVLink client that asked with
MAV_CMD_CAN_FORWARD, as CAN_FRAME (CANFD_FRAME for FD frames), and writes every CAN_FRAME it
receives onto that bus (ArduPilot 90700977c5, libraries/AP_CANManager/AP_MAVLinkCAN.cpp:
``handle_can_forward`` l. 27-69, ``handle_can_frame`` l. 74-136, ``can_frame_callback``
l. 257-320). This bus is that client: ``channel`` is the autopilot's CAN bus number, 1-based as
in ``CAN_P1_*`` and in the command's param1 (l. 30: ``bus = param1 - 1``); the frames carry the
0-based index (l. 103).

Why a carrier Protocol and not a MAVLink connection of its own: the bridge already has one link
to the autopilot (a serial port is opened once), with its signing, its peer rules and its
receive thread; and the import rules forbid ``transport`` to import the MAVLink side. So this
bus speaks through a :class:`FrameCarrier` (what the MAVLink side's ``CanTunnel`` implements
and the app hands in) and is told what arrives through :class:`CarrierSink`: transport owns
the CAN semantics (a python-can bus, its counters, its liveness), the MAVLink side owns the
link. Neither imports the other.

Keeping the forward alive: ArduPilot stops forwarding when no MAV_CMD_CAN_FORWARD came for 5 s,
checked at ``frame_counter++ == 100``, every 101st frame on the bus (l. 268-279). The bus sends
it every ``keepalive_s`` (0.5 s: ten times inside the 5 s), from its own send and receive calls
(the scheduler makes both at least every 50 ms), so a restarted autopilot is asked again within
``keepalive_s`` of answering.

Liveness, as a USB adapter's: ArduPilot answers each request with COMMAND_ACK ACCEPTED
(libraries/GCS_MAVLink/GCS_Common.cpp l. 4197-4200), so a working forward is heard at least
every ``keepalive_s`` even on a silent bus. Nothing heard (no frame, no ACK) for
``forward_timeout_s``, or the request refused (bus not configured: l. 43-45 answer FAILED), is
a lost device: ``recv`` raises ``CanOperationError``, and
:class:`~mavservo.transport.resilient_bus.ResilientBus` closes this bus, refuses sends (the
scheduler's refused-send path takes the servos offline, their failsafe as for an unplugged
adapter) and reopens it with backoff through :func:`tunnel_factory`, whose reopened bus counts
only once the autopilot has answered (``confirm_s``).

The autopilot's own DroneCAN traffic comes along (every frame the bus carries, its own sends
included: libraries/AP_HAL/CANIface.cpp l. 80-104). DroneCAN frames are 29-bit; with
``keep_extended`` False (no family of the bus's servos answers with 29-bit ids and no DroneCAN
node is configured on it) they are counted as ``ignored`` and never reach the scheduler.
"""

from __future__ import annotations

import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from typing import Any, Protocol

import can

from mavservo.transport.counters import TransportCounters
from mavservo.transport.outage_words import OutageWords, SaysItsOutages

#: The python-can interface name (``can.buses[].interface``).
MAVLINK_CAN = "mavlink-can"

#: AP_HAL::CANFrame's flag bits in the 32-bit id that CAN_FRAME carries (libraries/AP_HAL/
#: CANIface.h l. 32-34): extended frame, remote request, error frame.
FLAG_EFF = 1 << 31
FLAG_RTR = 1 << 30
FLAG_ERR = 1 << 29
MASK_EXT_ID = 0x1FFFFFFF
MASK_STD_ID = 0x7FF

#: CAN buses an ArduPilot board can have (HAL_NUM_CAN_IFACES is at most 3: CAN_P1..CAN_P3).
MAX_BUS_NUMBER = 3
KEEPALIVE_S = 0.5
FORWARD_TIMEOUT_S = 1.5
#: Extra time the first open gives the autopilot to be heard (the bridge opens its buses before
#: its MAVLink link, and an autopilot that boots with the companion takes seconds).
STARTUP_GRACE_S = 5.0
#: How long a reopened bus waits for the autopilot's answer before the reopen counts as failed.
CONFIRM_S = 0.3
#: ResilientBus's backoff for this bus: a reopen is one small message and a bounded wait, and a
#: restarted autopilot should be asked at once (with a USB adapter's 2 s the bus came back 1.6 s
#: after the autopilot's heartbeat through SITL; docs/engineering/mavlink-can.md).
TUNNEL_MAX_BACKOFF_S = 0.5
RX_QUEUE_FRAMES = 1024
#: The YAML's bounds of this interface's options (``mavservo check`` refuses others): the
#: keep-alive well inside ArduPilot's 5 s, the timeout above two keep-alives.
OPTION_BOUNDS: dict[str, tuple[float, float]] = {
    "keepalive_s": (0.05, 2.0),
    "forward_timeout_s": (0.2, 10.0),
    "foreign_frames_hz": (0.0, 10_000.0),
    "rx_queue_frames": (16, 100_000),
}
_STAT_KEYS = ("sent", "received", "ignored", "dropped", "refused", "outages", "forward_requests")
#: A driver's ``recv(None)`` still wakes this often to keep the forward alive.
_MAX_WAIT_S = 0.1


class CarrierSink(Protocol):
    """What the carrier tells a subscribed bus; called on the MAVLink receive thread."""

    def on_frame(self, raw_id: int, data: bytes, fd: bool, t: float) -> None:
        """A forwarded frame: ``raw_id`` with AP_HAL's flag bits, its data, at monotonic ``t``."""

    def on_forward_ack(self, accepted: bool, result: int, t: float) -> None:
        """The autopilot's COMMAND_ACK of MAV_CMD_CAN_FORWARD (``result``: MAV_RESULT)."""


class FrameCarrier(Protocol):
    """A MAVLink link that carries CAN frames to and from one autopilot."""

    def subscribe(self, bus_index: int, sink: CarrierSink) -> None:
        """Deliver what arrives for CAN bus ``bus_index`` (0-based) to ``sink``."""

    def unsubscribe(self, bus_index: int, sink: CarrierSink) -> None:
        """Stop delivering to ``sink`` (a closed bus)."""

    def send_frame(self, bus_index: int, raw_id: int, data: bytes, fd: bool) -> bool:
        """CAN_FRAME (CANFD_FRAME) to the autopilot; False when it cannot go (no autopilot
        heard yet, link not open)."""

    def request_forward(self, bus_number: int) -> bool:
        """MAV_CMD_CAN_FORWARD with param1 ``bus_number`` (1-based); False when not sent."""

    def set_filter(self, bus_number: int, ids: list[int]) -> bool:
        """CAN_FILTER_MODIFY: forward only frames whose :func:`filter_key` is in ``ids``."""


class TunnelledCanBus(can.BusABC, TransportCounters, SaysItsOutages):
    """The autopilot's CAN bus ``channel`` (1-based), through ``carrier``; see the module.

    ``clock`` is injectable so a test runs minutes of keep-alive in no time; ``confirm_s`` > 0
    makes the constructor wait that long for the autopilot's answer (a reopen) and raise
    ``CanInitializationError`` without one.
    """

    def __init__(
        self,
        channel: Any,
        *,
        carrier: FrameCarrier | None = None,
        keepalive_s: float = KEEPALIVE_S,
        forward_timeout_s: float = FORWARD_TIMEOUT_S,
        startup_grace_s: float = 0.0,
        confirm_s: float = 0.0,
        keep_extended: bool = False,
        foreign_frames_hz: float = 30.0,
        rx_queue_frames: int = RX_QUEUE_FRAMES,
        filter_at_autopilot: bool = True,
        forward_filter_ids: list[int] | None = None,
        clock: Callable[[], float] = time.monotonic,
        **kwargs: Any,
    ) -> None:
        """``foreign_frames_hz``: the frames per second the autopilot's own nodes put on that
        bus (its DroneCAN; ~27/s measured on ArduPlane SITL), forwarded over the link whether
        kept or not: the link plan counts them (``mavservo check``). ``forward_filter_ids``
        (set by the bridge from the servos' reply ids; None: none possible) goes to the
        autopilot as CAN_FILTER_MODIFY with every keep-alive unless ``filter_at_autopilot`` is
        False (:func:`filter_key`). The YAML's bounds are checked at load
        (:data:`OPTION_BOUNDS`)."""
        if carrier is None:
            raise can.CanInitializationError(
                "interface 'mavlink-can' speaks through the bridge's MAVLink link; it is "
                "opened by the bridge (mavservo run), not on its own"
            )
        number = bus_number(channel)
        if number is None:
            raise can.CanInitializationError(
                f"mavlink-can channel must be the autopilot's CAN bus number 1..{MAX_BUS_NUMBER} "
                f"(CAN_P1..CAN_P{MAX_BUS_NUMBER}), got {channel!r}"
            )
        self.bus_number = number
        self.bus_index = number - 1
        self._carrier = carrier
        self._keepalive_s = keepalive_s
        self._forward_timeout_s = forward_timeout_s
        self._keep_extended = keep_extended
        self.foreign_frames_hz = foreign_frames_hz
        self._filter = (
            sorted(set(forward_filter_ids))
            if filter_at_autopilot and forward_filter_ids is not None
            else None
        )
        self._clock = clock
        self._lock = threading.Lock()
        self._arrived = threading.Condition(self._lock)
        self._queue: deque[can.Message] = deque()
        self._queue_limit = max(1, int(rx_queue_frames))
        self.counters: Counter[str] = Counter()
        now = clock()
        self._last_heard = now + startup_grace_s
        self._next_request = now
        self._lost: str | None = None
        self._answered = False
        """The autopilot answered this bus (a frame or an accepted ACK) since it was opened."""
        self._closed = False
        self.channel_info = f"autopilot CAN{number} via MAVLink"
        super().__init__(channel=number, **kwargs)
        carrier.subscribe(self.bus_index, self)
        self._maintain(now)
        if confirm_s > 0 and not self._wait_confirmed(confirm_s):
            reason = self._lost or (
                f"no answer to MAV_CMD_CAN_FORWARD for CAN bus {number} within {confirm_s:g} s"
            )
            self.shutdown()
            raise can.CanInitializationError(reason)

    # ------------------------------------------------------------------ carrier side

    def on_frame(self, raw_id: int, data: bytes, fd: bool, t: float) -> None:
        with self._lock:
            self._heard(t)
            if raw_id & FLAG_ERR:
                self.counters["error_frames"] += 1
                return
            extended = bool(raw_id & FLAG_EFF)
            if extended and not self._keep_extended:
                self.counters["ignored"] += 1  # the autopilot's own DroneCAN traffic
                return
            if len(self._queue) >= self._queue_limit:
                self.counters["dropped"] += 1
                return
            self._queue.append(
                can.Message(
                    timestamp=t,
                    arbitration_id=raw_id & (MASK_EXT_ID if extended else MASK_STD_ID),
                    is_extended_id=extended,
                    is_remote_frame=bool(raw_id & FLAG_RTR),
                    is_fd=fd,
                    dlc=len(data),
                    data=data,
                    channel=self.bus_number,
                )
            )
            self.counters["received"] += 1
            self._arrived.notify()

    def _heard(self, t: float) -> None:
        """The autopilot answered at ``t`` (under the lock); the start-up grace ends with its
        first answer."""
        self._last_heard = max(self._last_heard, t) if self._answered else t
        self._answered = True

    def on_forward_ack(self, accepted: bool, result: int, t: float) -> None:
        with self._lock:
            self.counters["forward_acks"] += 1
            if accepted:
                self._heard(t)
                self._arrived.notify()
                return
            self.counters["forward_refused"] += 1
            self._lost = refusal_text(self.bus_number, result)
            self._arrived.notify()

    # ------------------------------------------------------------------ python-can side

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._maintain(self._clock())
        if self._lost is not None:
            raise can.CanOperationError(self._lost)
        limit = 64 if msg.is_fd else 8
        if msg.is_error_frame or len(msg.data) > limit:
            self.counters["refused"] += 1
            raise can.CanError(f"mavlink-can cannot carry this frame: {msg}")
        raw_id = msg.arbitration_id & (MASK_EXT_ID if msg.is_extended_id else MASK_STD_ID)
        raw_id |= (FLAG_EFF if msg.is_extended_id else 0) | (FLAG_RTR if msg.is_remote_frame else 0)
        if not self._carrier.send_frame(self.bus_index, raw_id, bytes(msg.data), msg.is_fd):
            self.counters["refused"] += 1
            raise can.CanTimeoutError(
                f"CAN bus {self.bus_number} via MAVLink: the autopilot is not heard yet"
            )
        self.counters["sent"] += 1

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        deadline = None if timeout is None else self._clock() + timeout
        while True:
            now = self._clock()
            self._maintain(now)
            with self._lock:
                if self._queue:
                    return self._queue.popleft(), False
                if self._lost is not None:
                    raise can.CanOperationError(self._lost)
                wait = _MAX_WAIT_S if deadline is None else min(deadline - now, _MAX_WAIT_S)
                if wait <= 0:
                    return None, False
                self._arrived.wait(wait)
                if self._closed:
                    return None, False

    def _maintain(self, now: float) -> None:
        """The keep-alive when due, and the forward's liveness (see the module)."""
        with self._lock:
            if self._closed:
                return
            silent = now - self._last_heard
            if self._lost is None and silent > self._forward_timeout_s:
                self.counters["outages"] += 1
                self._lost = (
                    f"the autopilot stopped forwarding CAN bus {self.bus_number}: nothing heard "
                    f"for {silent:.1f} s (no frame, no answer to MAV_CMD_CAN_FORWARD)"
                )
                self._arrived.notify_all()
            due = now >= self._next_request
            if due:
                self._next_request = now + self._keepalive_s
        if due and self._lost is None:
            if self._carrier.request_forward(self.bus_number):
                self.counters["forward_requests"] += 1
                if self._filter is not None:
                    self._carrier.set_filter(self.bus_number, self._filter)
            else:  # no autopilot yet: asked again at the next call, before the first frame
                with self._lock:
                    self._next_request = now

    def _wait_confirmed(self, seconds: float) -> bool:
        """True once the autopilot answered (a frame or an accepted ACK) within ``seconds``
        of real time (a thread waits here, whatever clock the bus keeps)."""
        deadline = time.monotonic() + seconds
        with self._lock:
            while not self._answered and self._lost is None:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._arrived.wait(min(left, _MAX_WAIT_S))
            return self._lost is None

    def outage_words(self) -> OutageWords:
        """Not a device unplugged: the forward stopped (the reason says how: nothing heard, or
        the request refused) and the bus asks the autopilot again; back once it answered."""
        return OutageWords(
            lost="{name}: {reason}; asking the autopilot again",
            back="{name}: the autopilot's CAN port is back after {down_for:.1f} s "
            f"(forwarding CAN bus {self.bus_number} again)",
            down="{name}: the autopilot's CAN port is not forwarding; asking it again",
            retrying="{name}: no answer from the autopilot for CAN bus "
            f"{self.bus_number} ({{failed}} requests since it stopped): {{reason}}; still asking",
        )

    @property
    def forwarding(self) -> bool:
        """Whether the forward is alive as far as this bus knows."""
        return self._lost is None

    def stats(self) -> dict[str, Any]:
        """``sent``/``received``: frames each way; ``ignored``: 29-bit frames dropped (the
        autopilot's DroneCAN); ``dropped``: frames the full receive queue lost; ``refused``:
        frames that could not go; ``outages``: forwards lost; ``forward_*``: the keep-alive."""
        with self._lock:
            return {**dict.fromkeys(_STAT_KEYS, 0), **self.counters, "queued": len(self._queue)}

    def shutdown(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._arrived.notify_all()
        self._carrier.unsubscribe(self.bus_index, self)
        super().shutdown()


#: MAV_RESULT values (common.xml) an autopilot answers MAV_CMD_CAN_FORWARD with.
MAV_RESULT_UNSUPPORTED = 3
MAV_RESULT_FAILED = 4


def refusal_text(number: int, result: int) -> str:
    """Why the autopilot refused to forward CAN bus ``number`` (``result``: its MAV_RESULT)."""
    if result == MAV_RESULT_UNSUPPORTED:  # PX4's commander answers unknown commands so
        return (
            f"the autopilot does not support CAN forwarding (MAV_CMD_CAN_FORWARD unsupported; "
            f"PX4 has none): CAN bus {number} cannot be reached through MAVLink"
        )
    return (
        f"the autopilot refused to forward CAN bus {number} (MAV_CMD_CAN_FORWARD result "
        f"{result}): is CAN_P{number}_DRIVER set (ArduPilot answers FAILED for a bus without a "
        "driver), and its CAN_Dx_PROTOCOL DroneCAN (1)?"
    )


def bus_number(channel: Any) -> int | None:
    """The 1-based CAN bus number a ``mavlink-can`` channel names (``1``, ``"1"``), or None."""
    if isinstance(channel, bool):
        return None
    try:
        number = int(channel)
    except (TypeError, ValueError):
        return None
    return number if 1 <= number <= MAX_BUS_NUMBER else None


def filter_key(raw_id: int) -> int:
    """The key ArduPilot matches a forwarded frame against a CAN_FILTER_MODIFY list with
    (AP_MAVLinkCAN.cpp l. 281-292, written for DroneCAN ids): 0 when the low byte is 0, bits
    16-23 when bit 7 is set (a service), else bits 8-23. An 11-bit id's key is 0..7, so a list of
    the servos' keys keeps their replies and drops the autopilot's own DroneCAN messages."""
    if raw_id & 0xFF == 0:
        return 0
    if raw_id & 0x80:
        return (raw_id >> 16) & 0xFF
    return (raw_id >> 8) & 0xFFFF


def tunnel_factory(
    kwargs: dict[str, Any], carrier: FrameCarrier | None
) -> Callable[[], can.BusABC]:
    """The opener :class:`~mavservo.transport.resilient_bus.ResilientBus` calls: the first bus
    is opened at once (the bridge opens its buses before its MAVLink link; it gets
    :data:`STARTUP_GRACE_S` to hear the autopilot), each reopen after an outage counts only once
    the autopilot answered within :data:`CONFIRM_S`."""
    options = {k: v for k, v in kwargs.items() if k not in ("interface", "ignore_config")}
    opened = False

    def factory() -> can.BusABC:
        nonlocal opened
        first = not opened
        bus = TunnelledCanBus(
            carrier=carrier,
            startup_grace_s=STARTUP_GRACE_S if first else 0.0,
            confirm_s=0.0 if first else CONFIRM_S,
            **options,
        )
        opened = True
        return bus

    return factory
