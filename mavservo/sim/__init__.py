"""Built-in hardware for tests, demos and CI: simulated CAN servos, a simulated CAN bus with real
frame times (and a foreign node flooding it), the same servos on a python-can ``virtual``
channel, an AA-55 USB-CAN adapter emulator on a pseudo-terminal (``mavservo sim``), and that
emulator in a child process for timing runs (:class:`SimulatorProcess`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from mavservo.faces import lazy_face

from .adapter import AdapterEmulator, LineFaults
from .canbus import SimCanBus
from .servo import Faults, Physics, SimServo
from .virtual import VirtualServoBus

# The rest of the face, each name imported from its module on first use
# (:func:`mavservo.faces.lazy_face`): ``SimulatorProcess``'s module is also the child's
# ``python -m`` entry point, and importing it with the package made runpy warn in every child it
# started; the others are what the layer above uses (``tests/test_package_faces.py``).
if TYPE_CHECKING:
    from .autopilot.factory import simulator_for, simulator_from_config
    from .bus_simulation import simulated_can_port, simulator_factory
    from .child import SimulatorProcess
    from .pty_adapter import PtyAdapter

__all__ = [
    "simulator_for",
    "AdapterEmulator",
    "Faults",
    "LineFaults",
    "Physics",
    "PtyAdapter",
    "SimCanBus",
    "SimServo",
    "SimulatorProcess",
    "VirtualServoBus",
    "simulator_factory",
    "simulated_can_port",
    "simulator_from_config",
]
__getattr__ = lazy_face(
    __name__,
    {
        "simulator_for": "autopilot.factory",
        "PtyAdapter": "pty_adapter",
        "SimulatorProcess": "child",
        "simulator_factory": "bus_simulation",
        "simulated_can_port": "bus_simulation",
        "simulator_from_config": "autopilot.factory",
    },
)
