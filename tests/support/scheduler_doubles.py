"""What the scheduler's parts are driven with in tests, without their threads: a clock the test
moves and a bus that records what is written (or refuses it, as an unplugged adapter does)."""

from __future__ import annotations

import can


class Clock:
    """A monotonic clock the test sets (``now``, seconds)."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class RecordingBus(can.BusABC):
    """Keeps every frame written (``sent``), or refuses them all while ``refuse``; delivers
    nothing."""

    def __init__(self) -> None:
        self.sent: list[can.Message] = []
        self.refuse = False
        self.channel_info = "recording"
        super().__init__(channel="recording")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self.refuse:
            raise can.CanOperationError("adapter unplugged")
        self.sent.append(msg)

    def _recv_internal(self, timeout: float | None) -> tuple[None, bool]:
        return None, False
