"""The root of mavservo's own exceptions.

Why one root: a caller (the CLI, an integrator embedding the bridge) can tell "mavservo refused
this, with a reason for the user" from a bug with one ``except MavservoError``. Existing errors
(``ConfigError``, ``OverrideError``, ``ScheduleError``...) adopt it in a later step; this module
imports nothing, so every layer may use it.
"""

from __future__ import annotations


class MavservoError(Exception):
    """Something mavservo refused or could not do, with a message meant for the user."""
