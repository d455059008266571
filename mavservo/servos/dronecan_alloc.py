"""Dynamic node id allocation server (placeholder until implemented)."""

from __future__ import annotations

from typing import Any

import can


class AllocationServer:
    """Not implemented yet: answers nothing."""

    def __init__(self, own_id: int, taken: set[int], first_id: int) -> None:
        self.own_id = own_id
        self.taken = set(taken)
        self.first_id = first_id

    def receive(self, received: Any, now: float) -> bool:
        return False

    def due(self, now: float) -> list[can.Message]:
        return []

    def pending(self) -> bool:
        return False

    def seen(self, node_id: int, now: float) -> None:
        self.taken.add(node_id)
