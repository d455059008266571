"""Replay ArduPlane's real gimbal traffic (tests/data/plane-gimbal.tlog) through GimbalDevice.

The expected timeline is the one in /work/shared/sitl-recordings/plane-gimbal-commands.txt:
each GCS command shows up as a new GIMBAL_DEVICE_SET_ATTITUDE target, the yaw-lock commands as
earth-frame yaw (flags 28) that the device must turn into body yaw with the vehicle's heading, and
the retract as ArduPilot's RETRACT/identity alternation, which must hold the retract pose for its
whole 3.2 s instead of flickering to 0/0/0.
"""

from __future__ import annotations

import pytest
from pymavlink import mavutil

from mavservo.mavlink.backend import ApplyResult, Outcome, ServoStatus
from mavservo.mavlink.gimbal import GimbalDevice, GimbalSettings
from mavservo.mavlink.quaternion import earth_to_body_yaw, wrap_180
from tests.support.paths import TEST_DATA

TLOG = TEST_DATA / "plane-gimbal.tlog"
MAX_MESSAGES = 10_000  # the file holds 7,164
LIMITS = {"roll": (-30.0, 30.0), "pitch": (-90.0, 30.0), "yaw": (-160.0, 160.0)}
RETRACT_POSE = (0.0, -90.0, 0.0)  # the default: pitch at its lower limit
HOLD_S = 0.25

# (first SET_ATTITUDE of the segment [s from the first record], roll, pitch, yaw, yaw frame)
TIMELINE = [
    (9.064, 0.0, -30.0, 0.0, "body"),  # RC targeting default
    (11.024, 0.0, 0.0, 0.0, "body"),
    (14.248, 0.0, -30.0, 0.0, "body"),
    (17.427, 0.0, -60.0, 0.0, "body"),
    (20.625, 0.0, -90.0, 0.0, "body"),
    (23.829, 0.0, -30.0, -45.0, "body"),
    (27.028, 0.0, -30.0, 45.0, "body"),
    (30.229, 0.0, -30.0, -45.0, "earth"),
    (33.431, 0.0, -30.0, 45.0, "earth"),
    (36.630, 0.0, -30.0, 0.0, "earth"),
    (39.830, *RETRACT_POSE, "retract"),
    (43.012 + HOLD_S, 0.0, 0.0, 0.0, "body"),  # neutral: RETRACT messages stop at 43.012
    (46.231, 0.0, -45.0, 30.0, "body"),
    (49.433, 0.0, 0.0, 0.0, "body"),
]


class RecordingBackend:
    """Records every gimbal request; reports no servo statuses (the replay checks commands)."""

    def __init__(self) -> None:
        self.calls: list[tuple[float, float | None, float | None, float | None]] = []

    def mapped_servo_channels(self) -> set[int]:
        return set()

    def mapped_actuator_indices(self) -> set[int]:
        return set()

    def apply_servo_output(self, channel, pwm_us, source, now) -> ApplyResult:
        return ApplyResult(Outcome.DENIED)

    def apply_actuator(self, index, value, source, now) -> ApplyResult:
        return ApplyResult(Outcome.DENIED)

    def apply_gimbal(self, gimbal, roll_deg, pitch_deg, yaw_deg, source, now) -> ApplyResult:
        self.calls.append((now, roll_deg, pitch_deg, yaw_deg))
        return ApplyResult(Outcome.ACCEPTED)

    def servo_statuses(self) -> list[ServoStatus]:
        return []

    def enter_failsafe(self, reason, now) -> None:
        pass

    def leave_failsafe(self, now) -> None:
        pass

    def health(self) -> dict[str, float]:
        return {}


@pytest.fixture(scope="module")
def replay():
    """Feed the whole recording through a device; return the calls with the vehicle yaw then."""
    settings = GimbalSettings(
        name="cam",
        axis_servos={"roll": "r", "pitch": "p", "yaw": "y"},
        limits_deg=LIMITS,
        component_id=154,
        system_id=1,
        retract_hold_s=HOLD_S,
    )
    backend = RecordingBackend()
    device = GimbalDevice(settings, backend)
    connection = mavutil.mavlink_connection(str(TLOG), dialect="ardupilotmega")
    calls_with_yaw = []
    start = None
    statuses = 0
    try:
        for _ in range(MAX_MESSAGES):
            msg = connection.recv_match()
            if msg is None:
                break
            if start is None:
                start = msg._timestamp
            now = msg._timestamp - start
            before = len(backend.calls)
            device.handle_message(msg, now)
            for call in backend.calls[before:]:
                calls_with_yaw.append((*call, device.vehicle_yaw_deg))
            statuses += len(device.periodic(now))
        else:
            pytest.fail("recording longer than expected")
    finally:
        connection.close()
    return device, calls_with_yaw, statuses


def expected_body(segment, vehicle_yaw):
    _, roll, pitch, yaw, frame = segment
    if frame == "earth":
        return (roll, pitch, earth_to_body_yaw(yaw, vehicle_yaw))
    return (roll, pitch, yaw)


def segment_of(t: float) -> int:
    index = -1
    for i, segment in enumerate(TIMELINE):
        if t >= segment[0] - 1e-3:
            index = i
    return index


def matches(call, target, tol=0.1) -> bool:
    return all(abs(wrap_180(a - b)) <= tol for a, b in zip(call, target, strict=True))


def test_every_applied_target_matches_the_timeline(replay):
    _, calls, _ = replay
    assert calls, "no gimbal request was applied"
    for now, roll, pitch, yaw, vehicle_yaw in calls:
        index = segment_of(now)
        assert index >= 0, f"target applied at {now:.3f} s, before the first SET_ATTITUDE"
        target = expected_body(TIMELINE[index], vehicle_yaw)
        assert matches((roll, pitch, yaw), target), (now, (roll, pitch, yaw), TIMELINE[index])


def test_each_segment_starts_when_its_first_set_attitude_arrives(replay):
    _, calls, _ = replay
    for index, segment in enumerate(TIMELINE):
        in_segment = [c for c in calls if segment_of(c[0]) == index]
        assert in_segment, f"segment {segment} never applied"
        first = in_segment[0]
        # the device reacts to the message itself: the first request lands on that message
        # (neutral after retract: on the first identity message once the hold time has passed)
        assert first[0] - segment[0] < 0.03, (segment, first)
        assert matches(first[1:4], expected_body(segment, first[4]))


def test_retract_is_held_for_its_whole_3_2_seconds(replay):
    device, calls, _ = replay
    during = [c for c in calls if 39.83 - 1e-3 <= c[0] < 43.012 + HOLD_S]
    assert during and all(matches(c[1:4], RETRACT_POSE) for c in during)
    # all 159 identity messages interleaved with the 160 RETRACT messages were recognised,
    # plus the ones arriving inside the hold time after the last RETRACT
    assert 159 <= device.counters.shadow_ignored <= 159 + int(HOLD_S * 50) + 2


def test_earth_frame_segments_follow_the_vehicle_heading(replay):
    _, calls, _ = replay
    earth = [c for c in calls if TIMELINE[segment_of(c[0])][4] == "earth"]
    assert earth
    # the recorded vehicle heads about -7 deg, so north-relative -45 is about -38 from the nose
    first_lock = earth[0]
    assert -9.0 < first_lock[4] < -5.0
    assert first_lock[3] == pytest.approx(-45.0 - first_lock[4], abs=0.1)


def test_status_streamed_throughout(replay):
    _, _, statuses = replay
    assert statuses >= 5 * 59  # >= 5 Hz over the 60 s recording (default is 10 Hz)


def test_segments_are_applied_in_order_without_repeats_of_the_50hz_stream(replay):
    _, calls, _ = replay
    visited = [segment_of(c[0]) for c in calls]
    collapsed = [s for i, s in enumerate(visited) if i == 0 or visited[i - 1] != s]
    assert collapsed == list(range(len(TIMELINE)))
    # 2,708 SET_ATTITUDE messages; an unchanged target is not re-sent (the scheduler refreshes)
    assert len(calls) < 3 * len(TIMELINE)
