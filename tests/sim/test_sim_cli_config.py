"""``mavservo sim --config`` with a full ``mavservo run`` config: the servos it declares.

Before, a config without a ``simulation.servos`` mapping got one ``rmd-x:1`` servo, so a bridge
run against the pty reported every other servo offline.
"""

from __future__ import annotations

import time
from pathlib import Path

import can
import pytest

from mavservo.servos import get_profile
from mavservo.sim.sim_command import build_emulator, build_parser, main
from mavservo.transport.aa55.bus import AA55Bus
from tests.support.signals import default_signal_dispositions
from tests.support.waiting import wait_until

TWO_BUSES = """\
can:
  buses:
    - {name: surfaces, channel: /dev/ttyUSB0, bitrate: 500000, protocol: fixed}
    - {name: gimbal, channel: /dev/ttyUSB1}
servos:
  - {name: aileron, profile: rmd-x, can_id: 1, bus: surfaces, limits_deg: [10, 30],
     neutral_deg: 20}
  - {name: hook, profile: lk, can_id: 9, bus: surfaces}
  - {name: pan, profile: cubemars-ak, can_id: 3, bus: gimbal, telemetry_hz: 25}
"""


def _emulator(path: Path, *options: str):
    return build_emulator(build_parser().parse_args(["--config", str(path), *options]))


def test_the_servos_of_the_first_bus_are_simulated_without_a_simulation_section(
    tmp_path: Path,
):
    config = tmp_path / "rig.yaml"
    config.write_text(TWO_BUSES)
    emulator = _emulator(config)
    assert [(s.profile, s.can_id) for s in emulator.servos] == [("rmd-x", 1), ("lk", 9)]
    assert (emulator.bitrate, emulator.protocol) == (500_000, "fixed")
    aileron = emulator.servos[0]
    assert aileron.position_deg == 10  # starts inside its limits, as the bridge's simulation


def test_bus_chooses_which_buses_servos_are_simulated(tmp_path: Path):
    config = tmp_path / "rig.yaml"
    config.write_text(TWO_BUSES)
    (pan,) = _emulator(config, "--bus", "gimbal").servos
    assert (pan.profile, pan.can_id, pan.status_rate_hz) == ("cubemars-ak", 3, 25)


def test_an_unknown_bus_or_a_bad_config_exits_two_with_the_reason(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    config = tmp_path / "rig.yaml"
    config.write_text(TWO_BUSES)
    assert main(["--config", str(config), "--bus", "nope"]) == 2
    assert "surfaces, gimbal" in capsys.readouterr().err
    bad = tmp_path / "bad.yaml"
    bad.write_text("servos:\n  - {name: a, profile: rmd-x, can_id: yes}\n")
    assert main(["--config", str(bad)]) == 2
    assert f"{bad}:2: servos[0].can_id" in capsys.readouterr().err


def test_a_bus_without_servos_exits_two_instead_of_simulating_a_default_servo(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    config = tmp_path / "rig.yaml"
    config.write_text(
        TWO_BUSES.replace(
            "    - {name: gimbal, channel: /dev/ttyUSB1}\n",
            "    - {name: gimbal, channel: /dev/ttyUSB1}\n"
            "    - {name: aux, channel: /dev/ttyUSB2}\n",
        )
    )
    assert main(["--config", str(config), "--bus", "aux"]) == 2
    err = capsys.readouterr().err
    assert err == f"mavservo sim: --bus aux: no servo of {config} is on bus 'aux'\n"
    # Explicit servos still win over the config's (empty) bus, as for any bus.
    (servo,) = _emulator(config, "--bus", "aux", "--ids", "5").servos
    assert (servo.profile, servo.can_id) == ("rmd-x", 5)


def test_every_declared_servo_answers_on_the_emulated_adapter(tmp_path: Path):
    config = tmp_path / "rig.yaml"
    config.write_text(
        "servos:\n"
        "  - {name: a, profile: rmd-x, can_id: 1}\n"
        "  - {name: b, profile: rmd-x, can_id: 2}\n"
        "  - {name: c, profile: lk, can_id: 7}\n"
    )
    with _emulator(config).start() as emulator, AA55Bus(channel=emulator.path) as bus:
        for profile_name, can_id in (("rmd-x", 1), ("rmd-x", 2), ("lk", 7)):
            profile = get_profile(profile_name)(can_id)
            for request in profile.telemetry_requests():
                bus.send(request)
            states: list[object] = []

            def answered(profile=profile, states=states) -> bool:
                message: can.Message | None = bus.recv(0.05)
                if message is not None:
                    state = profile.decode(message, time.monotonic())
                    if state is not None:
                        states.append(state)
                return bool(states)

            assert wait_until(answered, timeout=10.0), f"{profile_name}:{can_id} did not answer"


def test_sim_gives_each_dronecan_servo_its_own_actuator_id(tmp_path: Path):
    """``mavservo sim --profile dronecan --servos 3``: actuator ids 1..3 (ArduPilot's
    numbering), each node following its own entry of one ArrayCommand built by the ``dronecan``
    package (before, every node was actuator 1 and all three followed the first entry)."""
    import math
    import subprocess
    import sys

    import dronecan
    from dronecan.transport import Transfer

    from mavservo.servos.dronecan.profile import DroneCanServo

    process = subprocess.Popen(
        [sys.executable, "-m", "mavservo", "sim", "--profile", "dronecan", "--servos", "3"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=default_signal_dispositions,
    )
    try:
        assert process.stdout is not None and process.stderr is not None
        path = process.stdout.readline().strip()
        summary = process.stderr.readline()
        assert "servos dronecan:1/a1, dronecan:2/a2, dronecan:3/a3" in summary, summary
        targets = {1: 10.0, 2: -20.0, 3: 30.0}  # degrees, one per actuator id
        command = dronecan.uavcan.equipment.actuator.ArrayCommand(
            commands=[
                dronecan.uavcan.equipment.actuator.Command(
                    actuator_id=actuator, command_type=1, command_value=math.radians(deg)
                )
                for actuator, deg in targets.items()
            ]
        )
        profiles = {n: DroneCanServo(n, actuator_id=n) for n in targets}
        reached: set[int] = set()
        with AA55Bus(channel=path) as bus:
            deadline = time.monotonic() + 20.0
            tid = 0
            while reached != set(targets) and time.monotonic() < deadline:
                transfer = Transfer(transfer_id=tid % 32, source_node_id=100, payload=command)
                tid += 1
                for frame in transfer.to_frames():
                    bus.send(
                        can.Message(
                            arbitration_id=frame.message_id,
                            is_extended_id=True,
                            data=bytes(frame.bytes),
                        )
                    )
                for _ in range(20):  # bounded: a few Status frames between two commands
                    message = bus.recv(0.01)
                    if message is None:
                        continue
                    node = message.arbitration_id & 0x7F
                    if node not in profiles:
                        continue
                    state = profiles[node].decode(message, time.monotonic())
                    if state is not None and abs(state.position_deg - targets[node]) < 1.0:
                        reached.add(node)
        assert reached == set(targets)
    finally:
        process.terminate()
        process.wait(10)
