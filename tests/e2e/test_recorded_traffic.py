"""Real recorded ArduPlane traffic through the whole bridge to simulated servos.

The SITL recordings (tests/data, described in /work/shared/sitl-recordings/README.md) are
replayed at high speed into a bridge configured like the recorded plane; the CAN side is the
aa55 interface on the adapter emulator's pty. Checks are on values and orderings only: every
value change of a mapped SERVO_OUTPUT_RAW channel becomes a scheduler setpoint with the right
angle, in order, and the simulated servos settle on the mapping of the last PWM at checkpoints
cut out of the file (a prefix replayed, then let settle), zeros never move anything.
"""

from __future__ import annotations

import pytest

from mavservo.mavlink import open_connection
from mavservo.sim.autopilot.replay import iter_tlog, replay
from tests.support.bridge import Recorder, pwm_to_angle, running, sim_servo
from tests.support.paths import TEST_DATA
from tests.support.waiting import wait_until

# a bridge thread dying (an exception nobody catches) fails the test, not just warns
pytestmark = pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")

DATA = TEST_DATA
SERVOS_TLOG = DATA / "plane-servos.tlog"
GIMBAL_TLOG = DATA / "plane-gimbal.tlog"
SPEED = 20.0  # 90 s of recording in 4.5 s
SETTLE_TIMEOUT_S = 4.0
POSITION_TOLERANCE_DEG = 0.05  # commands carry 0.01 deg; the simulated loop settles on them

PLANE = """
  heartbeat_timeout_s: 60
servos:
  - {name: aileron, profile: rmd-x, can_id: 1, limits_deg: [-30, 30], telemetry_hz: 5}
  - {name: elevator, profile: rmd-x, can_id: 2, limits_deg: [-25, 25], telemetry_hz: 5}
  - {name: throttle, profile: rmd-x, can_id: 3, limits_deg: [0, 90], telemetry_hz: 5}
  - {name: rudder, profile: rmd-x, can_id: 4, limits_deg: [-30, 30], telemetry_hz: 5}
  - {name: payload_release, profile: lk, can_id: 9, limits_deg: [0, 90], telemetry_hz: 5}
  - {name: tow_hook, profile: rmd-x, can_id: 10, limits_deg: [-45, 45], telemetry_hz: 5}
# a reply counts as lost only when it never comes: a loaded shared machine can delay one
# past the usual 50 ms, and that is timing, which these tests do not judge
scheduler: {reply_timeout_s: 0.5}
channels:
  - {servo: aileron, source: servo_output, channel: 1, input: {min: 1100, max: 1900},
     output_deg: [-30, 30]}
  - {servo: elevator, source: servo_output, channel: 2, input: {min: 1100, max: 1900},
     output_deg: [-25, 25], reverse: true}
  - {servo: throttle, source: servo_output, channel: 3, input: {min: 1000, max: 2000},
     output_deg: [0, 90]}
  - {servo: rudder, source: servo_output, channel: 4, input: {min: 1100, max: 1900},
     output_deg: [-30, 30]}
  - {servo: payload_release, source: servo_output, channel: 9, input: {min: 1100, max: 1900},
     output_deg: [0, 90]}
  - {servo: tow_hook, source: servo_output, channel: 10, input: {min: 1100, max: 1900},
     output_deg: [-45, 45]}
"""

#: servo -> (channel, PWM min, PWM max, angle at min, angle at max), written out independently
#: of the config parser and the project's mapping code.
PLANE_MAP = {
    "aileron": (1, 1100, 1900, (-30.0, 30.0)),
    "elevator": (2, 1100, 1900, (25.0, -25.0)),  # reversed
    "throttle": (3, 1000, 2000, (0.0, 90.0)),
    "rudder": (4, 1100, 1900, (-30.0, 30.0)),
    "payload_release": (9, 1100, 1900, (0.0, 90.0)),
    "tow_hook": (10, 1100, 1900, (-45.0, 45.0)),
}


def expected_changes(end_s: float | None = None) -> dict[str, list[float]]:
    """Per servo: the angles of each non-zero value change of its channel up to ``end_s``."""
    out: dict[str, list[float]] = {name: [] for name in PLANE_MAP}
    last: dict[str, int] = {}
    for t, msg in iter_tlog(SERVOS_TLOG, {"SERVO_OUTPUT_RAW"}):
        if end_s is not None and t > end_s:
            break
        for name, (channel, low, high, angles) in PLANE_MAP.items():
            pwm = getattr(msg, f"servo{channel}_raw")
            if pwm == 0 or last.get(name) == pwm:
                continue
            last[name] = pwm
            out[name].append(pwm_to_angle(pwm, low, high, angles))
    return out


def settle_on(bridge, targets: dict[str, float]) -> dict[str, float]:
    """Wait (bounded) until every simulated servo is near its target; their true positions."""
    servos = {name: sim_servo(bridge, name) for name in targets}

    def settled() -> bool:
        return all(
            abs(servos[n].position_deg - t) < POSITION_TOLERANCE_DEG for n, t in targets.items()
        )

    wait_until(settled, SETTLE_TIMEOUT_S)
    return {name: servo.position_deg for name, servo in servos.items()}


def test_expected_changes_match_the_recording_readme() -> None:
    """The reference the bridge is checked against has the channel activity the README lists."""
    changes = expected_changes()
    assert len(changes["aileron"]) > 400 and len(changes["throttle"]) > 400
    assert [round(a) for a in changes["payload_release"][:3]] == [0, 45, 90]  # 1100/1500/1900
    assert [round(a) for a in changes["tow_hook"]] == [-45, 0, 45]  # 1100/1500/1900


def test_plane_servos_recording_drives_every_change_to_the_servos() -> None:
    recorder = Recorder()
    # (end of the prefix in recording seconds, what must hold there)
    checkpoints = [13.6, 27.6, 62.5, 68.0, 89.96]
    with running(PLANE, observers=[recorder]) as (bridge, port):
        # one socket for the whole recording, as the autopilot has: the bridge pins the
        # autopilot's identity to the address it is heard from (issue 40)
        url = open_connection(f"udpout:127.0.0.1:{port}", source_system=255, source_component=0)
        start = 0.0
        for end in checkpoints:
            result = replay(SERVOS_TLOG, url, speed=SPEED, start_s=start, end_s=end)
            assert result.sent > 0
            start = end
            expected = expected_changes(end)
            finals = {name: angles[-1] for name, angles in expected.items() if angles}
            positions = settle_on(bridge, finals)
            for name, angle in finals.items():
                assert positions[name] == pytest.approx(angle, abs=POSITION_TOLERANCE_DEG), (
                    f"t={end}: {name} at {positions[name]:.3f}, last PWM maps to {angle:.3f}"
                )
            for name, angles in expected.items():
                if not angles:  # servo9/10 before t=63: only zeros, never commanded
                    assert recorder.angles(name) == [], f"t={end}: {name} commanded by a zero"
                    assert sim_servo(bridge, name).commands == 0
                    assert sim_servo(bridge, name).position_deg == pytest.approx(0.0, abs=0.01)
        summary = bridge.stop()

    everything = expected_changes()
    for name, angles in everything.items():
        got = recorder.angles(name)
        assert got == pytest.approx(angles, abs=1e-6), f"{name}: setpoints differ from the file"
    # the checkpoints really were different places (the test can fail on a stuck servo)
    assert everything["aileron"][-1] == pytest.approx(0.0)
    assert max(everything["throttle"]) == pytest.approx(90.0)
    for name, row in summary["servos"].items():
        assert row["frames"]["lost"] == 0 and row["frames"]["rejected"] == 0, name
    assert summary["buses"]["bus0"]["bus_rejected"] == 0


GIMBAL = """
  heartbeat_timeout_s: 60
servos:
  - {name: gimbal_roll, profile: cubemars-ak, can_id: 1, limits_deg: [-30, 30], telemetry_hz: 20}
  - {name: gimbal_pitch, profile: cubemars-ak, can_id: 2, limits_deg: [-90, 30], telemetry_hz: 20}
  - {name: gimbal_yaw, profile: cubemars-ak, can_id: 3, limits_deg: [-160, 160], telemetry_hz: 20}
gimbals:
  - name: gimbal
    component_id: 154
    roll: gimbal_roll
    pitch: gimbal_pitch
    yaw: gimbal_yaw
    limits_deg: {roll: [-30, 30], pitch: [-90, 30], yaw: [-160, 160]}
"""


def test_plane_gimbal_recording_points_the_gimbal_servos() -> None:
    recorder = Recorder()
    # (prefix end, roll/pitch/yaw of the SET_ATTITUDE target in force there; commands file)
    checkpoints = [
        (13.0, (0.0, 0.0, 0.0)),
        (20.3, (0.0, -60.0, 0.0)),
        (23.5, (0.0, -90.0, 0.0)),
        (29.0, (0.0, -30.0, 45.0)),
        (60.0, (0.0, 0.0, 0.0)),
    ]
    axes = ("gimbal_roll", "gimbal_pitch", "gimbal_yaw")
    with running(GIMBAL, observers=[recorder]) as (bridge, port):
        url = open_connection(f"udpout:127.0.0.1:{port}", source_system=255, source_component=0)
        start = 0.0
        for end, pose in checkpoints:
            replay(GIMBAL_TLOG, url, speed=SPEED, start_s=start, end_s=end)
            start = end
            targets = dict(zip(axes, pose, strict=True))
            positions = settle_on(bridge, targets)
            for name, angle in targets.items():
                # the -90 target arrives as a quaternion that decodes to -89.99 deg
                assert positions[name] == pytest.approx(angle, abs=0.05), (
                    f"t={end}: {name} at {positions[name]:.3f}, target {angle}"
                )
        summary = bridge.stop()
    pitch = recorder.angles("gimbal_pitch")
    assert min(pitch) == pytest.approx(-90.0, abs=0.05)  # it went through the -90 target
    # the pitch targets appear in the recorded order (0 -> -30 -> -60 -> -90 ...)
    firsts = [next(i for i, a in enumerate(pitch) if abs(a - p) < 0.05) for p in (-60, -90)]
    assert firsts == sorted(firsts)
    for name in axes:
        assert summary["servos"][name]["frames"]["rejected"] == 0
