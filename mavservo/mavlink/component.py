"""What a pluggable hosted component (the gimbal device) must offer the MAVLink side.

The MAVLink side hosts several components on one link: the servo group (MAV_COMP_ID_SERVO1, 140)
and one component per gimbal (154, 171..175). A gimbal device is sans-I/O: it receives messages
and commands with the time as an argument and returns pymavlink message objects; the MAVLink side
sends them from the device's own component (own sequence numbers, own heartbeat).
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

#: MAV_TYPE_GIMBAL, advertised in the HEARTBEAT of gimbal components.
MAV_TYPE_GIMBAL = 26
#: MAV_TYPE_SERVO, advertised in the HEARTBEAT of the servo component.
MAV_TYPE_SERVO = 33


@runtime_checkable
class HostedComponent(Protocol):
    """The contract the gimbal device (``mavservo/mavlink/gimbal.py``) satisfies."""

    component_id: int

    def handle_message(self, msg: Any, now: float) -> None:
        """A message addressed to this component, or broadcast, that it may care about."""

    def handle_command(
        self,
        command: int,
        params: tuple[float, ...],
        now: float,
        *,
        sender: tuple[int, int] | None = None,
    ) -> int | None:
        """Handle a command from ``sender``; a MAV_RESULT, or None when it is not for it."""

    def handles_command(self, command: int) -> bool:
        """Whether :meth:`handle_command` acts on ``command`` at all (whatever its params): a
        broadcast of any other command is not this component's to answer."""

    def periodic(self, now: float) -> list[Any]:
        """Messages due at ``now`` (attitude status at its rate, ...), sent from its component."""

    def requested_message(self, msg_id: int, now: float) -> Any | None:
        """The message answering MAV_CMD_REQUEST_MESSAGE(msg_id), or None if not published."""


@runtime_checkable
class CountingComponent(Protocol):
    """A hosted component that counts what it refused (the gimbal device's ``GimbalCounters``):
    the MAVLink core puts the counts in its stats, so they reach the summary and metrics.json."""

    def counter_values(self) -> dict[str, int]:
        """Each counter by name."""
        ...


@runtime_checkable
class DemandHolder(Protocol):
    """A hosted component that holds a demand of the autopilot's (the gimbal device): the
    MAVLink core makes it forget the demand when the autopilot is lost or restarts."""

    def forget_demand(self) -> None:
        """The autopilot that gave the demand is gone: drop it, drive nothing until a new one."""
        ...
