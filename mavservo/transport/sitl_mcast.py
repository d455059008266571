"""python-can ``sitl-mcast``: ArduPilot SITL's simulated CAN bus (multicast UDP).

ArduPilot SITL (``SIM_CAN_TYPE1/2`` 1, the default) puts each CAN interface on a multicast group
(ArduPilot 90700977c5, libraries/AP_HAL_SITL/CAN_Multicast.cpp): interface k (0-based: CAN_P1 is
0, l. 40-43) joins ``239.65.82.k`` port 57732 (l. 20-21); one datagram is one frame (l. 26-32,
49-65): ``<HHHI`` little-endian magic 0x2934, CRC, flags (bit 0: CAN FD), the 32-bit id with
AP_HAL::CANFrame's flag bits (bit 31 extended, 30 remote, 29 error), then the data, whose length
is the rest of the datagram; the CRC is CRC-16/CCITT-FALSE (``crc16_ccitt`` with 0xFFFF, which
``binascii.crc_hqx`` computes) over flags..data (l. 62, 80). A member drops its own datagrams by
source address (libraries/AP_HAL/utility/Socket.cpp ``recv``: "discard packets from
ourselves"); so does this bus.

``channel`` is that group's last octet (0 = CAN_P1), as pydronecan's ``mcast:0``. Why a bus of
the project's own: the live test puts the project's simulated servos on SITL's CAN bus (and the
bridge can be rehearsed against it with ``interface: sitl-mcast``); python-can's own
``udp_multicast`` speaks another format. Datagrams leave the host never: the multicast TTL is 0
(delivered on this machine only).
"""

from __future__ import annotations

import binascii
import select
import socket
import struct
from typing import Any

import can

#: The python-can interface name.
SITL_MCAST = "sitl-mcast"
GROUP_BASE = "239.65.82."
PORT = 57732
MAGIC = 0x2934
FLAG_CANFD = 0x0001
_HEADER = struct.Struct("<HHHI")
_EFF, _RTR, _ERR = 1 << 31, 1 << 30, 1 << 29
_MAX_DATAGRAM = _HEADER.size + 64


def encode(msg: can.Message) -> bytes:
    """One datagram for ``msg`` (CAN_Multicast::send)."""
    raw_id = msg.arbitration_id & (0x1FFFFFFF if msg.is_extended_id else 0x7FF)
    raw_id |= (_EFF if msg.is_extended_id else 0) | (_RTR if msg.is_remote_frame else 0)
    body = struct.pack("<HI", FLAG_CANFD if msg.is_fd else 0, raw_id) + bytes(msg.data)
    return struct.pack("<HH", MAGIC, binascii.crc_hqx(body, 0xFFFF)) + body


def decode(datagram: bytes, timestamp: float = 0.0) -> can.Message | None:
    """The frame in ``datagram``, or None for one CAN_Multicast::receive would drop (short,
    bad magic, bad CRC) or an error frame."""
    if len(datagram) < _HEADER.size or len(datagram) > _MAX_DATAGRAM:
        return None
    magic, crc, flags, raw_id = _HEADER.unpack_from(datagram)
    if magic != MAGIC or crc != binascii.crc_hqx(datagram[4:], 0xFFFF) or raw_id & _ERR:
        return None
    data = datagram[_HEADER.size :]
    fd = bool(flags & FLAG_CANFD)
    if not fd and len(data) > 8:
        return None
    extended = bool(raw_id & _EFF)
    return can.Message(
        timestamp=timestamp,
        arbitration_id=raw_id & (0x1FFFFFFF if extended else 0x7FF),
        is_extended_id=extended,
        is_remote_frame=bool(raw_id & _RTR),
        is_fd=fd,
        dlc=len(data),
        data=data,
    )


class SitlMulticastBus(can.BusABC):
    """Member ``channel`` (0 = CAN_P1) of ArduPilot SITL's multicast CAN bus."""

    def __init__(self, channel: Any = 0, **kwargs: Any) -> None:
        try:
            index = int(channel)
        except (TypeError, ValueError):
            index = -1
        if not 0 <= index <= 255 or isinstance(channel, bool):
            raise can.CanInitializationError(
                f"sitl-mcast channel is the SITL CAN interface 0..255 (0 = CAN_P1), got {channel!r}"
            )
        self.group = GROUP_BASE + str(index)
        self.garbled = 0
        rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            rx.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            rx.bind((self.group, PORT))
            membership = struct.pack("4s4s", socket.inet_aton(self.group), bytes(4))
            rx.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, membership)
            tx.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)  # this host only
            tx.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
            tx.connect((self.group, PORT))
        except OSError as exc:
            rx.close()
            tx.close()
            raise can.CanInitializationError(f"sitl-mcast {self.group}:{PORT}: {exc}") from exc
        self._rx, self._tx = rx, tx
        self._own = tx.getsockname()
        self.channel_info = f"ArduPilot SITL CAN {self.group}:{PORT}"
        super().__init__(channel=index, **kwargs)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        try:
            self._tx.send(encode(msg))
        except OSError as exc:
            raise can.CanOperationError(f"sitl-mcast send: {exc}") from exc

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        try:
            ready, _, _ = select.select([self._rx], [], [], timeout)
            if not ready:
                return None, False
            datagram, source = self._rx.recvfrom(_MAX_DATAGRAM + 1)
        except OSError as exc:
            raise can.CanOperationError(f"sitl-mcast receive: {exc}") from exc
        if source == self._own:
            return None, False  # our own frame, looped back
        msg = decode(datagram)
        if msg is None:
            self.garbled += 1
        return msg, False

    def fileno(self) -> int:
        return self._rx.fileno()

    def shutdown(self) -> None:
        super().shutdown()
        self._rx.close()
        self._tx.close()
