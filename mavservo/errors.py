"""The root of mavservo's own exceptions, and the typed start-up failures.

Why one root: a caller (the CLI, an integrator embedding the bridge) can tell "mavservo refused
this, with a reason for the user" from a bug with one ``except MavservoError``: the first gets
one clear line, the second a traceback. Errors that must also honour another contract keep that
base too (``LinkBusyError`` is an ``OSError``; the AA-55 adapter's open failures are python-can's
``CanInitializationError``, which ``can.Bus()`` callers expect). This module imports nothing, so
every layer may use it.
"""

from __future__ import annotations


class MavservoError(Exception):
    """Something mavservo refused or could not do, with a message meant for the user."""


class StartupError(MavservoError):
    """The bridge could not start (nothing is left running); the message names the cause."""


class EndpointBusyError(StartupError):
    """A port mavservo needs (a UDP port, a serial adapter) is held by another process."""


class DeviceMissingError(StartupError):
    """A device named in the configuration (a serial adapter) is not there."""
