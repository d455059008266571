"""The simulated ODrive axis behind the real SimServo physics, driven by the profile's own
frames: it powers up IDLE and does not move until closed loop, pushes encoder estimates at the
telemetry rate and a heartbeat every 100 ms, its watchdog disarms it (WATCHDOG_TIMER_EXPIRED,
IDLE) when the host falls silent, a motor fault disarms it and arming is refused while it
lasts, and the profile turns all of that into faults and a new start-up.
"""

from __future__ import annotations

import can
import pytest

from mavservo.servos import NO_FAULT, Fault
from mavservo.servos.odrive.profile import (
    CMD_ENCODER_ESTIMATES,
    CMD_HEARTBEAT,
    STATE_CLOSED_LOOP,
    STATE_IDLE,
    WATCHDOG_TIMER_EXPIRED,
    ODrive,
    ODriveOptions,
)
from mavservo.sim.servo import SimServo


def make(**options: object) -> tuple[ODrive, SimServo]:
    opts = ODriveOptions.model_validate(options)
    return ODrive(1, opts), SimServo("odrive", 1, seed=1, reply_latency_s=0.0, options=opts)


def send(sim: SimServo, frames: list[can.Message], now: float) -> None:
    for msg in frames:
        assert sim.receive(msg, now) == []  # CANSimple answers none of them


def pushes(profile: ODrive, sim: SimServo, now: float) -> list[can.Message]:
    """The pushes due at ``now``, decoded by the profile."""
    out = [reply for _, reply in sim.poll(now)]
    for msg in out:
        assert profile.decode(msg, now) is not None
    return out


def drive(profile: ODrive, sim: SimServo, angle: float, start: float, seconds: float) -> float:
    """Command ``angle`` every 20 ms (feeding the watchdog) with pushes at 50 Hz."""
    now = start
    while now < start + seconds:
        send(sim, [profile.position_command(angle)], now)
        pushes(profile, sim, now)
        now += 0.02
    return now


def heartbeat_state(profile: ODrive, sim: SimServo, now: float) -> int | None:
    """Poll 0.1 s of pushes; the axis state of the last heartbeat."""
    for step in range(6):
        pushes(profile, sim, now + step * 0.02)
    return profile.axis_state


def test_powers_up_idle_and_moves_only_in_closed_loop() -> None:
    profile, sim = make()
    sim.poll(0.0)
    assert heartbeat_state(profile, sim, 0.02) == STATE_IDLE and profile.needs_startup()
    drive(profile, sim, 30.0, 0.2, 0.5)
    assert abs(sim.position_deg) < 1e-6 and not sim.enabled
    send(sim, profile.startup_frames(), 0.8)
    assert sim.enabled
    end = drive(profile, sim, 30.0, 0.8, 2.0)
    assert sim.position_deg == pytest.approx(30.0, abs=0.01)
    assert heartbeat_state(profile, sim, end) == STATE_CLOSED_LOOP
    assert not profile.needs_startup()
    state = profile.last_state
    assert state is not None and state.faults == NO_FAULT
    assert state.position_deg == pytest.approx(sim.position_deg, abs=0.05)


def test_heartbeat_every_100_ms_encoder_estimates_at_the_telemetry_rate() -> None:
    profile, sim = make()
    sim.poll(0.0)
    commands = []
    for step in range(1, 51):  # one second at the 50 Hz status rate (clear of float ties)
        commands += [m.arbitration_id & 0x1F for m in pushes(profile, sim, step * 0.02 + 1e-6)]
    assert commands.count(CMD_ENCODER_ESTIMATES) == 50
    assert commands.count(CMD_HEARTBEAT) == 10


def test_watchdog_expiry_disarms_and_a_new_startup_rearms() -> None:
    profile, sim = make(watchdog_timeout_s=0.3)
    sim.poll(0.0)
    send(sim, profile.startup_frames(), 0.0)
    now = drive(profile, sim, 20.0, 0.0, 1.0)
    assert heartbeat_state(profile, sim, now) == STATE_CLOSED_LOOP
    # the host falls silent: only pushes for a second
    for step in range(50):
        pushes(profile, sim, now + 0.1 + step * 0.02)
    assert not sim.enabled
    assert profile.axis_state == STATE_IDLE and profile.needs_startup()
    assert profile.axis_error & WATCHDOG_TIMER_EXPIRED
    state = profile.last_state
    assert state is not None and Fault.COMMUNICATION_LOST in state.faults
    # commands alone do not re-arm it; the start-up (clear errors, closed loop) does
    now += 1.2
    drive(profile, sim, -20.0, now, 0.3)
    assert not sim.enabled
    send(sim, profile.startup_frames(), now + 0.3)
    now = drive(profile, sim, -20.0, now + 0.3, 2.0)
    assert sim.position_deg == pytest.approx(-20.0, abs=0.01)
    assert heartbeat_state(profile, sim, now) == STATE_CLOSED_LOOP
    state = profile.last_state
    assert state is not None and state.faults == NO_FAULT


def test_the_watchdog_set_over_rxsdo_at_startup() -> None:
    """A device whose watchdog is off until the start-up writes it through the endpoints."""
    ids = {"watchdog_timeout_endpoint": 300, "enable_watchdog_endpoint": 301}
    profile = ODrive(1, ODriveOptions(watchdog_timeout_s=0.2, **ids))  # type: ignore[arg-type]
    opts = ODriveOptions(watchdog_timeout_s=0.0, **ids)  # type: ignore[arg-type]
    sim = SimServo("odrive", 1, seed=1, reply_latency_s=0.0, options=opts)
    sim.poll(0.0)
    send(sim, ODrive(1, opts).startup_frames(), 0.0)  # writes "disabled"
    drive(profile, sim, 10.0, 0.0, 0.2)
    for step in range(50):
        pushes(profile, sim, 0.3 + step * 0.02)
    assert sim.enabled  # no watchdog: it holds
    send(sim, profile.startup_frames(), 1.5)  # writes 0.2 s, enabled
    drive(profile, sim, 10.0, 1.5, 0.2)
    for step in range(20):
        pushes(profile, sim, 1.8 + step * 0.02)
    assert not sim.enabled and profile.axis_error & WATCHDOG_TIMER_EXPIRED


def test_a_motor_fault_disarms_and_arming_is_refused_while_it_lasts() -> None:
    profile, sim = make()
    sim.poll(0.0)
    send(sim, profile.startup_frames(), 0.0)
    now = drive(profile, sim, 10.0, 0.0, 0.5)
    sim.faults.over_current = True
    now = drive(profile, sim, 10.0, now, 0.2)
    assert not sim.enabled and profile.axis_state == STATE_IDLE
    state = profile.last_state
    assert state is not None and Fault.OVER_CURRENT in state.faults
    send(sim, profile.startup_frames(), now)
    now = drive(profile, sim, 10.0, now, 0.2)
    assert not sim.enabled and profile.procedure_result == 3  # DISARMED
    sim.faults.over_current = False
    send(sim, profile.startup_frames(), now)
    now = drive(profile, sim, 10.0, now, 0.2)
    assert sim.enabled and profile.axis_state == STATE_CLOSED_LOOP
    state = profile.last_state
    assert state is not None and state.faults == NO_FAULT


def test_release_turns_the_motor_off() -> None:
    profile, sim = make()
    sim.poll(0.0)
    send(sim, profile.startup_frames(), 0.0)
    now = drive(profile, sim, 10.0, 0.0, 0.3)
    send(sim, profile.release_frames(), now)
    assert not sim.enabled
    assert heartbeat_state(profile, sim, now) == STATE_IDLE


def test_trap_traj_through_a_gear_and_auxiliary_messages() -> None:
    profile, sim = make(
        input_mode="trap-traj",
        motor_turns_per_rev=8.0,
        velocity_limit_turns_s=4.0,
        traj_accel_turns_s2=1000.0,
        aux_rate_ms=100,
    )
    sim.poll(0.0)
    send(sim, profile.startup_frames(), 0.0)
    send(sim, [profile.position_command(170.0)], 0.0)
    sim.advance(0.2)
    # 4 motor turns/s through 1:8 is 180 deg/s at the output
    assert sim.velocity_dps == pytest.approx(180.0, rel=0.01)
    now = drive(profile, sim, 90.0, 0.2, 2.0)
    assert sim.position_deg == pytest.approx(90.0, abs=0.01)
    heartbeat_state(profile, sim, now)
    state = profile.last_state
    assert state is not None
    assert state.position_deg == pytest.approx(90.0, abs=0.05)
    assert state.voltage_v == pytest.approx(sim.voltage_v)
    assert state.temperature_c == pytest.approx(sim.temperature_c, abs=0.5)
    assert state.current_a == state.current_a  # a reading, not NaN
