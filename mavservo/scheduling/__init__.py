"""Who gets the bus when: the pure policy core (``schedule_core`` with its parts ``bus_plan``,
``lifecycle``, ``poll_round``, ``liveness``, ``owed_replies``, ``reply_matching``), the scheduler
that owns the only writer to the bus (``runner`` with its write side ``sender``, receive side
``receiver``, their shared ``bus_book``, ``pacing``, ``observers``, ``advice``, ``bus_nodes``),
the bus-load arithmetic (paper eq. 4) and the servo outage log."""

from __future__ import annotations

from typing import TYPE_CHECKING

from mavservo.faces import lazy_face

# The face: what the other layers use from this package (``tests/test_package_faces.py``), each
# name imported from its module on first use (:func:`mavservo.faces.lazy_face`); the modules'
# other names are the package's own business.
if TYPE_CHECKING:
    from .bus_nodes import family_nodes, node_unique_id, software_version
    from .busload import (
        FrameFlow,
        ServoTraffic,
        frame_time,
        load_ratio,
        message_bits,
        servo_traffic,
    )
    from .lifecycle import STARTUP_RETRY_S
    from .observers import SchedulerObserver, WriteObserver
    from .runner import Scheduler
    from .schedule_core import FrameKind, ServoSpec, SetpointResult, TimingConfig

__all__ = [
    "family_nodes",
    "FrameFlow",
    "ServoTraffic",
    "FrameKind",
    "STARTUP_RETRY_S",
    "Scheduler",
    "SchedulerObserver",
    "ServoSpec",
    "SetpointResult",
    "TimingConfig",
    "WriteObserver",
    "frame_time",
    "load_ratio",
    "message_bits",
    "node_unique_id",
    "servo_traffic",
    "software_version",
]
__getattr__ = lazy_face(
    __name__,
    {
        "family_nodes": "bus_nodes",
        "FrameFlow": "busload",
        "ServoTraffic": "busload",
        "FrameKind": "schedule_core",
        "STARTUP_RETRY_S": "lifecycle",
        "Scheduler": "runner",
        "SchedulerObserver": "observers",
        "ServoSpec": "schedule_core",
        "SetpointResult": "schedule_core",
        "TimingConfig": "schedule_core",
        "WriteObserver": "observers",
        "frame_time": "busload",
        "load_ratio": "busload",
        "message_bits": "busload",
        "node_unique_id": "bus_nodes",
        "servo_traffic": "busload",
        "software_version": "bus_nodes",
    },
)
