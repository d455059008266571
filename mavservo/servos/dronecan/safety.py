"""The bridge node's ``ardupilot.indication.SafetyState`` broadcast on one bus: its plan, its
cadence, and the warning when ArduPilot peripherals will hear none.

ArduPilot peripherals (AP_Periph) keep their outputs off until they hear SAFETY_OFF, and obey
the last SafetyState they hear; ArduPilot's flight controller sends it every 500 ms
(``AP_DroneCAN``, its 2 Hz safety broadcast). Whether the bridge sends it at all, when it turns
safety back on (at stop, in failsafe) and what ``check`` says about it is one job with its own
state (when it is next due, what it last said, whether the bus is in failsafe, its own transfer
ids), apart from the node's other traffic; :class:`.node.BridgeNode` owns one and asks it for
frames. Pure: no clock, no I/O; times are handed in.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from typing import Literal

import can

from . import wire
from .notices import Notices

SAFETY_PERIOD_S = 0.5
"""``ardupilot.indication.SafetyState`` every 500 ms, as ArduPilot's flight controller sends it
(``AP_DroneCAN``, its 2 Hz safety broadcast); a peripheral that hears nothing keeps its state."""

SafetyOn = Literal["stop", "failsafe_and_stop", "never"]


class SafetyBroadcast:
    """The SafetyState plan of one bus: SAFETY_OFF every :data:`SAFETY_PERIOD_S` from start
    (``safety_off``), or nothing (the peripherals keep their outputs off, and the crew is told
    when ArduPilot nodes are configured)."""

    def __init__(
        self,
        node_id: int,
        safety_off: bool,
        safety_on: SafetyOn,
        ardupilot_nodes: Sequence[int],
        start: float,
        counters: Counter[str],
        notices: Notices,
    ) -> None:
        self.node_id = node_id
        self.safety_off = safety_off
        """The plan: broadcast at all (SAFETY_OFF from start)."""
        self.safety_on = safety_on
        self.ardupilot_nodes = list(ardupilot_nodes)
        self._counters = counters
        self._notices = notices
        self._next = start
        self._sent: bool | None = None
        self._failsafe = False
        self._transfer_id = 0
        self._warning_due = bool(self.ardupilot_nodes and not safety_off)
        """Say it again with the first command: a ground station that connects after the
        start never heard the start's text, and the first command is when it matters."""
        if self._warning_due:
            notices.add(self.warning())

    @property
    def turns_on_at_stop(self) -> bool:
        """The plan sends SAFETY_ON once as the bridge stops (:meth:`at_stop`)."""
        return self.safety_off and self.safety_on != "never"

    def failsafe(self, in_failsafe: bool) -> None:
        """Every command of the slot just packed was a failsafe setpoint (or none was)."""
        self._failsafe = in_failsafe and self.safety_on == "failsafe_and_stop"

    def ardupilot_commanded(self) -> None:
        """A servo on ArduPilot firmware is commanded: the warning again, the first time."""
        if self._warning_due:
            self._warning_due = False
            self._notices.add(self.warning())

    def next_due(self) -> float | None:
        """When :meth:`due` next has a frame (None: the plan sends none)."""
        return self._next if self.safety_off else None

    def due(self, now: float) -> list[can.Message]:
        """SafetyState every 500 ms (at once when it changes): SAFETY_OFF, or SAFETY_ON while
        the plan says failsafe and every commanded servo is in failsafe."""
        if not self.safety_off:
            return []
        off = not self._failsafe
        if now < self._next and off == self._sent:
            return []
        self._next = now + SAFETY_PERIOD_S
        return self._frames(off)

    def at_stop(self) -> list[can.Message]:
        """SAFETY_ON once as the bridge stops (the plan's ``stop``): outputs off."""
        return self._frames(False)

    def _frames(self, off: bool) -> list[can.Message]:
        self._sent = off
        self._counters["safety_off" if off else "safety_on"] += 1
        tid, self._transfer_id = self._transfer_id, (self._transfer_id + 1) & 0x1F
        return wire.encode_message(wire.safety_state(off), self.node_id, tid, wire.PRIORITY_LOW)

    def warning(self) -> str:
        nodes = ", ".join(map(str, self.ardupilot_nodes))
        return (
            f"DroneCAN nodes {nodes} run ArduPilot firmware, which keeps its outputs off until "
            "it hears SafetyState SAFETY_OFF, and the bridge sends none (safety_state: none): "
            "their servos will not move; set node.dronecan.safety_state: safety_off"
        )

    def plan(self) -> str:
        """The SafetyState plan, as ``check`` prints it."""
        if not self.safety_off:
            return (
                "SafetyState: not sent (safety_state: none): ArduPilot peripherals (AP_Periph) "
                "keep their outputs off; other DroneCAN servos do not care"
            )
        on = {
            "stop": "SAFETY_ON when the bridge stops",
            "failsafe_and_stop": "SAFETY_ON while every servo of the bus is in failsafe and "
            "when the bridge stops",
            "never": "never SAFETY_ON (outputs stay enabled after the bridge stops; "
            "ArduPilot peripherals still zero them 200 ms after the last command)",
        }[self.safety_on]
        return (
            f"SafetyState: SAFETY_OFF every {SAFETY_PERIOD_S * 1000:g} ms from start (as "
            f"ArduPilot's flight controller); {on}"
        )
