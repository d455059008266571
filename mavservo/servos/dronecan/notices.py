"""What the bridge's DroneCAN node has to tell the crew, kept until the scheduler takes it.

The node's parts (the SafetyState broadcast, the watch on other nodes sharing the bus, the
watch on actuators that stop reporting) each find things worth a log line and a STATUSTEXT;
they write them here, in the order they happen, and :meth:`BridgeNode.take_notices
<.node.BridgeNode.take_notices>` hands them on. A kind said once (a flood of one kind of
request) is said once for the node, whichever part says it.
"""

from __future__ import annotations


class Notices:
    """Texts in the order they were said; ``once`` kinds at most one text each."""

    __slots__ = ("_kinds", "_texts")

    def __init__(self) -> None:
        self._texts: list[str] = []
        self._kinds: set[str] = set()

    def add(self, text: str) -> None:
        self._texts.append(text)

    def once(self, kind: str, text: str) -> None:
        """``text`` the first time something of ``kind`` happens (its count goes on)."""
        if kind not in self._kinds:
            self._kinds.add(kind)
            self._texts.append(text)

    def take(self) -> list[str]:
        """Every text said since the last call, oldest first."""
        texts, self._texts = self._texts, []
        return texts
