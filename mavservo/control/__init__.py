"""MAVLink units <-> servo angles: the channel mapping (reverse, trim, limits, slew) and the
servo backend that turns the MAVLink side's commands into scheduler setpoints and the scheduler's
servo state back into what the MAVLink side publishes."""

from __future__ import annotations

from typing import TYPE_CHECKING

from mavservo.faces import lazy_face

# The face: what the other layers use from this package (``tests/test_package_faces.py``), each
# name imported from its module on first use (:func:`mavservo.faces.lazy_face`); the modules'
# other names are the package's own business.
if TYPE_CHECKING:
    from .config_targets import ConfigTargets
    from .health import HealthEvent
    from .health_thresholds import describe_limits, health_limits, servo_limits
    from .health_watch import HealthWatch
    from .live_parameters import LiveParameters
    from .mapping import ChannelMap, Rejected
    from .overlay_saver import OverlaySaver
    from .servo_backend import ServoBackend

__all__ = [
    "ChannelMap",
    "ConfigTargets",
    "HealthEvent",
    "HealthWatch",
    "LiveParameters",
    "OverlaySaver",
    "Rejected",
    "ServoBackend",
    "describe_limits",
    "health_limits",
    "servo_limits",
]
__getattr__ = lazy_face(
    __name__,
    {
        "ChannelMap": "mapping",
        "ConfigTargets": "config_targets",
        "HealthEvent": "health",
        "HealthWatch": "health_watch",
        "LiveParameters": "live_parameters",
        "OverlaySaver": "overlay_saver",
        "Rejected": "mapping",
        "ServoBackend": "servo_backend",
        "describe_limits": "health_thresholds",
        "health_limits": "health_thresholds",
        "servo_limits": "health_thresholds",
    },
)
