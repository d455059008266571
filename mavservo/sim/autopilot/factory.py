"""Build the simulator a ``sim`` MAVLink endpoint asks for, from ``simulation.autopilot``.

The bridge (``mavlink.url: sim``) calls :func:`simulator_from_config` with the validated
``simulation.autopilot`` section (a pydantic model or a plain mapping) and the connection string
the simulator should use to reach the bridge; it gets back an object with ``start()``/``stop()``.
Keys understood: ``profile`` (a :mod:`mavservo.sim.autopilot.motion_scripts` name or ``replay``),
``servo_output_rate_hz``,
``actuator_output_status_hz`` (PX4-style, 0 = off),
``replay_file``, ``speed``, ``seed``, ``script`` (list of events, see
:mod:`mavservo.config.autopilot_script`),
``gimbal``, ``command_target``, ``repeat_servo_cycle``. Unknown keys are ignored so the config
may grow ahead of the simulator.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from mavservo.config.autopilot_script import GimbalTarget, parse_script
from mavservo.sim.autopilot.motion_scripts import Profile, RandomWalkProfile, get_profile
from mavservo.sim.autopilot.replay import ReplayRunner
from mavservo.sim.autopilot.stream import AutopilotStream, gimbal_demo_script


def _as_dict(section: Any) -> dict[str, Any]:
    if section is None:
        return {}
    if hasattr(section, "model_dump"):
        return dict(section.model_dump())
    if isinstance(section, Mapping):
        return dict(section)
    raise TypeError(f"simulation.autopilot must be a mapping, got {type(section).__name__}")


def simulator_from_config(section: Any, url: str) -> AutopilotStream | ReplayRunner:
    """An unstarted stream simulator (or tlog replayer) configured by ``section``."""
    cfg = _as_dict(section)
    profile_name = str(cfg.get("profile", "sweep"))
    if profile_name == "replay":
        if not cfg.get("replay_file"):
            raise ValueError("profile 'replay' needs replay_file")
        return ReplayRunner(cfg["replay_file"], url, speed=float(cfg.get("speed", 1.0)))
    profile: Profile
    if profile_name == "random-walk":
        profile = RandomWalkProfile(seed=int(cfg.get("seed", 0)))
    else:
        profile = get_profile(profile_name)
    events = list(parse_script(cfg.get("script") or []).events)
    gimbal = bool(cfg.get("gimbal", False))
    if gimbal and not any(isinstance(e.action, GimbalTarget) for e in events):
        events += gimbal_demo_script()
    target = cfg.get("command_target", (1, 0))
    return AutopilotStream(
        url,
        profile,
        events,
        servo_output_rate_hz=float(cfg.get("servo_output_rate_hz", 20.0)),
        actuator_output_status_hz=float(cfg.get("actuator_output_status_hz", 0.0)),
        gimbal=gimbal,
        command_target=(int(target[0]), int(target[1])),
        repeat_servo_cycle=str(cfg.get("repeat_servo_cycle", "seconds")),
        signing_key=cfg.get("signing_key"),
    )
