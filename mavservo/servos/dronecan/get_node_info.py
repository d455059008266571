"""DroneCAN ``uavcan.protocol.GetNodeInfo`` as frames: the request a tool node sends and the
reader that reassembles a node's answer (who it says it is). Pure: builds and parses frames, no
I/O; the doctor (:mod:`mavservo.app.doctor`) decides whom to ask and when.

From the DSDL ``uavcan/protocol/1.GetNodeInfo.uavcan`` (as shipped in the ``dronecan``
package): a "full node info request" with an empty request section, a read that changes nothing
on the node; the response carries ``status`` (NodeStatus), ``software_version`` (major, minor,
``optional_field_flags``: bit 0 ``vcs_commit`` set, bit 1 ``image_crc`` set),
``hardware_version`` (major, minor, ``unique_id[16]``, a certificate) and ``name`` (up to 80
ASCII bytes, a reversed domain name). The ``dronecan`` package encodes the request and decodes
the response (through :mod:`.wire`, which owns the package's lazy import and a reassembler that
counts, never raises on, a hostile transfer).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import can

from . import wire

NAME_MAX = 80


@dataclass(frozen=True)
class NodeInfo:
    """What a node said of itself."""

    node_id: int
    name: str
    software: str
    hardware: str
    unique_id: str

    def text(self) -> str:
        return (
            f"GetNodeInfo: {self.name}, software {self.software}, hardware {self.hardware}, "
            f"unique id {self.unique_id}"
        )


def get_node_info_request(node_id: int, source: int, transfer_id: int) -> list[can.Message]:
    """The frames of one GetNodeInfo request from ``source`` to ``node_id``."""
    request = wire.lib().uavcan.protocol.GetNodeInfo.Request()
    return wire.encode_service(
        request, source=source, destination=node_id, transfer_id=transfer_id, request=True
    )


def _printable(raw: bytes) -> str:
    """A node's name, with anything not printable ASCII shown as ``?`` (a hostile node's
    name goes to a terminal)."""
    return "".join(chr(c) if 0x20 <= c < 0x7F else "?" for c in raw[:NAME_MAX]) or "(no name)"


def _node_info(node_id: int, payload: Any) -> NodeInfo:
    software = payload.software_version
    version = f"{int(software.major)}.{int(software.minor)}"
    flags = int(software.optional_field_flags)
    if flags & 1:
        version += f" (vcs 0x{int(software.vcs_commit):08x})"
    if flags & 2:
        version += f" (image crc 0x{int(software.image_crc):016x})"
    hardware = payload.hardware_version
    unique = bytes(int(b) & 0xFF for b in hardware.unique_id)
    return NodeInfo(
        node_id,
        _printable(bytes(int(b) & 0xFF for b in payload.name)),
        version,
        f"{int(hardware.major)}.{int(hardware.minor)}",
        unique.hex() if any(unique) else "(none)",
    )


class NodeInfoReader:
    """GetNodeInfo responses addressed to ``own_id``, reassembled from the frames heard."""

    def __init__(self, own_id: int) -> None:
        self.own_id = own_id
        self.reassembler = wire.Reassembler()

    def accepts(self, msg: can.Message) -> bool:
        """A frame of a GetNodeInfo response to the doctor's node (each frame of the
        transfer, not only its last)."""
        fields = wire.service_fields(msg)
        return (
            fields is not None
            and not msg.is_error_frame
            and fields.dtid == wire.DTID_GET_NODE_INFO
            and not fields.request
            and fields.destination == self.own_id
            and 1 <= fields.source <= 127
        )

    def push(self, msg: can.Message, now: float) -> NodeInfo | None:
        """The node's answer once its last frame is in; None before, and for any other
        frame or a transfer that does not decode."""
        if not self.accepts(msg):
            return None
        received = self.reassembler.push(msg, now)
        if received is None or received.full_name != "uavcan.protocol.GetNodeInfo":
            return None
        try:
            return _node_info(received.source, received.payload)
        except (AttributeError, TypeError, ValueError):  # a payload the library let through oddly
            return None
