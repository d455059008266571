"""Pushing (CubeMars) gimbal servos through an adapter outage, end to end (findings 7 and 8).

The trial: with the adapter unplugged the three CubeMars gimbal servos (they push their status,
nobody polls them) stayed "online" with fault fields 0 and ESC telemetry counters advancing, the
first DO_MOUNT_CONTROL of the outage was ACCEPTED, and pitch demands -60 ... -51 refused later in
the outage were carried out 2.2 s after the replug. Now the pushes stopping is what takes them
offline (STATUSTEXT, NO_REPLY, empty ESC slots, commands TEMPORARILY_REJECTED), and a refused
gimbal demand is never applied afterwards.

Real parts: a pymavlink GCS over UDP on 127.0.0.1, the bridge, aa55 on the adapter emulator's
pty, simulated CubeMars servos; every wait is bounded.
"""

from __future__ import annotations

import pytest

from mavservo.mavlink.connection import mavlink2
from mavservo.servos.base import Fault
from tests.e2e.test_recorded_traffic import GIMBAL  # the three-CubeMars gimbal of the recorded runs
from tests.support.bridge import (
    MAV_RESULT_ACCEPTED,
    MAV_RESULT_TEMPORARILY_REJECTED,
    Peer,
    ServoSpy,
    running,
    sim_servo,
)
from tests.support.waiting import wait_until

pytestmark = pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")

MAV_CMD_DO_MOUNT_CONTROL = 205
MAV_MOUNT_MODE_MAVLINK_TARGETING = 2
GIMBAL_TARGET = (1, 154)
AXES = ("gimbal_roll", "gimbal_pitch", "gimbal_yaw")
WAIT_S = 5.0


def status(bridge, name: str):
    return next(s for s in bridge.backend.servo_statuses() if s.name == name)


def all_reporting(bridge) -> bool:
    return all(status(bridge, n).online and status(bridge, n).state is not None for n in AXES)


def mount_control(peer: Peer, pitch: float) -> int | None:
    params = [pitch, 0.0, 0.0, 0.0, 0.0, 0.0, MAV_MOUNT_MODE_MAVLINK_TARGETING]
    return peer.command(MAV_CMD_DO_MOUNT_CONTROL, params, target=GIMBAL_TARGET)


def esc_counts(peer: Peer, mark: int) -> list[tuple[int, ...]]:
    # the servos' ESC numbers start where the bridge put them (17 by default, above motors)
    return [
        tuple(m.count[:3]) for m in peer.since(mark) if m.get_type().startswith("ESC_TELEMETRY_")
    ]


def test_pushing_gimbal_servos_go_offline_in_an_outage_and_refused_demands_never_run() -> None:
    with running(GIMBAL) as (bridge, port):
        peer = Peer(port)
        try:
            assert wait_until(lambda: all_reporting(bridge), WAIT_S)
            assert mount_control(peer, -20.0) == MAV_RESULT_ACCEPTED
            pitch = sim_servo(bridge, "gimbal_pitch")
            assert wait_until(lambda: abs(pitch.position_deg + 20) < 0.2, WAIT_S)
            spy = ServoSpy(pitch)
            emulator = bridge.emulators["bus0"]
            mark = peer.count()

            emulator.unplug()
            # uncommanded roll and yaw too: their pushes stopped, so they are offline
            assert wait_until(lambda: not any(status(bridge, n).online for n in AXES), WAIT_S)
            for name in AXES:
                assert Fault.NO_REPLY in status(bridge, name).state.faults
                assert wait_until(
                    lambda n=name: f"servo {n} offline" in peer.statustexts(mark), WAIT_S
                ), peer.statustexts(mark)
            esc_mark = peer.count()
            assert wait_until(lambda: len(esc_counts(peer, esc_mark)) >= 2, WAIT_S)
            assert esc_counts(peer, esc_mark)[-1] == (0, 0, 0)  # empty slots, not frozen data
            for refused_pitch in range(-60, -50):
                assert mount_control(peer, refused_pitch) == MAV_RESULT_TEMPORARILY_REJECTED

            emulator.replug()
            assert wait_until(lambda: all_reporting(bridge), 8.0)
            assert wait_until(lambda: len(spy.frames) > 20, WAIT_S)  # refreshed again
            # the trial's refused -51 arrived 2.2 s after the replug: wait it out
            assert not wait_until(lambda: spy.targets and min(spy.targets) < -50, 3.0)
            assert pitch.target_deg == pytest.approx(-20.0, abs=0.01)
            assert mount_control(peer, -45.0) == MAV_RESULT_ACCEPTED
            assert wait_until(lambda: abs(pitch.position_deg + 45) < 0.2, WAIT_S)
        finally:
            peer.close()


def test_an_uncommanded_pushing_servo_that_falls_silent_is_offline_until_it_pushes() -> None:
    with running(GIMBAL) as (bridge, port):
        peer = Peer(port)
        try:
            peer.send(mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))  # a GCS: answer me
            assert wait_until(lambda: all_reporting(bridge), WAIT_S)
            yaw = sim_servo(bridge, "gimbal_yaw")
            mark = peer.count()
            yaw.faults.silent = True  # the trial's silent port: nothing from this servo
            assert wait_until(lambda: not status(bridge, "gimbal_yaw").online, WAIT_S)
            assert status(bridge, "gimbal_roll").online  # the others keep pushing
            assert wait_until(lambda: "servo gimbal_yaw offline" in peer.statustexts(mark), WAIT_S)
            # a gimbal command that needs the silent axis is refused, not accepted
            params = [0.0, 0.0, 30.0, 0.0, 0.0, 0.0, MAV_MOUNT_MODE_MAVLINK_TARGETING]
            result = peer.command(MAV_CMD_DO_MOUNT_CONTROL, params, target=GIMBAL_TARGET)
            assert result == MAV_RESULT_TEMPORARILY_REJECTED
            yaw.faults.silent = False
            assert wait_until(lambda: status(bridge, "gimbal_yaw").online, WAIT_S)
        finally:
            peer.close()


def test_uncommanded_pushing_servos_go_offline_when_the_adapter_is_unplugged() -> None:
    """The trial exactly: no gimbal command yet, adapter unplugged; the servos stayed online and
    the first DO_MOUNT_CONTROL of the outage was ACCEPTED."""
    with running(GIMBAL) as (bridge, port):
        peer = Peer(port)
        try:
            peer.send(mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))  # a GCS: answer me
            assert wait_until(lambda: all_reporting(bridge), WAIT_S)
            mark = peer.count()
            bridge.emulators["bus0"].unplug()
            assert wait_until(lambda: not any(status(bridge, n).online for n in AXES), WAIT_S)
            assert mount_control(peer, -30.0) == MAV_RESULT_TEMPORARILY_REJECTED
            assert wait_until(
                lambda: all(f"servo {n} offline" in peer.statustexts(mark) for n in AXES),
                WAIT_S,
            ), peer.statustexts(mark)
            bridge.emulators["bus0"].replug()
            assert wait_until(lambda: all(status(bridge, n).online for n in AXES), 8.0)
        finally:
            peer.close()
