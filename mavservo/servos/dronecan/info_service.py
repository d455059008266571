"""The bridge node's answers to ``uavcan.protocol.GetNodeInfo``: who it is, at a bounded rate.

A DroneCAN tool (``dronecan-gui-tool``) or an autopilot's node monitor asks every node it sees
who it is. The answer (NodeStatus, software and hardware version with the unique id, the name)
is about nine frames for a one-frame request, so a node that asks in a loop could fill the bus
with the bridge's traffic: the answers are bounded to :data:`GET_NODE_INFO_PER_S`, the requests
beyond counted and said once. A job with its own state (when it last answered), apart from the
node's broadcasts; :class:`.node.BridgeNode` hands it the requests addressed to it. The reader
of other nodes' answers (the doctor's side) is :mod:`.node_info`. Pure: no clock, no I/O.
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Callable
from typing import Any

import can

from . import wire
from .notices import Notices

GET_NODE_INFO_PER_S = 4
"""GetNodeInfo answers per second at most (a tool or node monitor asks once per node it
sees): each answer is about nine frames for a one-frame request, so an unbounded answer rate
would let any node on the bus fill it with the bridge's traffic. Requests beyond are counted
(``get_node_info_limited``) and not answered; the asker asks again."""


class NodeInfoService:
    """Answers GetNodeInfo for one node: ``status(now)`` is its NodeStatus payload then."""

    def __init__(
        self,
        node_id: int,
        name: str,
        software_version: tuple[int, int],
        unique_id: bytes,
        status: Callable[[float], Any],
        counters: Counter[str],
        notices: Notices,
    ) -> None:
        self.node_id = node_id
        self.name = name
        self.software_version = software_version
        self.unique_id = unique_id
        self._status = status
        self._counters = counters
        self._notices = notices
        self._answered: deque[float] = deque(maxlen=GET_NODE_INFO_PER_S)

    def answer(self, request: wire.Received, now: float) -> list[can.Message] | None:
        """The frames answering ``request``; None when the rate bound refuses it (counted)."""
        answered = self._answered
        if len(answered) == answered.maxlen and now - answered[0] < 1.0:
            self._counters["get_node_info_limited"] += 1
            self._notices.once(
                "get_node_info_limited",
                f"DroneCAN node {request.source} asks GetNodeInfo faster than "
                f"{GET_NODE_INFO_PER_S}/s: the requests beyond are not answered "
                "(counted in get_node_info_limited)",
            )
            return None
        answered.append(now)
        self._counters["get_node_info"] += 1
        return self.response(request, now)

    def response(self, request: wire.Received, now: float) -> list[can.Message]:
        """The answer's frames, addressed to the asker, with its transfer id and priority."""
        info = wire.lib().uavcan.protocol.GetNodeInfo.Response()
        info.status = self._status(now)
        info.software_version.major, info.software_version.minor = self.software_version
        info.hardware_version.unique_id.from_bytes(self.unique_id)
        info.name = self.name
        return wire.encode_service(
            info,
            source=self.node_id,
            destination=request.source,
            transfer_id=request.transfer_id,
            request=False,
            priority=request.priority,  # a response keeps its request's priority
        )

    def frames(self) -> int:
        """Frames of the answer: NodeStatus (7 bytes), software version (15), hardware version
        with an empty certificate (19), the name (tail array, no length byte), the transfer
        CRC; 7 bytes a frame."""
        return -(-(7 + 15 + 19 + len(self.name) + 2) // 7)
