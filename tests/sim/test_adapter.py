"""The USB-CAN adapter emulator on a real pty, driven by real AA-55 clients.

python-can's own ``seeedstudio`` driver and the project's ``aa55`` interface both talk to it
over the published device path; every injected fault must be visible from the host side.
Waits are bounded (count and time) and only ever used as upper limits.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import can
import pytest

from mavservo.servos import CubeMarsAK, Fault, RmdX, ServoProfile, ServoState
from mavservo.sim.adapter import AdapterEmulator, LineFaults
from mavservo.sim.servo import Faults, Physics, SimServo
from mavservo.transport.aa55.bus import AA55Bus
from tests.support.paths import REPO
from tests.support.signals import default_signal_dispositions

ROOT = REPO


def _reply(bus: can.BusABC, profile: ServoProfile, timeout: float = 0.5) -> ServoState | None:
    """The next frame from ``profile``'s servo, decoded, or None if none comes in time."""
    deadline = time.monotonic() + timeout
    for _ in range(200):
        left = deadline - time.monotonic()
        if left <= 0:
            return None
        msg = bus.recv(timeout=min(left, 0.05))
        if msg is not None and profile.is_reply(msg):
            return profile.decode(msg, time.monotonic())
    return None


def _ask(bus: can.BusABC, profile: ServoProfile, timeout: float = 0.5) -> ServoState | None:
    for request in profile.telemetry_requests():
        bus.send(request)
    return _reply(bus, profile, timeout)


def _unanswered(bus: can.BusABC, asked: ServoProfile, witness: ServoProfile) -> bool:
    """True when ``asked`` does not answer a poll, shown by ordering instead of a fixed wait.

    ``asked`` is polled first, then ``witness``, a servo that answers no sooner: the simulated
    bus sends frames in the order they are due (a lower id first only among frames due
    together, so ``asked`` has the lower id or the witness answers late), so a reply of
    ``asked`` would arrive before the witness's. Every frame up to the witness's reply is read.
    """
    for request in asked.telemetry_requests() + witness.telemetry_requests():
        bus.send(request)
    for _ in range(200):  # bounded: frames of other servos may come in between
        msg = bus.recv(timeout=2.0)
        assert msg is not None, "the witness never answered"
        if asked.is_reply(msg):
            return False
        if witness.is_reply(msg):
            return True
    raise AssertionError("no reply of the witness among 200 frames")


@pytest.fixture
def emulator_factory():
    started: list[AdapterEmulator] = []

    def make(servos, **kwargs) -> AdapterEmulator:
        emulator = AdapterEmulator(servos, **kwargs).start()
        started.append(emulator)
        return emulator

    yield make
    for emulator in started:
        emulator.stop()
        assert emulator.error is None


def test_python_can_seeedstudio_driver_commands_a_simulated_servo(emulator_factory):
    emulator = emulator_factory([SimServo("rmd-x", 1)])
    bus = can.Bus(
        interface="seeedstudio", channel=emulator.path, baudrate=2_000_000, bitrate=1_000_000
    )
    try:
        profile = RmdX(1)
        bus.send(profile.position_command(45.0, 720))
        first = _reply(bus, profile, timeout=2.0)
        assert first is not None  # the A4 command is answered
        state = None
        for _ in range(60):
            state = _ask(bus, profile)
            if state is not None and state.position_deg == 45.0:
                break
            time.sleep(0.05)  # give the servo time to move
        assert state is not None and state.position_deg == 45.0
        assert emulator.settings is not None and emulator.settings.bitrate == 1_000_000
    finally:
        bus.shutdown()


def test_servos_driven_through_the_aa55_interface_converge(emulator_factory):
    emulator = emulator_factory([SimServo("rmd-x", 1), SimServo("cubemars-ak", 2)])
    rmd, cube = RmdX(1, multi_turn_poll_every=2), CubeMarsAK(2)
    with AA55Bus(channel=emulator.path) as bus:
        for target in (30.0, -60.0):
            bus.send(rmd.position_command(target, 720))
            bus.send(cube.position_command(target, 720))
            for _ in range(60):
                rmd_state = _ask(bus, rmd)
                cube_state = _reply(bus, cube)  # pushes at 50 Hz
                if (
                    rmd_state
                    and cube_state
                    and abs(rmd_state.position_deg - target) <= 0.05
                    and abs(cube_state.position_deg - target) <= 0.05
                ):
                    break
            assert rmd_state is not None and rmd_state.position_deg == pytest.approx(
                target, abs=0.05
            )
            assert cube_state is not None and cube_state.position_deg == pytest.approx(
                target, abs=0.05
            )
    assert emulator.canbus.frames > 0 and emulator.load(window=5.0) > 0


def test_dropped_delayed_and_silent_servos_are_seen_from_the_host(emulator_factory):
    servos = [
        SimServo("rmd-x", 1),
        SimServo("rmd-x", 2, faults=Faults(drop_reply_prob=1.0)),
        SimServo("rmd-x", 3, faults=Faults(reply_delay_s=0.3)),
    ]
    emulator = emulator_factory(servos)
    with AA55Bus(channel=emulator.path) as bus:
        assert _ask(bus, RmdX(1)) is not None
        asked = time.monotonic()
        # servo 2 drops its reply; servo 3 answers 0.3 s late: it is the witness
        assert _unanswered(bus, RmdX(2), witness=RmdX(3))
        assert time.monotonic() - asked >= 0.3  # a lower bound set by the fault, not the machine
        assert servos[1].replies_dropped >= 1
        servos[0].faults.silent = True  # faults can be flipped while running
        assert _unanswered(bus, RmdX(1), witness=RmdX(3))


def test_fault_flags_reach_the_host(emulator_factory):
    emulator = emulator_factory(
        [
            SimServo("rmd-x", 1, faults=Faults(over_current=True)),
            SimServo("cubemars-ak", 2, faults=Faults(over_temperature=True)),
        ]
    )
    rmd = RmdX(1, fault_poll_every=1)
    with AA55Bus(channel=emulator.path) as bus:
        rmd_state = _ask(bus, rmd, timeout=2.0)
        cube_state = _reply(bus, CubeMarsAK(2), timeout=2.0)
    assert rmd_state is not None and Fault.OVER_CURRENT in rmd_state.faults
    assert cube_state is not None and cube_state.faults == Fault.OVER_TEMPERATURE


def test_line_corruption_is_visible_to_the_host_decoder(emulator_factory):
    emulator = emulator_factory(
        [SimServo("rmd-x", 1)], line_faults=LineFaults(flip_prob=0.05, burst_prob=0.2), seed=3
    )
    profile = RmdX(1, fault_poll_every=None)
    with AA55Bus(channel=emulator.path) as bus:
        good = sum(_ask(bus, profile, timeout=0.1) is not None for _ in range(40))
        stats = bus.stats()
    assert emulator.line.flipped > 0 and emulator.line.bursts > 0
    assert stats["bytes_discarded"] > 0
    assert good < 40


def test_settings_frame_sets_bitrate_mode_filter_and_protocol(emulator_factory):
    emulator = emulator_factory([SimServo("rmd-x", 1), SimServo("rmd-x", 2)])
    with AA55Bus(channel=emulator.path, bitrate=125_000, protocol="fixed") as bus:
        assert _ask(bus, RmdX(1), timeout=2.0) is not None
        assert (emulator.bitrate, emulator.protocol) == (125_000, "fixed")
    with AA55Bus(channel=emulator.path, mode="loopback") as bus:
        request = RmdX(1).telemetry_requests()[0]
        bus.send(request)
        echo = bus.recv(timeout=2.0)
        assert echo is not None and echo.arbitration_id == request.arbitration_id
        assert _reply(bus, RmdX(1), timeout=0.3) is None  # loopback ignores the bus
    only_servo_2 = [{"can_id": 0x242, "can_mask": 0x7FF, "extended": False}]
    with AA55Bus(channel=emulator.path, can_filters=only_servo_2) as bus:
        assert _ask(bus, RmdX(2), timeout=2.0) is not None
        assert (emulator.filter_id, emulator.mask) == (0x242, 0x7FF)
        filtered_before = emulator.frames_filtered
        assert _unanswered(bus, RmdX(1), witness=RmdX(2))  # 0x241 would win arbitration
        assert emulator.frames_filtered > filtered_before


def test_pulling_and_replugging_the_usb_cable(emulator_factory):
    emulator = emulator_factory([SimServo("rmd-x", 1)])
    bus = AA55Bus(channel=emulator.path)
    try:
        assert _ask(bus, RmdX(1), timeout=2.0) is not None
        emulator.unplug()
        assert not os.path.exists(emulator.path)
        with pytest.raises(can.CanOperationError):
            for _ in range(20):
                bus.send(RmdX(1).telemetry_requests()[0])
                bus.recv(timeout=0.05)
    finally:
        bus.shutdown()
    emulator.replug()
    assert os.path.realpath(emulator.path) == emulator.device
    with AA55Bus(channel=emulator.path) as bus:
        assert _ask(bus, RmdX(1), timeout=2.0) is not None
    assert emulator.plug_count == 2


def test_relaxation_is_visible_without_refresh(emulator_factory):
    physics = Physics(relax_after_s=0.6, relax_rate_dps=200.0)
    emulator = emulator_factory([SimServo("rmd-x", 1, physics)])
    profile = RmdX(1, multi_turn_poll_every=1, fault_poll_every=None)
    with AA55Bus(channel=emulator.path) as bus:
        bus.send(profile.position_command(90.0, 2000))
        positions = []
        for _ in range(40):
            state = _ask(bus, profile)
            if state is not None:
                positions.append(state.position_deg)
            if positions and max(positions) > 80 and positions[-1] < max(positions) - 10:
                break
            time.sleep(0.05)
    assert max(positions) > 80
    assert positions[-1] < max(positions) - 10  # drifted back once the commands stopped


def test_sim_command_prints_the_path_first_and_exits_cleanly_on_sigterm():
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    process = subprocess.Popen(
        [sys.executable, "-m", "mavservo.sim.sim_command", "--servos", "2", "--profile", "rmd-x"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=default_signal_dispositions,
        env=env,
        cwd=ROOT,
    )
    try:
        path = process.stdout.readline().strip()
        assert os.path.exists(path)
        with AA55Bus(channel=path) as bus:
            assert _ask(bus, RmdX(2), timeout=2.0) is not None
    finally:
        process.send_signal(signal.SIGTERM)
        code = process.wait(timeout=10)
    assert code == 0
    assert not os.path.exists(path)


def test_sim_command_reads_servos_and_faults_from_yaml(tmp_path):
    config = tmp_path / "sim.yaml"
    config.write_text(
        "simulation:\n"
        "  servos:\n"
        "    - {id: 4, profile: lk, faults: {silent: true}}\n"
        "    - {id: 5, profile: cubemars-ak}\n"
    )
    from mavservo.sim.sim_command import build_emulator, build_parser

    emulator = build_emulator(build_parser().parse_args(["--config", str(config)]))
    assert [(s.profile, s.can_id, s.faults.silent) for s in emulator.servos] == [
        ("lk", 4, True),
        ("cubemars-ak", 5, False),
    ]
    bad = tmp_path / "bad.yaml"
    bad.write_text("simulation:\n  servos:\n    - {id: 1, profile: nope}\n")
    from mavservo.sim.sim_command import main

    assert main(["--config", str(bad)]) == 2


def test_sim_command_accepts_a_full_mavservo_config(tmp_path):
    config = tmp_path / "mavservo.yaml"
    config.write_text(
        "servos:\n"
        "  - {name: pan, profile: rmd-x, can_id: 1}\n"
        "  - {name: tilt, profile: cubemars-ak, can_id: 2, telemetry_hz: 20}\n"
        "simulation:\n"
        "  servos:\n"
        "    tilt: {faults: {drop_reply_prob: 0.5}}\n"
        "    default: {physics: {relax_after_s: 3}}\n"
    )
    from mavservo.sim.sim_command import build_emulator, build_parser

    emulator = build_emulator(build_parser().parse_args(["--config", str(config)]))
    pan, tilt = emulator.servos
    assert (pan.profile, pan.can_id, pan.physics.relax_after_s) == ("rmd-x", 1, 3)
    assert (tilt.profile, tilt.can_id, tilt.faults.drop_reply_prob) == ("cubemars-ak", 2, 0.5)
    assert tilt.status_rate_hz == 20
