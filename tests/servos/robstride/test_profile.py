"""Robstride profile: byte-exact vectors from the vendor's manual, every fault bit, the
lifecycle of the simulated motor, the other-protocol advice, hypothesis round trips, and
cross-checks against two independent implementations on PyPI (``robstride-dynamics``,
``robstride``).

Document: Robstride "RS01 User Manual" (260428; the RS00..RS06 manuals share chapters 4 and 6):
4.1 private protocol (types 2, 3, 4, 6, 0x12, 0x15, 0x18; the type 2 table: fault bits 21..16,
mode bits 23..22, angle over +-4 pi, temperature x 10), 4.1.13 parameter table (run_mode
0x7005, loc_ref 0x7016, limit_spd 0x7017, EPScan_time 0x7026 "1 = 10 ms, +1 = 5 ms more",
canTimeout 0x7028 "20000 is 1 s"), 4.1.14 the read example (``0x11 0x00FD 0x7F: 1E 70 00 00
00 00 00 00``, answer ``... F0 41`` = 30.0), 4.4 example code (V/T/KP/KD ranges per model),
6.3-6.17 MIT protocol (``FF x7 FC``/``FD``/``FE``, ``FF x6 FF FB``, ``FF x6 01 F9``, parameter
write ``4 7F: 29 70 00 00 00 00 00 00``).
"""

from __future__ import annotations

import math
import struct
from typing import Any

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mavservo.servos import NO_FAULT, Fault, get_profile
from mavservo.servos.robstride.profile import (
    FEEDBACK_FAULT_BITS,
    MODELS,
    Robstride,
    RobstrideOptions,
    faults_from_word,
    report_counts,
    report_period_s,
)
from mavservo.sim.servo import SimServo


def ext(arbitration_id: int, hex_data: str) -> can.Message:
    return can.Message(
        arbitration_id=arbitration_id, is_extended_id=True, data=bytes.fromhex(hex_data)
    )


def frames(messages: list[can.Message]) -> list[tuple[int, bool, str]]:
    return [(m.arbitration_id, m.is_extended_id, m.data.hex()) for m in messages]


def test_registered_under_its_yaml_name() -> None:
    assert get_profile("robstride") is Robstride


# -- byte-exact vectors (private protocol) ---------------------------------------------------


def test_parameter_write_has_the_manuals_layout() -> None:
    """4.1.7 with the 4.1.14 example's index and value: type 0x12, host 0xFD in bits 15..8,
    motor 0x7F; ``1E 70 00 00`` (loc_kp) then 30.0 as a little-endian float (``00 00 F0 41``)."""
    msg = Robstride(0x7F).param_write(0x701E, struct.pack("<f", 30.0))
    assert frames([msg]) == [(0x1200FD7F, True, "1e7000000000f041")]


def test_position_command_writes_loc_ref_in_radians() -> None:
    msg = Robstride(1).position_command(math.degrees(1.0))
    assert frames([msg]) == [(0x1200FD01, True, "16700000" + "0000803f")]  # 1.0 rad


def test_startup_sets_up_then_enables_alone() -> None:
    """The manual's CSP sequence in two steps: a stop with the clear flag, run_mode 5,
    canTimeout (200 ms x 20 = 4000 = 0x0FA0), EPScan_time for 20 Hz (50 ms: 1 + (50 - 10) / 5
    = 9), limit_spd, active reporting on; then, once the motor reports reset mode, the enable
    alone (queued with the others it would win arbitration over the stop and the run_mode
    write, and the motor would run in operation control mode)."""
    servo = Robstride(1, comm_timeout_ms=200)
    servo.telemetry_hz = 20.0
    servo.position_command(0.0, 360.0)  # the speed limit the scheduler asks for
    assert frames(servo.startup_frames()) == [
        (0x0400FD01, True, "0100000000000000"),  # stop, byte 0 = 1: clear faults
        (0x1200FD01, True, "0570000005000000"),  # run_mode = 5 (CSP)
        (0x1200FD01, True, "28700000a00f0000"),  # canTimeout = 4000
        (0x1200FD01, True, "2670000009000000"),  # EPScan_time = 9 (50 ms)
        (0x1200FD01, True, "17700000db0fc940"),  # limit_spd = 2 pi rad/s
        (0x1800FD01, True, "0102030405060100"),  # active reporting on (F_CMD = 1)
    ]
    assert servo.needs_startup()
    servo.decode(ext(0x180001FD, "7fff7fff7fff00fa"), 0.0)  # report: reset mode, no fault
    assert servo.needs_startup()
    assert frames(servo.startup_frames()) == [(0x0300FD01, True, "0000000000000000")]


def test_the_enable_alone_only_for_a_motor_set_up_and_clean() -> None:
    """Reset mode without a fault while the active reports (type 0x18) still come: just the
    enable (its own timeout stopped it, or a release); a fault (a clear is due), or reports
    that stopped (a power-cycled motor reports nothing), get the set-up step again."""
    servo = Robstride(1)
    servo.telemetry_hz = 20.0  # reports every 50 ms: still coming within 150 ms
    servo.decode(ext(0x180001FD, "7fff7fff7fff00fa"), 0.0)  # report, reset mode
    servo.decode(ext(0x020001FD, "7fff7fff7fff00fa"), 0.1)  # answer, reset mode
    assert servo.needs_startup()
    assert frames(servo.startup_frames()) == [(0x0300FD01, True, "0000000000000000")]
    servo.decode(ext(0x181001FD, "7fff7fff7fff00fa"), 0.2)  # report, reset mode, stall
    assert len(servo.startup_frames()) == 6
    servo.decode(ext(0x020001FD, "7fff7fff7fff00fa"), 5.0)  # answers only: reports stopped
    assert len(servo.startup_frames()) == 6
    servo.decode(ext(0x188001FD, "7fff7fff7fff00fa"), 5.1)  # report, run mode
    assert not servo.needs_startup()


def test_release_is_a_plain_stop_and_zero_is_type_6() -> None:
    servo = Robstride(3, host_id=0xAA)
    assert frames(servo.release_frames()) == [(0x0400AA03, True, "0000000000000000")]
    assert frames(servo.shutdown_frames()) == frames(servo.release_frames())
    assert frames([servo.set_zero_frame()]) == [(0x0600AA03, True, "0100000000000000")]


def test_report_period_counts() -> None:
    assert [report_counts(hz) for hz in (100, 50, 20, 10, 1)] == [1, 3, 9, 19, 199]
    assert report_counts(1000) == 1  # 10 ms is the fastest the motor reports
    assert report_period_s(19) == pytest.approx(0.1)


# -- feedback ------------------------------------------------------------------------------


def test_feedback_vector() -> None:
    """Type 2, mode 2 (run), over-temperature (bit 18), motor 1, host 0xFD; angle 0xFFFF =
    +4 pi, velocity 0 = -44 rad/s, torque 0x8000 ~ 0, temperature 0x00FA = 25.0 degC."""
    servo = Robstride(1)
    state = servo.decode(ext(0x028401FD, "ffff00008000" + "00fa"), 1.0)
    assert state is not None
    assert state.position_deg == pytest.approx(720.0)
    assert state.velocity_dps == pytest.approx(math.degrees(-44.0))
    assert state.current_a == pytest.approx(0.0, abs=1e-3)
    assert state.temperature_c == pytest.approx(25.0)
    assert state.faults == Fault.OVER_TEMPERATURE
    assert not servo.needs_startup()
    servo.decode(ext(0x020001FD, "7fff7fff7fff00fa"), 1.1)  # reset mode: enable again
    assert servo.needs_startup()


@pytest.mark.parametrize(("bit", "fault"), sorted(FEEDBACK_FAULT_BITS.items()))
def test_every_feedback_fault_bit_is_named(bit: int, fault: Fault) -> None:
    state = Robstride(1).decode(ext(0x02800000 | 1 << bit | 0x01FD, "7fff7fff7fff00fa"), 0.0)
    assert state is not None and state.faults == fault


def test_active_reports_and_fault_frames_are_decoded() -> None:
    servo = Robstride(1)
    report = servo.decode(ext(0x188001FD, "7fff7fff7fff0100"), 0.0)
    assert report is not None and report.temperature_c == pytest.approx(25.6)
    fault = servo.decode(ext(0x150001FD, "02400000" + "01000000"), 0.1)  # driver chip, stall
    assert fault is not None and fault.faults == Fault.DRIVER | Fault.STALL
    assert faults_from_word(1 << 6) == Fault.OTHER  # an undocumented bit is never "no fault"
    assert faults_from_word(0) == NO_FAULT


@pytest.mark.parametrize(
    "msg",
    [
        ext(0x028002FD, "7fff7fff7fff00fa"),  # another motor
        ext(0x028001AA, "7fff7fff7fff00fa"),  # another host
        ext(0x118001FD, "7fff7fff7fff00fa"),  # a parameter read answer
        ext(0x028001FD, "7fff7fff7fff"),  # short
        can.Message(arbitration_id=0xFD, is_extended_id=False, data=bytes(8)),
        can.Message(arbitration_id=0x028001FD, is_extended_id=True, is_remote_frame=True, dlc=8),
    ],
)
def test_foreign_and_hostile_frames_are_not_replies(msg: can.Message) -> None:
    servo = Robstride(1)
    assert not servo.is_reply(msg)
    assert servo.decode(msg, 0.0) is None


# -- options and ranges ----------------------------------------------------------------------


def test_out_of_range_angles_are_refused_and_speeds_saturate() -> None:
    servo = Robstride(1)
    with pytest.raises(ValueError, match="outside"):
        servo.position_command(721.0)
    with pytest.raises(ValueError):
        servo.position_command(math.nan)
    servo.position_command(0.0, 1e9)
    limit = servo.startup_frames()[4]
    assert struct.unpack_from("<f", bytes(limit.data), 4)[0] == pytest.approx(44.0)  # RS01


def test_gains_beyond_the_models_range_are_refused() -> None:
    RobstrideOptions(model="RS03", kp=4000.0, kd=50.0)
    with pytest.raises(ValueError, match="kp/kd of a RS01"):
        RobstrideOptions(model="RS01", kp=600.0)
    with pytest.raises(ValueError):
        RobstrideOptions.model_validate({"model": "RS09"})
    with pytest.raises(ValueError):
        RobstrideOptions.model_validate({"host": 1})


# -- MIT protocol ------------------------------------------------------------------------------


def test_mit_mode_vectors() -> None:
    """6.5 packing with an RS01's ranges (+-12.57 rad, +-44 rad/s, +-17 N m, kp 0..500, kd
    0..5): 0 deg, kp 20, kd 1 -> 7FFF 7FF 0A3 333 7FF; 6.17 parameter write on 0x400 | id."""
    servo = Robstride(0x7F, protocol="mit")
    assert frames([servo.position_command(0.0)]) == [(0x7F, False, "7fff7ff0a33337ff")]
    assert frames([servo.param_write(0x7029, bytes(4))]) == [(0x47F, False, "2970000000000000")]
    assert frames(servo.startup_frames())[2:] == [
        (0x7F, False, "fffffffffffffffb"),  # clear faults
        (0x7F, False, "fffffffffffffffc"),  # enable
        (0x7F, False, "ffffffffffff01f9"),  # active reporting on
    ]
    assert frames(servo.release_frames()) == [(0x7F, False, "fffffffffffffffd")]
    reply = can.Message(
        arbitration_id=0xFD, is_extended_id=False, data=bytes.fromhex("7f" + "7fff7ff7ff" + "00fa")
    )
    state = servo.decode(reply, 0.0)
    assert state is not None and state.temperature_c == pytest.approx(25.0)
    assert state.position_deg == pytest.approx(0.0, abs=0.02)


# -- the simulated motor ----------------------------------------------------------------------


def started(**options: Any) -> tuple[Robstride, SimServo]:
    profile = Robstride(1, **options)
    profile.telemetry_hz = 20.0
    sim = SimServo(
        "robstride", 1, seed=1, reply_latency_s=0.0, status_rate_hz=20.0, options=profile.options
    )
    return profile, sim


def start_up(profile: Robstride, sim: SimServo, now: float) -> None:
    """The start-up frames, again while the profile asks for them (as the scheduler does)."""
    for _ in range(3):
        for msg in profile.startup_frames():
            assert len(send(profile, sim, msg, now)) == profile.replies_per_lifecycle
        if not profile.needs_startup():
            return


def send(profile: Robstride, sim: SimServo, msg: can.Message, now: float) -> list[can.Message]:
    replies = [reply for _, reply in sim.receive(msg, now)]
    for reply in replies:
        assert profile.decode(reply, now) is not None
    return replies


def pushes(profile: Robstride, sim: SimServo, start: float, end: float) -> list[can.Message]:
    out = []
    t = start
    while t <= end + 1e-9:
        for _, reply in sim.poll(t):
            assert profile.decode(reply, t) is not None
            out.append(reply)
        t += 0.01
    return out


def test_a_disabled_motor_does_not_move_and_reports_nothing_before_start_up() -> None:
    profile, sim = started()
    send(profile, sim, profile.position_command(30.0, 180.0), 0.0)
    assert pushes(profile, sim, 0.0, 1.0) == []  # active reporting is off at power-up
    assert sim.position_deg == pytest.approx(0.0)
    assert not sim.enabled


def test_start_up_enables_moves_and_reports_at_the_programmed_rate() -> None:
    profile, sim = started()
    start_up(profile, sim, 0.0)
    assert sim.enabled and not profile.needs_startup()
    t = 0.0
    for _ in range(20):  # keep the motor's own timeout fed
        send(profile, sim, profile.position_command(30.0, 180.0), t)
        pushes(profile, sim, t, t + 0.09)
        t += 0.1
    reports = pushes(profile, sim, t, t + 1.0)
    assert 18 <= len(reports) <= 21  # 20 Hz
    assert sim.position_deg == pytest.approx(30.0, abs=0.5)
    assert profile.last_state is not None
    assert profile.last_state.position_deg == pytest.approx(30.0, abs=0.5)


def test_its_own_timeout_stops_it_and_the_reports_ask_for_a_start_up() -> None:
    """canTimeout 100 ms: silent host -> reset mode; the reports go on and say so, so the
    profile asks the scheduler to enable again; after the start-up frames it moves again."""
    profile, sim = started(comm_timeout_ms=100)
    start_up(profile, sim, 0.0)
    send(profile, sim, profile.position_command(10.0, 180.0), 0.0)
    pushes(profile, sim, 0.0, 0.5)
    assert not sim.enabled
    assert profile.needs_startup()
    start_up(profile, sim, 0.6)
    assert sim.enabled and not profile.needs_startup()


def test_a_fault_stops_the_motor_and_shows_until_cleared() -> None:
    profile, sim = started()
    start_up(profile, sim, 0.0)
    sim.faults.over_current = True
    reports = pushes(profile, sim, 0.0, 0.3)
    assert reports and profile.last_state is not None
    assert Fault.OVER_CURRENT in profile.last_state.faults
    assert not sim.enabled and profile.needs_startup()
    sim.faults.over_current = False
    pushes(profile, sim, 0.3, 0.5)
    assert Fault.OVER_CURRENT in profile.last_state.faults  # latched until the clear flag
    start_up(profile, sim, 0.6)
    assert profile.last_state.faults == NO_FAULT and sim.enabled


def test_it_answers_only_in_its_protocol_and_the_profile_says_which() -> None:
    """A motor switched to MIT ignores private frames, and its MIT answers are recognised by a
    private-protocol profile (and the other way round) as advice naming the option."""
    private = Robstride(1)
    mit_motor = SimServo("robstride", 1, options=RobstrideOptions(protocol="mit"))
    for msg in private.startup_frames():
        assert mit_motor.receive(msg, 0.0) == []
    mit_profile = Robstride(1, protocol="mit")
    answers = [r for m in mit_profile.startup_frames() for _, r in mit_motor.receive(m, 0.0)]
    advice = [private.diagnose(r) for r in answers]
    assert any(a and "options.protocol: mit" in a for a in advice), advice
    private_motor = SimServo("robstride", 1)
    answers = [r for m in private.startup_frames() for _, r in private_motor.receive(m, 0.0)]
    assert answers and all(not mit_profile.is_reply(r) for r in answers)
    assert "options.protocol: private" in str(mit_profile.diagnose(answers[0]))
    assert "options.host_id: 0xFD" in str(Robstride(1, host_id=0xAA).diagnose(answers[0]))
    assert private.diagnose(answers[0]) is None  # its own answer needs no advice
    assert "never answered in the private protocol" in str(private.silence_hint())


# -- round trips ---------------------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(
    model=st.sampled_from(sorted(MODELS)),
    angle=st.floats(-720.0, 720.0),
    velocity=st.floats(-2000.0, 2000.0),
    temperature=st.floats(-20.0, 150.0),
)
def test_feedback_round_trips_through_the_device(
    model: str, angle: float, velocity: float, temperature: float
) -> None:
    profile, sim = started(model=model)
    sim.position_deg, sim.velocity_dps, sim.temperature_c = angle, velocity, temperature
    device = sim._device  # noqa: SLF001 - the device's own encoder
    state = profile.decode(device.feedback(0x02), 0.0)  # type: ignore[attr-defined]
    assert state is not None
    assert state.position_deg == pytest.approx(angle, abs=profile.resolution_deg)
    v_max = math.degrees(MODELS[model].v_max_rad_s)
    expected_v = max(-v_max, min(v_max, velocity))
    assert state.velocity_dps == pytest.approx(expected_v, abs=2 * v_max / 65535 + 1e-9)
    assert state.temperature_c == pytest.approx(max(0.0, temperature), abs=0.051)


@settings(max_examples=60, deadline=None)
@given(angle=st.floats(-720.0, 720.0), speed=st.floats(1.0, 2000.0))
def test_position_writes_round_trip(angle: float, speed: float) -> None:
    msg = Robstride(5).position_command(angle, speed)
    index, _, value = struct.unpack("<HHf", bytes(msg.data))
    assert index == 0x7016
    assert math.degrees(value) == pytest.approx(angle, rel=1e-6, abs=1e-4)


# -- independent implementations ----------------------------------------------------------------


class FakeChannel:
    """Stands in for the socketcan bus the PyPI drivers open: records what they send and
    answers with queued frames."""

    def __init__(self, answers: list[can.Message]) -> None:
        self.sent: list[can.Message] = []
        self.answers = answers

    def send(self, msg: can.Message) -> None:
        self.sent.append(msg)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        return self.answers.pop(0) if self.answers else None


def dynamics_bus(answers: list[can.Message]) -> Any:
    rd = pytest.importorskip("robstride_dynamics.bus")
    bus = rd.RobstrideBus("fake", {"m": rd.Motor(1, "rs-01")})
    bus.host_id = 0xFD
    bus.channel_handler = FakeChannel(answers)
    return bus


def test_robstride_dynamics_sends_the_same_frames() -> None:
    """Its enable, disable and loc_ref write (with its host id set to ours) are ours byte for
    byte; it writes no clear-faults flag on disable, as the manual's "0 when running"."""
    rd_protocol = pytest.importorskip("robstride_dynamics.protocol")
    feedback = ext(0x028001FD, "7fff7fff7fff00fa")
    bus = dynamics_bus([feedback] * 3)
    bus.enable("m")
    bus.disable("m")
    bus.write("m", rd_protocol.ParameterType.POSITION_TARGET, 1.0)
    sent, bus.channel_handler = bus.channel_handler.sent, None  # its __del__ would disable
    ours = Robstride(1)
    assert frames(sent) == frames(
        [
            ours.private_frame(3, bytes(8)),
            ours.release_frames()[0],
            ours.position_command(math.degrees(1)),
        ]
    )


@settings(max_examples=40, deadline=None)
@given(
    angle=st.integers(0, 0xFFFF),
    velocity=st.integers(0, 0xFFFF),
    torque=st.integers(0, 0xFFFF),
    temperature=st.integers(0, 2000),
)
def test_robstride_dynamics_decodes_our_feedback_alike(
    angle: int, velocity: int, torque: int, temperature: int
) -> None:
    """Its scaling is ``(u / 0x7FFF - 1) x range``, ours the manual's ``u x 2 range / 65535 -
    range``: they differ by under two counts. Its table agrees with the manuals for the RS01
    (+-44 rad/s, +-17 N m) but not for other models (its RS00 +-50 / +-17, RS03 +-50 rad/s,
    RS05 +-33 / +-17, RS06 +-20 / +-60; the RS00/03/05/06 manuals' example code says
    +-33 / +-14, +-20 / +-60, +-50 / +-5.5, +-50 / +-36): we follow the manuals."""
    msg = ext(0x028001FD, struct.pack(">HHHH", angle, velocity, torque, temperature).hex())
    bus = dynamics_bus([msg])
    position, speed, torque_nm, temp = bus.receive_status_frame("m")
    bus.channel_handler = None  # its __del__ would disable the motor
    state = Robstride(1).decode(msg, 0.0)
    assert state is not None
    assert math.radians(state.position_deg) == pytest.approx(position, abs=2 * 8 * math.pi / 65535)
    assert math.radians(state.velocity_dps) == pytest.approx(speed, abs=2 * 88 / 65535)
    assert state.current_a * MODELS["RS01"].torque_constant_nm_per_a == pytest.approx(
        torque_nm, abs=2 * 34 / 65535
    )
    assert state.temperature_c == pytest.approx(temp)


def test_robstride_client_parses_our_feedback_and_writes_loc_ref_alike() -> None:
    """``robstride`` (PyPI): the same ids, write layout and fault bits 16..19 and 21; it names
    bit 20 a Hall-encoder fault (the CyberGear manual's), the Robstride manuals a stall /
    overload: we follow the Robstride manual. It reads the mode from bit 22 alone, the manual
    from bits 23..22."""
    client_module = pytest.importorskip("robstride.client")
    feedback = ext(0x028F01FD, "7fff7fff7fff00fa")  # run mode; bits 16, 17, 18, 19
    channel = FakeChannel([feedback])
    client = client_module.Client(channel, host_can_id=0xFD)
    parsed = client.write_param(1, "loc_ref", 1.0)
    assert frames(channel.sent) == frames([Robstride(1).position_command(math.degrees(1.0))])
    names = {e.name for e in parsed.errors}
    assert names == {"Undervoltage", "Overcurrent", "Overtemp", "MagneticEncodingFault"}
    state = Robstride(1).decode(feedback, 0.0)
    assert state is not None
    assert state.faults == Fault.LOW_VOLTAGE | Fault.OVER_CURRENT | Fault.OVER_TEMPERATURE | (
        Fault.ENCODER
    )
    assert parsed.temp == pytest.approx(state.temperature_c)
    assert parsed.angle == pytest.approx(math.radians(state.position_deg), abs=1e-3)


def test_an_mit_command_never_reads_as_a_special_frame() -> None:
    """Six 0xFF lead every MIT special command (F9 reporting, FB clear, FC enable, FD stop or
    protocol). The bridge's commands carry velocity 0 (byte 2 = 0x7F), so even the top of the
    position range with the model's largest gains cannot look like one (the profile refuses
    such a frame anyway)."""
    for model, kp, kd in (("RS01", 500.0, 5.0), ("RS03", 5000.0, 100.0)):
        servo = Robstride(1, model=model, protocol="mit", kp=kp, kd=kd)
        for angle in (math.degrees(12.57), -math.degrees(12.57), 0.0):
            data = servo.position_command(angle).data
            assert data[:6] != b"\xff" * 6 and data[2] == 0x7F


@settings(max_examples=60, deadline=None)
@given(
    model=st.sampled_from(sorted(MODELS)),
    angle=st.floats(-700.0, 700.0),
    temperature=st.floats(0.0, 79.0),  # hotter is an over-temperature: a fault report
)
def test_mit_feedback_round_trips_through_the_device(
    model: str, angle: float, temperature: float
) -> None:
    """The MIT device answers with the shared packing (:mod:`mavservo.servos.mit`) and the
    temperature x 10 after it; the profile reads back what it sent, within one count."""
    profile, sim = started(model=model, protocol="mit")
    sim.position_deg, sim.temperature_c = angle, temperature
    start_up(profile, sim, 0.0)
    state = profile.decode(sim._device.feedback(0x02), 0.0)  # type: ignore[attr-defined]  # noqa: SLF001
    assert state is not None
    assert state.position_deg == pytest.approx(angle, abs=profile.resolution_deg)
    assert state.temperature_c == pytest.approx(temperature, abs=0.051)


def test_the_scheduler_advises_once_per_servo(caplog: pytest.LogCaptureFixture) -> None:
    """A frame no servo claims goes to the profiles that can diagnose it; the advice is logged
    and handed to ``on_event`` (the bridge's STATUSTEXT) once per servo, however often the
    motor repeats it."""
    from mavservo.scheduling.runner import Scheduler, ServoSpec

    bus = can.Bus(interface="virtual", channel="robstride-advice", receive_own_messages=False)
    try:
        scheduler = Scheduler(bus, [ServoSpec("hip", Robstride(1))], name="b")
        events: list[str] = []
        scheduler.on_event = events.append
        mit_answer = can.Message(arbitration_id=0xFD, is_extended_id=False, data=b"\x01" + bytes(7))
        for t in range(5):
            assert scheduler.handle_frame(mit_answer, float(t)) is None
    finally:
        bus.shutdown()
    assert len(events) == 1 and events[0].startswith("servo hip: answers in the MIT protocol")
    assert any("options.protocol: mit" in r.getMessage() for r in caplog.records)


def test_start_up_survives_arbitration_on_the_bus() -> None:
    """Everything of a step queued at once on the simulated bus, where the lowest id wins:
    the set-up step with a command, then the enable with a command. Nothing in the first
    step can overtake the stop, the enable goes alone, and the motor runs in position mode
    and follows (sent in one burst, the enable went first and the motor ignored positions)."""
    from mavservo.sim.canbus import SimCanBus

    profile, sim = started(comm_timeout_ms=0)
    bus = SimCanBus([sim])

    def play(messages: list[can.Message], t: float, until: float) -> None:
        for msg in messages:
            bus.submit(msg, t)
        for _, reply in bus.run_until(until):
            profile.decode(reply, reply.timestamp or until)

    play([*profile.startup_frames(), profile.position_command(20.0, 360.0)], 0.0, 0.3)
    assert not sim.enabled and profile.needs_startup()
    retry = profile.startup_frames()
    assert frames(retry) == [(0x0300FD01, True, "0000000000000000")]
    play([*retry, profile.position_command(20.0, 360.0)], 1.0, 2.0)
    assert sim.enabled and not profile.needs_startup()
    assert sim.position_deg == pytest.approx(20.0, abs=0.5)


def test_a_report_between_a_command_and_its_answer_is_a_push_not_a_late_answer() -> None:
    """The scheduler owes the command an answer (type 2, key "feedback"); an active report
    (type 0x18, key "report") arriving first is a push, and the answer still matches."""
    from mavservo.scheduling.schedule_core import ScheduleCore, ServoSpec, TimingConfig

    profile = Robstride(1)
    core = ScheduleCore([ServoSpec("hip", profile)], TimingConfig(), start=0.0)
    core.submit("hip", 10.0, "test", 0.0)
    for out in core.step(0.0).frames:  # the set-up step and the command, each answered
        assert core.on_reply("hip", 0.001, profile.exchange_key(out.msg)).kind is not None
    core.submit("hip", 20.0, "test", 0.1)
    assert [o.kind for o in core.step(0.1).frames] == ["command"]
    report = ext(0x188001FD, "7fff7fff7fff00fa")
    answer = ext(0x028001FD, "7fff7fff7fff00fa")
    assert core.on_reply("hip", 0.1005, profile.exchange_key(report)).kind is None
    assert core.on_reply("hip", 0.101, profile.exchange_key(answer)).kind == "command"


RIG = """
can: {buses: [{name: bus0, interface: virtual, channel: rs}]}
servos:
  - {name: a, profile: robstride, can_id: 1, limits_deg: [-90, 90], options: A_OPTIONS}
  - {name: b, profile: robstride, can_id: 2, limits_deg: [-90, 90], options: B_OPTIONS}
  - {name: c, profile: robstride, can_id: 3, limits_deg: [-90, 90], options: {protocol: mit}}
  - {name: d, profile: damiao-dm, can_id: 4, limits_deg: [-90, 90], options: {master_id: 0x7D}}
channels: []
"""


def test_check_finds_collisions_through_the_masked_ids() -> None:
    """The motor's answers keep fault and mode bits in the id (masked out): motor 1 answering
    host 2 sends what motor 2 with host 1 is sent (type 0x18), and an MIT motor answering on
    the standard host id 0x7D names itself in byte 0 as Damiao motor 4 does on its master id
    0x7D (low nibble); the defaults do not clash."""
    from mavservo.config import ConfigError, load_config_text

    fine = RIG.replace("A_OPTIONS", "{}").replace("B_OPTIONS", "{}")
    assert len(load_config_text(fine, "rig.yaml").servos) == 4
    crossed = RIG.replace("A_OPTIONS", "{host_id: 2}").replace("B_OPTIONS", "{host_id: 1}")
    with pytest.raises(ConfigError, match="servo 'b' \\(robstride id 2\\) collides"):
        load_config_text(crossed, "rig.yaml")
    shared = fine.replace("can_id: 3", "can_id: 20").replace(
        "{protocol: mit}", "{protocol: mit, host_id: 0x7D}"
    )  # byte 0 = 0x14: Damiao's motor 4 names itself by the low nibble only
    with pytest.raises(ConfigError, match="collides"):
        load_config_text(shared, "rig.yaml")
