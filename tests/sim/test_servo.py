"""Simulated servos and the simulated CAN bus, in simulated time (no clock, no threads)."""

from __future__ import annotations

from itertools import pairwise

import can
import pytest

from mavservo.scheduling.busload import frame_time
from mavservo.servos import CubeMarsAK, Fault, RmdX
from mavservo.sim.canbus import SimCanBus
from mavservo.sim.servo import Faults, Physics, SimServo


def _run(servo: SimServo, until: float, start: float = 0.0, step: float = 0.01) -> list[float]:
    """Advance in ``step`` increments, returning the velocity seen at each step."""
    velocities = []
    t = start
    while t < until - 1e-12:
        t = min(until, t + step)
        servo.advance(t)
        velocities.append(servo.velocity_dps)
    return velocities


def test_position_loop_converges_within_speed_and_acceleration_limits():
    physics = Physics(max_speed_dps=300, max_accel_dps2=2000)
    servo = SimServo("rmd-x", 1, physics)
    servo.advance(0.0)
    servo.receive(RmdX(1).position_command(120.0, 200), 0.0)
    velocities = _run(servo, 3.0, step=0.001)
    assert servo.position_deg == pytest.approx(120.0, abs=0.01)
    assert max(abs(v) for v in velocities) <= 200 + 1e-6
    accelerations = [abs(b - a) / 0.001 for a, b in pairwise(velocities)]
    assert max(accelerations) <= 2000 * 1.001


def test_current_follows_acceleration_and_load_and_heats_the_winding():
    physics = Physics(load_current=3.0, current_noise_a=0.0, heating_c_per_a2s=0.5)
    servo = SimServo("rmd-x", 1, physics)
    servo.advance(0.0)
    servo.receive(RmdX(1).position_command(300.0, 600), 0.0)
    servo.advance(0.05)  # accelerating
    accelerating = servo.current_a
    servo.advance(3.0)  # settled, holding the load
    holding = servo.current_a
    assert accelerating > holding
    assert holding == pytest.approx(3.0, abs=0.2)
    assert servo.temperature_c > physics.ambient_c + 1.0
    warm = servo.temperature_c
    servo.physics.load_current = 0.0
    servo.advance(60.0)
    assert servo.temperature_c < warm  # cools once the load is gone


def test_servo_without_commands_relaxes_and_a_refresh_prevents_it():
    physics = Physics(relax_after_s=0.5, relax_rate_dps=10.0, relax_rest_deg=0.0)
    limp = SimServo("rmd-x", 1, physics)
    held = SimServo("rmd-x", 2, Physics(relax_after_s=0.5, relax_rate_dps=10.0))
    command = {1: RmdX(1).position_command(40.0), 2: RmdX(2).position_command(40.0)}
    for servo in (limp, held):
        servo.advance(0.0)
        servo.receive(command[servo.can_id], 0.0)
    t = 0.0
    for _ in range(40):  # 4 s, the held servo refreshed every 100 ms
        t += 0.1
        limp.advance(t)
        held.receive(command[2], t)
    assert limp.relaxed and not held.relaxed
    assert held.position_deg == pytest.approx(40.0, abs=0.01)
    assert limp.position_deg < 40.0 - 10.0  # drifted toward rest at about 10 dps


def test_rmd_status_reply_carries_whole_degrees_multi_turn_hundredths():
    servo = SimServo("rmd-x", 1)
    servo.position_deg = servo.target_deg = 90.4
    profile = RmdX(1, multi_turn_poll_every=2, fault_poll_every=None)
    [(_, coarse)] = servo.receive(profile.telemetry_requests()[0], 0.0)
    assert RmdX(1).decode(coarse, 0.0).position_deg == 90.0
    profile.poll_sent()  # the first poll went out: the second asks for the multi-turn angle
    [(_, fine)] = servo.receive(profile.telemetry_requests()[0], 0.0)
    assert RmdX(1).decode(fine, 0.0).position_deg == pytest.approx(90.4)


def test_dropped_replies_follow_the_probability_and_the_seed():
    def replies(seed: int) -> list[bool]:
        servo = SimServo("rmd-x", 1, faults=Faults(drop_reply_prob=0.5), seed=seed)
        request = RmdX(1).telemetry_requests()[0]
        return [bool(servo.receive(request, i * 0.01)) for i in range(200)]

    first = replies(1)
    assert first == replies(1)
    assert 40 < sum(first) < 160  # about half answered
    assert first != replies(2)


def test_delay_silence_and_fault_flags_are_visible_in_replies():
    request = RmdX(1).telemetry_requests()[0]
    slow = SimServo("rmd-x", 1, faults=Faults(reply_delay_s=0.25), reply_latency_s=0.0)
    [(due, _)] = slow.receive(request, 1.0)
    assert due == pytest.approx(1.25)

    mute = SimServo("rmd-x", 1, faults=Faults(silent=True))
    assert mute.receive(request, 0.0) == []
    mute.receive(RmdX(1).position_command(10.0), 0.0)
    mute.advance(2.0)
    assert mute.position_deg == pytest.approx(10.0, abs=0.01)  # still obeys

    hot = SimServo("rmd-x", 1, faults=Faults(over_current=True, over_temperature=True))
    status_1 = RmdX(1, fault_poll_every=1)
    [(_, reply)] = hot.receive(status_1.telemetry_requests()[0], 0.0)
    assert status_1.decode(reply, 0.0).faults == Fault.OVER_CURRENT | Fault.OVER_TEMPERATURE

    cube = SimServo("cubemars-ak", 4, faults=Faults(over_temperature=True))
    [(_, status)] = cube.receive(CubeMarsAK(4).position_command(5.0), 0.0)
    assert CubeMarsAK(4).decode(status, 0.0).faults == Fault.OVER_TEMPERATURE


def test_physics_trips_over_temperature_by_itself():
    servo = SimServo("rmd-x", 1, Physics(load_current=8.0, heating_c_per_a2s=1.0))
    servo.advance(0.0)
    servo.receive(RmdX(1).position_command(0.0), 0.0)
    assert servo.active_faults == Fault(0)
    servo.advance(20.0)
    assert Fault.OVER_TEMPERATURE in servo.active_faults


def test_faults_and_physics_build_from_yaml_mappings():
    assert Faults.from_dict({"silent": True}).silent
    assert Physics.from_dict({"relax_after_s": 2}).relax_after_s == 2
    with pytest.raises(ValueError, match="drop_prob"):
        Faults.from_dict({"drop_prob": 0.1})


def test_cubemars_pushes_status_at_its_rate():
    servo = SimServo("cubemars-ak", 2, status_rate_hz=50)
    bus = SimCanBus([servo])
    received = []
    for step in range(1, 101):  # 1 s in 10 ms steps
        received += bus.run_until(step * 0.01)
    assert 45 <= len(received) <= 50
    assert all(msg.arbitration_id == 0x2902 for _, msg in received)


def test_bus_serialises_frames_at_their_real_duration_and_arbitrates_by_id():
    servos = [SimServo("rmd-x", i, reply_latency_s=0.0) for i in (1, 2, 3)]
    bus = SimCanBus(servos, bitrate=125_000)
    for i in (3, 1, 2):  # all ready at once: the lowest ID goes first
        bus.submit(RmdX(i).telemetry_requests()[0], 0.0)
    replies = bus.run_until(1.0)
    one_frame = frame_time(False, 8, 125_000)
    # requests 0x141, 0x142, 0x143 go first (lower IDs than any reply), then the replies
    assert [msg.arbitration_id for _, msg in replies] == [0x241, 0x242, 0x243]
    assert [t for t, _ in replies] == pytest.approx([one_frame * k for k in (4, 5, 6)])
    assert bus.frames == 6
    assert bus.load(1.0, window=1.0) == pytest.approx(6 * one_frame)


def test_frames_not_finished_by_now_are_not_delivered_yet():
    bus = SimCanBus([SimServo("rmd-x", 1, reply_latency_s=0.0)], bitrate=10_000)
    bus.submit(RmdX(1).telemetry_requests()[0], 0.0)
    one_frame = frame_time(False, 8, 10_000)
    assert bus.run_until(one_frame * 1.5) == []
    [(t, msg)] = bus.run_until(one_frame * 3)
    assert t == pytest.approx(2 * one_frame) and msg.arbitration_id == 0x241


def test_remote_and_foreign_frames_get_no_answer():
    servo = SimServo("rmd-x", 1)
    remote = can.Message(arbitration_id=0x141, is_extended_id=False, is_remote_frame=True, dlc=8)
    assert servo.receive(remote, 0.0) == []
    assert servo.receive(RmdX(2).telemetry_requests()[0], 0.0) == []
    assert servo.receive(CubeMarsAK(1).position_command(3.0), 0.0) == []
