"""The server side of DroneCAN dynamic node id allocation (``uavcan.protocol.dynamic_node_id.
Allocation``, data type 1), for servos that start without a node id.

The exchange (DroneCAN specification, "Dynamic node ID allocation", centralised server; the
``dronecan`` package's ``CentralizedServer`` follows the same steps): a node without an id sends
anonymous Allocation messages carrying its 16-byte unique id in three parts (6, 6 and 4 bytes;
the first flagged ``first_part_of_unique_id``); after each part the server broadcasts what it
has so far, and after the last one the id it allocates. A query not continued within
``FOLLOWUP_TIMEOUT`` is forgotten.

Which id: a unique id a servo's ``options.unique_id`` names gets that servo's configured node
id (so the config says which physical servo is which); one in the table (persisted next to the
config by the bridge, handed back through ``node.dronecan.allocation_table``) gets its id again;
anything else gets the node's preferred id if free, else the highest free id from
``allocation_first_id`` down. Ids of the config's servos, of the bridge and of every node heard
on the bus are never handed out.

Bounds (anyone on the bus can make up unique ids, and an anonymous request needs no node id):
unique ids the config does not name get at most ``max_entries`` table entries, and at most
:data:`NEW_IDS_PER_MINUTE` new ones a minute; an entry whose node has not been heard
(NodeStatus) for ``expire_s`` goes, and so does a node id heard on the bus that has been silent
that long (it blocked allocation while it was there). When no id can be handed out the server
says so once (:meth:`AllocationServer.pool_empty_noted`), for the bridge to report.

Pure: times are handed in; the table changes are counted in :attr:`AllocationServer.version`
for the bridge to save.
"""

from __future__ import annotations

from collections import deque
from typing import Any

import can

from . import wire

FOLLOWUP_TIMEOUT_S = 0.5
"""``Allocation.FOLLOWUP_TIMEOUT_MS``: a query not continued within this is forgotten."""
_STAGE_LENGTHS = (6, 6, 4)
_ALLOCATIONS_KEPT = 64
ALLOCATION_ANSWERS_PER_S = 6
"""Answers per second at most: an allocation takes three, and a node without an id asks again
after a random pause (the specification's request period), so this serves two nodes a second
while a flood of anonymous requests (which need no node id to send) cannot fill the bus with
answers; requests beyond are counted in :attr:`AllocationServer.limited` and not answered."""
ALLOCATION_ANSWER_FRAMES = 3
"""Frames of the longest answer (node id and the whole 16-byte unique id, 17 bytes, and the
transfer CRC: three frames), for the bus-load budget."""
NEW_IDS_PER_MINUTE = 6
"""New table entries (unique ids the config does not name) a minute, at most: a board of
servos powering up allocates a handful at once; a stranger inventing unique ids gets six a
minute, within the cap, instead of the whole pool in a minute."""
UNCONFIRMED_EXPIRE_S = 10.0
"""An id handed out whose node never sends a NodeStatus within this long is free again (and
is never saved): a node starts its NodeStatus as soon as it has an id, a made-up unique id
never does."""
_EXPIRE_EVERY_S = 1.0
_MAX_REGULAR_ID = 125
"""126 and 127 are reserved for tools (the specification's ``MAX_NODE_ID`` for allocation)."""


class AllocationServer:
    """A centralised allocator (module docstring)."""

    def __init__(
        self,
        own_id: int,
        configured: dict[bytes, int],
        static_ids: set[int],
        first_id: int,
        table: dict[bytes, int] | None = None,
        *,
        max_entries: int = 16,
        expire_s: float = 600.0,
        start: float = 0.0,
    ) -> None:
        self.own_id = own_id
        self.configured = dict(configured)
        self.reserved = set(static_ids) | set(configured.values()) | {own_id}
        self.table: dict[bytes, int] = {}
        self.dropped: list[tuple[str, int]] = []
        """Table entries not kept: the table comes from a file anyone may have edited, and an
        entry with the bridge's id, a servo's, another entry's, or for a configured unique id
        would hand an id in use to a second node."""
        for unique_id, node_id in sorted((table or {}).items()):
            taken = self.reserved | set(self.table.values())
            if unique_id in self.configured or node_id in taken or not 1 <= node_id <= 125:
                self.dropped.append((unique_id.hex(), node_id))
            else:
                self.table[unique_id] = node_id
        self.first_id = first_id
        self.max_entries = max_entries
        self.expire_s = expire_s
        self.seen_ids: dict[int, float] = {}
        """Node ids heard on the bus -> when last (they expire, see the module docstring)."""
        self._heard: dict[int, float] = dict.fromkeys(self.table.values(), start)
        """Node ids of table entries -> when their node was last heard (loaded ones: start)."""
        self._confirmed: set[int] = set(self.table.values())
        """Node ids of table entries whose node has sent a NodeStatus (loaded ones: were)."""
        self._new_ids: deque[float] = deque(maxlen=NEW_IDS_PER_MINUTE)
        self._next_expiry = start
        self.refused = 0
        """Requests for a new id refused: the cap, the rate, or no id left."""
        self.expired = 0
        self.rate_limited = 0
        """New ids refused for the rate (:data:`NEW_IDS_PER_MINUTE`)."""
        self._pool_empty = False
        self._pool_empty_told = False
        self.version = 0
        """Bumped whenever :attr:`table` changes (the bridge saves it then)."""
        self.allocations: deque[tuple[str, int]] = deque(maxlen=_ALLOCATIONS_KEPT)
        """The latest ``(unique id hex, node id)`` handed out, in order (diagnostics, tests;
        bounded: a node may ask again and again)."""
        self.ignored = 0
        self.limited = 0
        self._answered: deque[float] = deque(maxlen=ALLOCATION_ANSWERS_PER_S)
        self._query = b""
        self._query_time = 0.0
        self._queue: list[can.Message] = []
        self._tid = 0

    def pending(self) -> bool:
        return bool(self._queue)

    def due(self, now: float) -> list[can.Message]:
        if now >= self._next_expiry:
            self._next_expiry = now + _EXPIRE_EVERY_S
            self._expire(now)
        out, self._queue = self._queue, []
        return out

    def seen(self, node_id: int, now: float) -> None:
        """A node with this id is on the bus: never hand its id to another while it is."""
        if node_id in self._heard:
            self._heard[node_id] = now
            if node_id not in self._confirmed:
                self._confirmed.add(node_id)
                self.version += 1  # now worth saving
        elif node_id in self.seen_ids or len(self.seen_ids) < _MAX_REGULAR_ID + 2:
            self.seen_ids[node_id] = now

    def _expire(self, now: float) -> None:
        """Forget seen ids and table entries silent for ``expire_s`` (module docstring)."""
        limit = now - self.expire_s
        for node_id in [n for n, t in self.seen_ids.items() if t < limit]:
            del self.seen_ids[node_id]
            self._pool_empty = False
        unconfirmed = now - UNCONFIRMED_EXPIRE_S
        stale = [
            uid
            for uid, node_id in self.table.items()
            if self._heard.get(node_id, now)
            < (limit if node_id in self._confirmed else unconfirmed)
        ]
        for unique_id in stale:
            node_id = self.table.pop(unique_id)
            del self._heard[node_id]
            self._confirmed.discard(node_id)
            self.expired += 1
            self.version += 1
            self._pool_empty = False

    def pool_empty_noted(self) -> bool:
        """True once each time the pool runs empty (a request got no id), for a notice."""
        if self._pool_empty and not self._pool_empty_told:
            self._pool_empty_told = True
            return True
        if not self._pool_empty:
            self._pool_empty_told = False
        return False

    def describe_pool(self) -> str:
        """The state of the pool, for the notice."""
        return (
            f"{len(self.table)} of at most {self.max_entries} entries for unknown nodes, "
            f"{len(self.seen_ids)} node ids heard on the bus; entries and heard ids expire "
            f"after {self.expire_s:g} s of silence"
        )

    def receive(self, received: wire.Received, now: float) -> bool:
        """An anonymous Allocation request; True when an answer waits in :meth:`due`."""
        if received.source != 0 or received.service:
            self.ignored += 1  # another allocator, or not an allocation request
            return False
        answered = self._answered
        if len(answered) == answered.maxlen and now - answered[0] < 1.0:
            self.limited += 1
            return False
        message = received.payload
        try:
            unique_id = bytes(message.unique_id.to_bytes())
            preferred = int(message.node_id)
            first = bool(message.first_part_of_unique_id)
        except (AttributeError, TypeError, ValueError):
            self.ignored += 1
            return False
        if self._query and now - self._query_time > FOLLOWUP_TIMEOUT_S:
            self._query = b""
        stage = len(self._query) // 6 if len(self._query) in (0, 6, 12) else None
        if first and len(unique_id) == _STAGE_LENGTHS[0]:
            self._query = unique_id
        elif not first and stage in (1, 2) and len(unique_id) == _STAGE_LENGTHS[stage]:
            self._query += unique_id
        else:
            self.ignored += 1
            return False
        self._query_time = now
        node_id = 0
        if len(self._query) == 16:
            rate_limited = self.rate_limited
            node_id = self._allocate(self._query, preferred, now)
            if node_id == 0:
                self.refused += 1  # no id for it: say nothing (the node keeps asking)
                self._pool_empty = self.rate_limited == rate_limited
                self._query = b""
                return False
        self._answer(node_id, self._query, now)
        if node_id:
            self._query = b""
        return True

    def _answer(self, node_id: int, unique_id: bytes, now: float) -> None:
        self._answered.append(now)
        allocation = wire.lib().uavcan.protocol.dynamic_node_id.Allocation()
        allocation.node_id = node_id
        allocation.first_part_of_unique_id = False
        allocation.unique_id.from_bytes(unique_id)
        self._queue += wire.encode_message(allocation, self.own_id, self._tid, wire.PRIORITY_LOW)
        self._tid = (self._tid + 1) & 0x1F

    def _allocate(self, unique_id: bytes, preferred: int, now: float) -> int:
        node_id = self.configured.get(unique_id) or self.table.get(unique_id)
        if node_id is None:
            if len(self.table) >= self.max_entries:
                return 0
            new_ids = self._new_ids
            if len(new_ids) == new_ids.maxlen and now - new_ids[0] < 60.0:
                self.rate_limited += 1
                return 0
            used = self.reserved | set(self.seen_ids) | set(self.table.values())
            if 1 <= preferred <= _MAX_REGULAR_ID and preferred not in used:
                node_id = preferred
            else:
                node_id = next((i for i in range(self.first_id, 0, -1) if i not in used), 0)
            if node_id == 0:
                return 0
            self.table[unique_id] = node_id
            self._heard[node_id] = now
            new_ids.append(now)
            self.version += 1
        elif node_id in self._heard:
            self._heard[node_id] = now
        self._pool_empty = False
        self.allocations.append((unique_id.hex(), node_id))
        return node_id

    def table_hex(self) -> dict[str, Any]:
        """The table as saved: unique id in hex -> node id, for nodes that have been heard
        (an id handed to a unique id that never became a node is not kept across restarts)."""
        return {
            uid.hex(): node_id
            for uid, node_id in sorted(self.table.items())
            if node_id in self._confirmed
        }
