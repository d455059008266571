"""Built-in hardware for tests, demos and CI: simulated CAN servos, a simulated CAN bus with real
frame times, the same servos on a python-can ``virtual`` channel, and an AA-55 USB-CAN adapter
emulator on a pseudo-terminal (``mavservo sim``)."""

from .adapter import AdapterEmulator, LineFaults
from .canbus import SimCanBus
from .servo import Faults, Physics, SimServo
from .virtual import VirtualServoBus

__all__ = [
    "AdapterEmulator",
    "Faults",
    "LineFaults",
    "Physics",
    "SimCanBus",
    "SimServo",
    "VirtualServoBus",
]
