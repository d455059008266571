"""Where a built-in profile finds its simulated device without importing it.

A simulated device is written from the vendor's document, never from the profile's code (issue
27): a profile and its simulator import nothing of each other (import-linter contracts in
``pyproject.toml``). The profile's ``sim_device`` asks this table by its name;
:mod:`mavservo.servos.simulators`, imported by the package, fills it with every built-in
family's device. Plug-in profiles keep building their own device in ``sim_device``.
"""

from __future__ import annotations

from collections.abc import Callable

from .base import ProfileOptions, ServoProfile, SimDevice, SimMotor

SimDeviceFactory = Callable[[SimMotor, int, ProfileOptions], SimDevice]
"""``(motor, can_id, options) -> device``: options are the profile's validated options,
which a simulator reads as the device's configuration (``model_dump()``), never as types."""

_FACTORIES: dict[str, SimDeviceFactory] = {}


def register(profile_name: str, factory: SimDeviceFactory) -> None:
    """Make ``factory`` the simulated device of the profile named ``profile_name``."""
    _FACTORIES[profile_name] = factory


def simulated_device(
    profile: type[ServoProfile], motor: SimMotor, can_id: int, options: ProfileOptions
) -> SimDevice:
    """The registered device of a built-in profile on ``motor``; a subclass of a built-in (a
    plug-in that changes only its name or options) gets its base's device."""
    for cls in profile.__mro__:
        if issubclass(cls, ServoProfile) and cls.name in _FACTORIES:
            return _FACTORIES[cls.name](motor, can_id, options)
    raise LookupError(f"no simulated device is registered for profile {profile.name!r}")
