"""Every registered profile, plug-ins installed at test time included, held to the contract of
``docs/profiles.md``: option defaults valid, round trips through its own simulated device,
``identifiers()`` consistent with what it sends and accepts, lifecycle frames accepted.

Run it in an environment with a plug-in installed and the plug-in is checked too (the worked
example's test does exactly that, tests/servos/test_plugin_example.py).
"""

from __future__ import annotations

import math

import can
import pytest

from mavservo.servos import ServoProfile, registry, release_frames_of
from mavservo.servos.base import FrameId, ProfileOptions
from mavservo.sim.servo import SimServo

NAMES = registry.names()


def _ids(cls: type[ServoProfile]) -> list[int]:
    """The ends of the id range and one in the middle."""
    return sorted({cls.min_id, (cls.min_id + cls.max_id) // 2, cls.max_id})


def _claimed_by(frame: can.Message, ids: tuple[FrameId, ...], direction: str) -> bool:
    return any(i.direction == direction and i.matches(frame) for i in ids)


def _started(name: str, can_id: int) -> tuple[ServoProfile, SimServo]:
    """A profile and its simulated servo after the start-up frames went out, again while the
    profile asks for them, as the scheduler does (Robstride enables in a second step)."""
    profile = registry.get_profile(name)(can_id)
    sim = SimServo(name, can_id, seed=1, reply_latency_s=0.0)
    for _ in range(3):
        for frame in profile.startup_frames():
            for _, reply in sim.receive(frame, 0.0):
                profile.decode(reply, 0.0)
        if not profile.needs_startup():
            break
    return profile, sim


def _state_after(profile: ServoProfile, sim: SimServo, now: float) -> list[can.Message]:
    """The telemetry the servo gives at ``now``: the answers to a poll, or its pushes."""
    replies = [
        reply for request in profile.telemetry_requests() for _, reply in sim.receive(request, now)
    ]
    if profile.telemetry == "pushed":
        sim.poll(now - 0.1)
        replies += [reply for _, reply in sim.poll(now)]
    return replies


@pytest.mark.parametrize("name", NAMES)
def test_declares_itself(name: str) -> None:
    cls = registry.get_profile(name)
    assert cls.name == name
    assert cls.telemetry in ("polled", "pushed")
    assert issubclass(cls.Options, ProfileOptions)
    defaults = cls.Options()
    assert cls.Options.model_validate(defaults.model_dump()) == defaults, "defaults are valid"
    assert cls.min_id <= cls.max_id
    with pytest.raises(ValueError):
        cls(cls.max_id + 1)
    # the scheduler's liveness rule follows the shape: polled servos are asked, pushed ones not
    polled = bool(cls(cls.min_id).telemetry_requests())
    assert polled == (cls.telemetry == "polled"), f"{name}: telemetry shape and requests disagree"


@pytest.mark.parametrize("name", NAMES)
def test_identifiers_cover_every_frame_it_sends(name: str) -> None:
    cls = registry.get_profile(name)
    for can_id in _ids(cls):
        profile = cls(can_id)
        ids = profile.identifiers()
        assert any(i.direction == "to_servo" for i in ids)
        assert any(i.direction == "from_servo" for i in ids)
        sent = [
            profile.position_command(0.0),
            profile.position_command(0.0, 90.0),
            *profile.telemetry_requests(),
            *profile.startup_frames(),
            *release_frames_of(profile),
            *profile.shutdown_frames(),
        ]
        for frame in sent:
            assert _claimed_by(frame, ids, "to_servo"), f"{name} {can_id}: {frame} not declared"


@pytest.mark.parametrize("name", NAMES)
def test_its_device_answers_its_frames_and_it_accepts_every_answer(name: str) -> None:
    cls = registry.get_profile(name)
    for can_id in _ids(cls):
        profile, sim = _started(name, can_id)
        ids = profile.identifiers()
        replies = [reply for _, reply in sim.receive(profile.position_command(10.0, 90.0), 0.0)]
        replies += _state_after(profile, sim, 0.2)
        assert replies, f"{name} {can_id}: the simulated device never answered"
        for reply in replies:
            assert profile.is_reply(reply), f"{name} {can_id}: its own device's {reply}"
            assert _claimed_by(reply, ids, "from_servo"), f"{name} {can_id}: {reply} undeclared"
            assert profile.decode(reply, 0.2) is not None


@pytest.mark.parametrize("name", NAMES)
def test_round_trip_through_its_simulated_device(name: str) -> None:
    cls = registry.get_profile(name)
    profile, sim = _started(name, cls.min_id)
    target = 30.0
    sim.receive(profile.position_command(target, 180.0), 0.0)
    states = [profile.decode(reply, 3.0) for reply in _state_after(profile, sim, 3.0)]
    positions = [s.position_deg for s in states if s is not None and not math.isnan(s.position_deg)]
    assert positions, f"{name}: no position came back"
    assert positions[-1] == pytest.approx(target, abs=cls.resolution_deg + 0.5)
    assert sim.position_deg == pytest.approx(target, abs=0.5)


@pytest.mark.parametrize("name", NAMES)
def test_lifecycle_frames_are_accepted_and_release_turns_the_motor_off(name: str) -> None:
    cls = registry.get_profile(name)
    profile, sim = _started(name, cls.min_id)
    assert sim.enabled, f"{name}: the motor is on after the start-up frames"
    for frame in profile.startup_frames():
        replies = sim.receive(frame, 0.1)
        assert len(replies) == profile.replies_per_lifecycle, f"{name}: replies to {frame}"
        for _, reply in replies:
            assert profile.decode(reply, 0.1) is not None
    if release_frames_of(profile):
        for frame in release_frames_of(profile):
            assert len(sim.receive(frame, 0.2)) == profile.replies_per_lifecycle
        assert not sim.enabled, f"{name}: release frames leave the motor off"
    for frame in profile.shutdown_frames():
        assert len(sim.receive(frame, 0.3)) == profile.replies_per_lifecycle
