"""How the bridge shows itself on the vehicle, said at start and again whenever it changes.

One line: the servo component, the ESC numbers the servos are published as, the
NAMED_VALUE_FLOAT prefix and the autopilot link's budget. A second bridge, or the autopilot's
own ESCs, must not look the same; the ESC numbers move when another component publishes the
same ones (issue 30), so the console, the event list and the summary say the numbers sent now,
not those of the start.

Why a part of its own: it has its own state (the line shown last) and one job, checked each
bridge tick; the bridge only asks for the line it shows.
"""

from __future__ import annotations

from mavservo.app.bridge_events import BridgeEvents
from mavservo.mavlink import MavlinkSide


class BridgeIdentity:
    """The identity line of ``side`` for ``servos`` servos, noted in ``notes`` when it changes."""

    def __init__(self, side: MavlinkSide, *, servos: int, notes: BridgeEvents) -> None:
        self._core = side.core
        self._servos = servos
        self._notes = notes
        #: the line said last (the summary's ``identity``)
        self.shown: str | None = None

    def line(self) -> str:
        core = self._core
        first = core.telemetry.esc_first
        plan = core.budget.plan
        budget = (
            "no link budget"
            if plan.budget_bytes_s is None
            else f"autopilot link {plan.link_bytes_s:,.0f} of {plan.budget_bytes_s:,.0f} B/s"
        )
        return (
            f"MAVLink: servo component {core.settings.servo_component_id}, servos as ESC "
            f"{first}-{first + self._servos - 1}, names {core.telemetry.name_prefix}1_*, {budget}"
        )

    def note_change(self) -> None:
        """Say the line when it differs from the one said last (the first call says it)."""
        line = self.line()
        if line != self.shown:
            self.shown = line
            self._notes.note(line)
