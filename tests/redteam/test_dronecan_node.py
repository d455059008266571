"""Red-team findings on the DroneCAN node and profile (review of issues 28 and 32 item 7): each
test failed on main 00d11a1 and passes with its fix."""

from __future__ import annotations

import math

import can
import pytest
from dronecan.transport import Frame, Transfer
from hypothesis import given, settings
from hypothesis import strategies as st

from mavservo.servos.dronecan import wire
from mavservo.servos.dronecan.node import SENDERS_REPORTED, BridgeNode, NodeOptions
from mavservo.servos.dronecan.profile import DroneCanServo


def library_decode(frames: list[can.Message]):  # type: ignore[no-untyped-def]
    """The ``dronecan`` package's own reassembly and decoding (independent of the profile's)."""
    transfer = Transfer()
    transfer.from_frames([Frame(m.arbitration_id, bytes(m.data)) for m in frames])
    return transfer


@settings(max_examples=300, deadline=None)
@given(
    st.integers(500, 2499).flatmap(
        lambda low: st.tuples(st.just(low), st.integers(low + 1, 2500), st.floats(0.0, 1.0))
    )
)
def test_a_pwm_command_on_the_wire_stays_within_the_channels_pulse_range(
    case: tuple[int, int, float],
) -> None:
    """float16 steps by 2 us above 2048 us: 2499 us used to go out as 2500, past pwm_max_us."""
    low, high, fraction = case
    profile = DroneCanServo(
        20, firmware="ardupilot", actuator_id=1, command="pwm", pwm_min_us=low, pwm_max_us=high
    )
    angle = profile.min_angle_deg + fraction * (profile.max_angle_deg - profile.min_angle_deg)
    [command] = library_decode([profile.position_command(angle)]).payload.commands
    value = float(command.command_value)
    assert low <= value <= high
    assert low <= int(value + 0.5) <= high  # what AP_Periph makes of it (rc_out.cpp)


def test_the_pwm_limit_itself_is_sent_inside_the_limit() -> None:
    profile = DroneCanServo(
        20, firmware="ardupilot", actuator_id=1, command="pwm", pwm_min_us=1000, pwm_max_us=2499
    )
    [command] = library_decode([profile.position_command(45.0)]).payload.commands
    assert float(command.command_value) == 2498.0


def _node(**options: object) -> BridgeNode:
    return BridgeNode(
        [DroneCanServo(20, firmware="ardupilot", actuator_id=1, command="pwm")],
        NodeOptions(node_id=100, **options),
        (0, 1),
        0.0,
    )


def test_another_nodes_safety_state_is_reported_once_and_counted_every_time() -> None:
    """A flight controller on the bus broadcasts SafetyState (SAFETY_ON while disarmed): an
    AP_Periph board obeys the last one heard, so its outputs toggle at 2 Hz against the
    bridge's SAFETY_OFF. It used to pass without a word."""
    node = _node(safety_state="safety_off")
    for tid in range(6):
        for msg in wire.encode_message(wire.safety_state(False), 9, tid, wire.PRIORITY_LOW):
            node.receive(msg, 0.5 * tid)
    [notice] = node.take_notices()
    assert "node 9" in notice and "SafetyState (SAFETY_ON)" in notice and "fight" in notice
    assert node.counters["foreign_safety_state"] == 6
    assert node.take_notices() == []
    # a spoof with the bridge's own id is named as such
    for msg in wire.encode_message(wire.safety_state(True), 100, 0, wire.PRIORITY_LOW):
        node.receive(msg, 4.0)
    [notice] = node.take_notices()
    assert "bridge's own node id 100" in notice and "SAFETY_OFF" in notice


def test_a_sender_that_turns_to_the_bridges_actuators_is_reported_as_a_second_master() -> None:
    """Reported once as "not the bridge's" (actuator 7), the same node later commanding the
    bridge's actuator 1 was never reported: two masters, silently."""
    node = _node(safety_state="safety_off")
    for msg in wire.encode_message(wire.array_command([(7, 4, 1500.0)]), 12, 0):
        node.receive(msg, 1.0)
    [first] = node.take_notices()
    assert "not the bridge's" in first
    for tid in range(1, 4):
        for msg in wire.encode_message(wire.array_command([(1, 4, 1500.0)]), 12, tid):
            node.receive(msg, 1.0 + tid)
    [second] = node.take_notices()
    assert "node 12" in second and "two masters" in second
    assert node.take_notices() == []


def test_a_stranger_making_up_source_ids_gets_a_bounded_number_of_reports() -> None:
    """One ArrayCommand and one SafetyState from each of 126 made-up node ids used to give 252
    WARNING lines and STATUSTEXTs; now two (a command, a safety state) for each of at most
    SENDERS_REPORTED nodes and one summary."""
    node = _node(safety_state="safety_off")
    for source in range(1, 128):
        if source == 100:
            continue
        for msg in wire.encode_message(wire.array_command([(1, 4, 1500.0)]), source, 0):
            node.receive(msg, 1.0)
        for msg in wire.encode_message(wire.safety_state(False), source, 0, wire.PRIORITY_LOW):
            node.receive(msg, 1.0)
    notices = node.take_notices()
    assert len(notices) == 2 * SENDERS_REPORTED + 1
    assert "counted" in notices[-1]
    assert node.counters["foreign_commands"] == 126
    assert node.counters["foreign_safety_state"] == 126


def test_a_real_ap_periph_board_without_status_is_not_said_to_ignore_its_commands() -> None:
    """AP_Periph sends actuator Status only as a SITL build (rc_out.cpp ``sim_update_actuator``
    under AP_SIM_ENABLED): a real board driving its outputs is silent. The warning used to tell
    its user "commands ignored? check the command type" for a correct setup."""
    servo = DroneCanServo(20, firmware="ardupilot", actuator_id=1, command="pwm")
    node = BridgeNode([servo], NodeOptions(node_id=100, safety_state="safety_off"), (0, 1), 0.0)
    heartbeat = wire.node_status(5.0, wire.HEALTH_OK, wire.MODE_OPERATIONAL)
    for msg in wire.encode_message(heartbeat, 20, 0, wire.PRIORITY_LOW):
        assert servo.decode(msg, 0.0) is not None
    node.pack([servo.position_command(10.0)])
    for step in range(50):  # 5 s of due() at 10 Hz, commanded, no Status
        node.due(0.1 * step, "ok")
    [notice] = node.take_notices()
    assert "expected of a real AP_Periph board" in notice
    assert "commands ignored" not in notice
    assert node.counters["silent_actuators"] == 1


def test_an_ardupilot_status_over_another_range_reads_back_as_the_angle_it_drives() -> None:
    """AP_Periph (SITL) reports ``norm x 45 deg``. Over a servo range of +-60 deg, a command of
    60 deg (norm 1.0) read back as 45 deg: 15 deg "behind" for ever in telemetry and in the
    health monitor's tracking check."""
    servo = DroneCanServo(
        20,
        firmware="ardupilot",
        actuator_id=2,
        command="pwm",
        unitless_min_deg=-60.0,
        unitless_max_deg=60.0,
    )
    for commanded in (60.0, 30.0, -60.0, 0.0):
        norm = 2.0 * (commanded + 60.0) / 120.0 - 1.0
        status = wire.lib().uavcan.equipment.actuator.Status(
            actuator_id=2,
            position=math.radians(norm * 45.0),
            force=0.0,
            speed=0.0,
            power_rating_pct=wire.POWER_RATING_UNKNOWN,
        )
        frames = wire.encode_message(status, 20, 0, wire.PRIORITY_LOW)
        states = [servo.decode(msg, 1.0) for msg in frames]
        assert states[-1] is not None
        assert states[-1].position_deg == pytest.approx(commanded, abs=0.1)
    # the +-45 preset reads it as it comes, and a generic servo's position is its measurement
    generic = DroneCanServo(21, actuator_id=2, command="unitless")
    status = wire.lib().uavcan.equipment.actuator.Status(
        actuator_id=2,
        position=math.radians(45.0),
        force=0.0,
        speed=0.0,
        power_rating_pct=wire.POWER_RATING_UNKNOWN,
    )
    [*_, state] = [generic.decode(m, 1.0) for m in wire.encode_message(status, 21, 0, 24)]
    assert state is not None and state.position_deg == pytest.approx(45.0, abs=0.1)


def _feed(servo: DroneCanServo, payload: object, source: int, t: float, tid: int) -> None:
    for msg in wire.encode_message(payload, source, tid & 0x1F, wire.PRIORITY_LOW):
        servo.decode(msg, t)


def _run_node(status_until: float, commanded_until: float, end: float) -> BridgeNode:
    """A generic servo on node 20: NodeStatus every second to the end, its Status at 10 Hz
    until ``status_until``, commanded every 50 ms until ``commanded_until``."""
    servo = DroneCanServo(20, actuator_id=1)
    node = BridgeNode([servo], NodeOptions(node_id=100), (0, 1), 0.0)
    actuator = wire.lib().uavcan.equipment.actuator
    for step in range(int(end / 0.05)):
        t = round(step * 0.05, 10)
        if step % 20 == 0:
            heartbeat = wire.node_status(t, wire.HEALTH_OK, wire.MODE_OPERATIONAL)
            _feed(servo, heartbeat, 20, t, step // 20)
        if t < status_until and step % 2 == 0:
            status = actuator.Status(
                actuator_id=1,
                position=0.1,
                force=0.0,
                speed=0.0,
                power_rating_pct=wire.POWER_RATING_UNKNOWN,
            )
            _feed(servo, status, 20, t, step // 2)
        if t < commanded_until:
            node.pack([servo.position_command(5.0)])
        node.due(t, "ok")
    return node


def test_an_actuator_whose_status_stops_while_its_node_lives_is_reported_once() -> None:
    """A servo's Status stopped at 2 s while its node's NodeStatus went on: it stayed online,
    its 2 s old position shown as current, and nothing was said (the silent-actuator notice is
    for an actuator that never reported)."""
    node = _run_node(status_until=2.0, commanded_until=10.0, end=10.0)
    [notice] = node.take_notices()
    assert "actuator 1 has sent no Status for 3 s while commanded" in notice
    assert node.counters["stopped_actuators"] == 1


def test_a_healthy_or_released_actuator_is_not_reported_as_stopped() -> None:
    healthy = _run_node(status_until=10.0, commanded_until=10.0, end=10.0)
    assert healthy.take_notices() == [] and not healthy.counters["stopped_actuators"]
    released = _run_node(status_until=2.0, commanded_until=2.0, end=10.0)
    assert released.take_notices() == [] and not released.counters["stopped_actuators"]


def test_the_safety_warning_is_said_again_with_the_first_command() -> None:
    """``safety_state: none`` with ArduPilot nodes was said once, at start: a ground station
    that connected later never heard why the servos do not move (the e2e test of it passed or
    failed on how fast the bridge started)."""
    servo = DroneCanServo(20, firmware="ardupilot", actuator_id=1, command="pwm")
    node = BridgeNode([servo], NodeOptions(node_id=100), (0, 1), 0.0)
    [at_start] = node.take_notices()
    assert "SAFETY_OFF" in at_start
    node.pack([servo.position_command(10.0)])
    assert node.take_notices() == [at_start]
    node.pack([servo.position_command(12.0)])
    assert node.take_notices() == []  # once more, not with every command
