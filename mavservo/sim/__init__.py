"""Built-in hardware for tests, demos and CI: simulated CAN servos, a simulated CAN bus with real
frame times (and a foreign node flooding it), the same servos on a python-can ``virtual``
channel, an AA-55 USB-CAN adapter emulator on a pseudo-terminal (``mavservo sim``), and that
emulator in a child process for timing runs (:class:`SimulatorProcess`)."""

from .adapter import AdapterEmulator, LineFaults
from .canbus import SimCanBus
from .child import SimulatorProcess
from .servo import Faults, Physics, SimServo
from .virtual import VirtualServoBus

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
