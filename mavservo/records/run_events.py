"""What the run log's callers hand its writer thread: small tuples tagged with an event code.

The vocabulary between the two sides of the run log's queue: :class:`~.runlog.RunLog` builds
these on the scheduler's and the link's threads (small ints and tuples are the cheapest thing
to build there), :class:`~.run_files.RunFiles` turns them into file records on the writer
thread, and both count them per category (``metrics.json``'s ``written``/``dropped``).
"""

from __future__ import annotations

from typing import Any

import can

#: An event on the queue: its code first, then the code's fields.
Event = tuple[Any, ...]

(TX, RX, SETPOINT, LOST, REJECT, MAV_IN, MAV_OUT, LATENCY, HEALTH, BUS_RX, STATE) = range(11)

#: the counter category of each event code
CATEGORY = {
    TX: "can",
    RX: "can",
    BUS_RX: "can",
    STATE: "trace",
    SETPOINT: "trace",
    LOST: "trace",
    REJECT: "rejections",
    MAV_IN: "mavlink",
    MAV_OUT: "mavlink",
    LATENCY: "latency",
    HEALTH: "trace",
}


def frame_fields(msg: can.Message) -> tuple[int, bool, bool, int, bytes]:
    """What the CAN logs keep of a frame, copied (the caller may reuse its message)."""
    return (msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame, msg.dlc, bytes(msg.data))
