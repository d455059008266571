"""Built-in hardware for tests, demos and CI: simulated CAN servos, a simulated CAN bus with real
frame times (and a foreign node flooding it), the same servos on a python-can ``virtual``
channel, an AA-55 USB-CAN adapter emulator on a pseudo-terminal (``mavservo sim``), and that
emulator in a child process for timing runs (:class:`SimulatorProcess`)."""

from __future__ import annotations

from typing import Any

from .adapter import AdapterEmulator, LineFaults
from .canbus import SimCanBus
from .servo import Faults, Physics, SimServo
from .virtual import VirtualServoBus


def __getattr__(name: str) -> Any:
    """``SimulatorProcess`` on first use: its module is also the child's ``python -m`` entry
    point, and importing it with the package made runpy warn in every child it started."""
    if name == "SimulatorProcess":
        from .child import SimulatorProcess

        return SimulatorProcess
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "AdapterEmulator",
    "Faults",
    "LineFaults",
    "Physics",
    "SimCanBus",
    "SimServo",
    "SimulatorProcess",
    "VirtualServoBus",
]
