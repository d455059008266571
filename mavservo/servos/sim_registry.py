"""Where a built-in profile finds its simulated device without importing it.

A simulated device is written from the vendor's document, never from the profile's code (issue
27): a profile and its simulator import nothing of each other (import-linter contracts in
``pyproject.toml``). The profile's ``sim_device`` asks here by its name; the device is the
``device`` of its line in :data:`~mavservo.servos.registry.BUILT_IN`, imported on first use.
Plug-in profiles keep building their own device in ``sim_device``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import cast

from .base import ProfileOptions, ServoProfile, SimDevice, SimMotor
from .registry import BUILT_IN, import_built_in

SimDeviceFactory = Callable[[SimMotor, int, ProfileOptions], SimDevice]
"""``(motor, can_id, options) -> device``: options are the profile's validated options,
which a simulator reads as the device's configuration (``model_dump()``), never as types."""


def _factory(profile_name: str) -> SimDeviceFactory | None:
    built_in = BUILT_IN.get(profile_name)
    if built_in is None or built_in.device is None:
        return None
    return cast(SimDeviceFactory, import_built_in(built_in.device))


def simulated_device(
    profile: type[ServoProfile], motor: SimMotor, can_id: int, options: ProfileOptions
) -> SimDevice:
    """The registered device of a built-in profile on ``motor``; a subclass of a built-in (a
    plug-in that changes only its name or options) gets its base's device."""
    for cls in profile.__mro__:
        if issubclass(cls, ServoProfile):
            factory = _factory(cls.name)
            if factory is not None:
                return factory(motor, can_id, options)
    raise LookupError(f"no simulated device is registered for profile {profile.name!r}")


def link_simulated_devices(profile: type[ServoProfile], devices: Sequence[SimDevice]) -> None:
    """Let the simulated devices of a built-in family on one bus meet (its ``link`` function,
    :data:`~mavservo.servos.registry.BUILT_IN`); nothing when the family has none."""
    for cls in profile.__mro__:
        if issubclass(cls, ServoProfile):
            built_in = BUILT_IN.get(cls.name)
            if built_in is not None and built_in.link is not None:
                link = cast(Callable[[Sequence[SimDevice]], None], import_built_in(built_in.link))
                link(devices)
                return
