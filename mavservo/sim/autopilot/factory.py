"""Build the simulator a ``sim`` MAVLink endpoint asks for, from ``simulation.autopilot``.

The bridge (``mavlink.url: sim``) calls :func:`simulator_for` with the validated
``simulation.autopilot`` section (:class:`~mavservo.config.schema.SimAutopilotConfig`, whose
defaults are the only ones) and the connection string the simulator should use to reach the
bridge; it gets back an object with ``start()``/``stop()``. :func:`simulator_from_config` takes
the same section as a plain mapping (tests, scripts) and validates it with the schema first.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal

from mavservo.config import GimbalTarget, SimAutopilotConfig, parse_script
from mavservo.sim.autopilot.can_forward import CanForwardLink
from mavservo.sim.autopilot.motion_scripts import Profile, RandomWalkProfile, get_profile
from mavservo.sim.autopilot.px4 import Px4Stream
from mavservo.sim.autopilot.replay import ReplayRunner
from mavservo.sim.autopilot.stream import AutopilotStream, gimbal_demo_script


def simulator_for(
    section: SimAutopilotConfig,
    url: str,
    *,
    repeat_servo_cycle: Literal["seconds", "milliseconds"] = "seconds",
    signing_key: bytes | None = None,
    actuator_output_status_hz: float = 0.0,
    can_forward: CanForwardLink | None = None,
) -> AutopilotStream | ReplayRunner:
    """An unstarted stream simulator (or tlog replayer) configured by ``section``; it reads
    DO_REPEAT_SERVO's cycle as ``repeat_servo_cycle`` (the bridge's ``mavlink`` setting) and
    signs with ``signing_key`` (the bridge's), PX4-style ACTUATOR_OUTPUT_STATUS at
    ``actuator_output_status_hz`` (0: off)."""
    if section.profile == "replay":
        if section.replay_file is None:  # the schema refuses it; a hand-built section too
            raise ValueError("profile 'replay' needs replay_file")
        return ReplayRunner(str(section.replay_file), url, speed=section.speed)
    profile: Profile
    if section.profile == "random-walk":
        profile = RandomWalkProfile(seed=section.seed)
    else:
        profile = get_profile(section.profile)
    events = list(parse_script(section.script).events)
    if section.gimbal and not any(isinstance(e.action, GimbalTarget) for e in events):
        events += gimbal_demo_script()
    # px4 (issue 39): PX4's onboard link, its own defaults
    simulator = Px4Stream if section.autopilot == "px4" else AutopilotStream
    return simulator(
        url,
        profile,
        events,
        servo_output_rate_hz=section.servo_output_rate_hz,
        actuator_output_status_hz=actuator_output_status_hz,
        gimbal=section.gimbal,
        command_target=section.command_target,
        repeat_servo_cycle=repeat_servo_cycle,
        signing_key=signing_key,
        can_forward=can_forward,  # a mavlink-can bus's simulated port
    )


def simulator_from_config(section: Mapping[str, Any], url: str) -> AutopilotStream | ReplayRunner:
    """:func:`simulator_for` a ``simulation.autopilot`` mapping, validated by the schema (a
    ValueError says what is wrong); ``repeat_servo_cycle``, ``signing_key`` and
    ``actuator_output_status_hz`` may ride along in it."""
    raw = dict(section)
    extras = {
        key: raw.pop(key)
        for key in ("repeat_servo_cycle", "signing_key", "actuator_output_status_hz")
        if key in raw
    }
    return simulator_for(SimAutopilotConfig.model_validate(raw), url, **extras)
