"""What both of the scheduler's threads book into, and the one lock that guards it all.

The write side (:mod:`.sender`) and the receive side (:mod:`.receiver`) are separate parts, but
a reply answers what a write expected and a refused write takes a servo offline that a reply
brings back: the policy core, the metrics, the servos' latest states, the online log and the
bus nodes are one record of the bus, changed by both threads and read by the upper layers. It
is named here, once, so that what the two sides share is explicit and narrow (this, the
observers and the advice), and so that nobody touches any of it without ``lock``.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

from mavservo.records import SchedulerMetrics
from mavservo.servos import ServoState

from .bus_nodes import BusNodes
from .outage_log import OnlineLog
from .schedule_core import ScheduleCore


@dataclass(frozen=True)
class BusBook:
    """One bus's shared record; every field is read and changed under ``lock`` only."""

    lock: threading.Lock
    core: ScheduleCore
    metrics: SchedulerMetrics
    states: dict[str, ServoState]
    """The latest state of each servo heard (NO_REPLY added when it goes offline)."""
    online_log: OnlineLog
    nodes: BusNodes
