"""``mavservo check``'s account of what each MAVLink link gets (px4: issue 38 item 5, issue 39).

Which telemetry the autopilot link carries depends on the autopilot and on what the link leads
to (``mavlink.autopilot.flavour`` and ``.link``; :mod:`mavservo.mavlink.link_carriage`): the
lines say, per autopilot the config may meet, which of ESC_TELEMETRY_x_TO_y, ESC_INFO,
ESC_STATUS and COMPONENT_METADATA go and which are held because that autopilot would drop them,
and what a fixed flavour takes out of the link budget's plan. A module of its own so ``check``
calls it with one line.
"""

from __future__ import annotations

from mavservo.config import Config
from mavservo.mavlink import carriage_lines, left_out_streams


def link_lines(config: Config) -> list[str]:
    """The "what each link gets" section of ``check`` (a blank line and a heading first)."""
    autopilot = config.mavlink.autopilot
    lines = ["", f"what each link gets (autopilot: {autopilot.flavour}):"]
    lines += ["  " + line for line in carriage_lines(autopilot.link, autopilot.flavour)]
    return lines


def left_out(config: Config) -> frozenset[str]:
    """The periodic streams the budget need not plan: those the configured autopilot drops
    (none with ``flavour: auto``: the plan is the worst case until the autopilot is heard)."""
    autopilot = config.mavlink.autopilot
    if autopilot.flavour == "auto":
        return frozenset()
    return left_out_streams(autopilot.link, autopilot.flavour)
