"""What a normal stop says about each servo: one INFO line each, what it does and when.

Why: every normal end of a run printed WARNINGs ("then on their own: aileron, elevator, ...:
holds its last target; with comm_timeout_ms set (0xB3, V4 firmware) it turns its motor off
that long after the last frame"): a routine stop read as an alarm, and the line named the
setting instead of its value (issue 37). Now each servo gets one line with its family's
documented behaviour and its own configured timeout (``ServoProfile.stop_behaviour``)::

    after the stop: servo aileron (rmd-x) holds its last target; motor off 1 s after the last
    frame (comm_timeout_ms; firmware before V4 holds on)

The console shows them at INFO (:data:`PREFIX` is one of its normal-step words).
"""

from __future__ import annotations

from mavservo.config import Config

PREFIX = "after the stop: "


def servo_stop_lines(config: Config) -> list[str]:
    """One line per servo, in config order."""
    return [
        f"{PREFIX}servo {servo.name} ({servo.profile}) {servo.make_profile().stop_behaviour()}"
        for servo in config.servos
    ]
