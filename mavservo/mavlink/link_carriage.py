"""What the autopilot link carries: only messages that can arrive where they are meant to go.

The bridge's telemetry for ground stations goes out on its one MAVLink link. What happens to a
message there depends on what is at the other end (``mavlink.autopilot.link``):

* ``port``: the autopilot's own MAVLink port. The autopilot parses every frame and forwards to
  its other links (the GCS's) only what its parser knows (:mod:`.autopilot_flavour`): ArduPilot
  drops ESC_INFO (290), ESC_STATUS (291) and COMPONENT_METADATA (397), PX4 drops ArduPilot's
  ESC_TELEMETRY_x_TO_y (and counts each dropped frame as a sequence gap, "lost", for the
  bridge's component). Those are not sent: they cost the radio's budget and reach nobody.
  Until the followed autopilot's HEARTBEAT says which it is (``flavour: auto``) everything goes,
  as to a ground station on the link (a bench without an autopilot stays that way); on UDP the
  bridge sends nothing before it has heard its peer, whose first message is that HEARTBEAT, and
  ``flavour: px4`` / ``ardupilot`` holds the autopilot's unknown messages from the start.
* ``router``: mavlink-router, MAVProxy or a ground station directly: every message reaches the
  ground station, so everything goes, except ArduPilot's ESC_TELEMETRY when the autopilot is a
  PX4 (a router passes broadcasts to every endpoint, the autopilot too).

The monitor outputs (local tools) get every message. A REQUEST_MESSAGE for COMPONENT_METADATA
that cannot arrive is answered UNSUPPORTED, so a ground station falls back to the parameter list
at once instead of waiting for a reply ArduPilot drops. Pure: no I/O.
"""

from __future__ import annotations

from typing import Literal

from mavservo.mavlink.autopilot_flavour import (
    ESC_TELEMETRY_IDS,
    FACTS,
    MSG_COMPONENT_METADATA,
    MSG_ESC_INFO,
    MSG_ESC_STATUS,
    PX4,
    AutopilotFlavour,
    Flavour,
)

LinkKind = Literal["port", "router"]

#: The messages whose carriage depends on the path, by what ``check`` calls them.
PATH_DEPENDENT: dict[str, frozenset[int]] = {
    "ESC_TELEMETRY_x_TO_y": ESC_TELEMETRY_IDS,
    "ESC_INFO": frozenset({MSG_ESC_INFO}),
    "ESC_STATUS": frozenset({MSG_ESC_STATUS}),
    "COMPONENT_METADATA": frozenset({MSG_COMPONENT_METADATA}),
}
#: Budget stream names (:mod:`.bandwidth`) of the path-dependent periodic messages.
BUDGET_STREAMS = {
    "ESC_TELEMETRY": ESC_TELEMETRY_IDS,
    "ESC_INFO": frozenset({MSG_ESC_INFO}),
    "ESC_STATUS": frozenset({MSG_ESC_STATUS}),
}


def blocked_ids(link: LinkKind, flavour: Flavour | None) -> frozenset[int]:
    """Message ids not sent on the autopilot link for this path and autopilot."""
    if link == "router":
        return PX4.unknown_ids if flavour == "px4" else frozenset()
    if flavour is None:  # no autopilot heard (yet): nothing is known to be dropped
        return frozenset()
    return FACTS[flavour].unknown_ids


class LinkCarriage:
    """Whether a message sent on the autopilot link can arrive (for the flavour in force)."""

    def __init__(self, link: LinkKind, flavour: AutopilotFlavour) -> None:
        self.link = link
        self.flavour = flavour

    def carries(self, msg_id: int) -> bool:
        return msg_id not in blocked_ids(self.link, self.flavour.flavour)

    def held_names(self) -> list[str]:
        """The path-dependent messages not sent now, by name (for the log)."""
        blocked = blocked_ids(self.link, self.flavour.flavour)
        return [name for name, ids in PATH_DEPENDENT.items() if ids <= blocked]

    def left_out_streams(self) -> frozenset[str]:
        """The budget's periodic streams not sent on the link (not planned either)."""
        return left_out_streams(self.link, self.flavour.flavour)


def left_out_streams(link: LinkKind, flavour: Flavour | None) -> frozenset[str]:
    """The budget's periodic streams a link leaves out (for ``check``'s plan)."""
    blocked = blocked_ids(link, flavour)
    return frozenset(name for name, ids in BUDGET_STREAMS.items() if ids <= blocked)


def carriage_lines(link: LinkKind, configured: str) -> list[str]:
    """``check``'s account of what each link gets, for a config's ``link`` and ``flavour``."""
    where = (
        "a router or the ground station directly: everything arrives"
        if link == "router"
        else "the autopilot's own MAVLink port: it forwards only what it knows"
    )
    flavours: list[Flavour | None] = (
        ["ardupilot", "px4", None] if configured == "auto" else [configured]  # type: ignore[list-item]
    )
    lines = [f"autopilot link (mavlink.autopilot.link: {link}, {where}):"]
    for flavour in flavours:
        blocked = blocked_ids(link, flavour)
        sent = [name for name, ids in PATH_DEPENDENT.items() if not ids <= blocked]
        held = [name for name, ids in PATH_DEPENDENT.items() if ids <= blocked]
        who = "before its HEARTBEAT" if flavour is None else f"to {FACTS[flavour].name}"
        text = f"  {who}: sends {', '.join(sent) or 'none of them'}"
        if held:
            text += f"; not {', '.join(held)}" + (
                "" if flavour is None else f" ({FACTS[flavour].name} drops them)"
            )
        lines.append(text)
    lines.append("monitor outputs: every message")
    return lines
