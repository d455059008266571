"""``mavservo doctor`` (issue 29) on the built-in simulation: every family found as configured,
each injected mistake named with its cause and fix, a ``servos:`` block that ``check`` accepts
and that runs clean, and never an enabling or moving frame without ``--allow-enable`` (read
back from the doctor's CAN log)."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from mavservo.app.bridge import Bridge
from mavservo.app.doctor import main as doctor_main
from mavservo.app.doctor.families import ENTER_MOTOR_MODE
from mavservo.app.doctor.recognise import Recogniser, announcements
from mavservo.app.doctor.session import BusDoctor
from mavservo.app.doctor.wire_facts import (
    ODRIVE_AXIS_STATES,
    ODRIVE_ERRORS,
    actuator_status,
    node_status,
    odrive_version,
    odrive_version_request,
    rmdx_identity,
    rmdx_identity_requests,
    robstride_device_id,
)
from mavservo.config import load_config, load_config_text
from mavservo.servos.dronecan.get_node_info import NodeInfoReader
from mavservo.sim.bus_simulation import wired_servos
from mavservo.sim.servo import SimServo
from mavservo.sim.slcan import SlcanEmulator
from mavservo.transport.bus_factory import BusRequest, OpenedBus, open_bus
from tests.app.test_run_cli import REPO
from tests.support.waiting import wait_until


def run_doctor(
    capsys: pytest.CaptureFixture[str],
    config: Path,
    tmp_path: Path,
    *extra: str,
    listen: float = 1.2,
) -> tuple[int, str, Path]:
    """The doctor in this process; its exit code, its report, its CAN log. ``listen``: 1.2 s
    hears a DroneCAN NodeStatus (1 Hz); families that push faster need less."""
    logs = tmp_path / "doctor-logs"
    code = doctor_main([str(config), "--listen", str(listen), "--log-dir", str(logs), *extra])
    out = capsys.readouterr().out
    [log] = list(logs.glob("doctor-*.asc"))
    return code, out, log


def suggested(out: str) -> dict[str, Any]:
    """The YAML block the doctor printed (everything after its header comment)."""
    _, _, block = out.partition("# mavservo doctor: what bus bus0 needs (paste into your config)")
    document = yaml.safe_load(block)
    assert isinstance(document, dict) and document["servos"], out
    return document


def write_config(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "bus.yaml"
    path.write_text(text)
    return path


#: The shipped family configs, with the flags each needs: MIT-mode motors answer only when
#: enabled, and the simulated Robstride answers no read.
FAMILIES = [
    ("slcan.yaml", ()),  # rmd-x, lk, cubemars-ak through python-can's slcan
    ("damiao.yaml", ()),
    ("odrive.yaml", ()),
    ("dronecan.yaml", ()),
    ("cubemars-mit.yaml", ("--allow-enable",)),
    ("robstride.yaml", ("--allow-enable",)),
]


#: What the doctor learns beyond "it answers" (state, identity, mode registers).
IDENTIFIED = {
    # MyActuator V4.2 2.32 and 2.29: the simulated RMD-X answers the document's examples
    "slcan.yaml": ["rmd-x id 1: OK", "model X8S2V10, software 2022-02-06"],
    "damiao.yaml": [
        "CTRL_MODE register: mit",
        # the simulated DM-J powers up in MIT mode
        "it answers in mit mode, configured position-velocity",
    ],
    "odrive.yaml": ["ODrive heartbeat: IDLE, errors: none"],
    "dronecan.yaml": ["DroneCAN node 11: NodeStatus OK, OPERATIONAL"],
}


@pytest.mark.parametrize(("config_name", "flags"), FAMILIES)
def test_doctor_finds_every_family_as_configured(
    config_name: str, flags: tuple[str, ...], capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    path = REPO / "config" / config_name
    code, out, log = run_doctor(capsys, path, tmp_path, "--no-bitrate-search", *flags)
    assert code == 0, out
    for servo in load_config(path).servos:
        assert f"{servo.name:<12} {servo.profile} id {servo.can_id}: OK" in out, out
    for phrase in IDENTIFIED.get(config_name, ()):
        assert phrase in out, (phrase, out)
    if not flags:
        assert_nothing_enabled_or_moved(path, log)


def _frames_sent(log: Path) -> list[can.Message]:
    with can.LogReader(str(log)) as reader:
        return [m for m in reader if not m.is_rx]


def assert_nothing_enabled_or_moved(path: Path, log: Path) -> None:
    """Every frame the doctor sent, read back from its CAN log, played to a fresh simulated
    servo of each configured kind whose motor is off: none turns it on or moves it."""
    sent = _frames_sent(log)
    assert not any(bytes(m.data) == ENTER_MOTOR_MODE for m in sent)
    for servo in load_config(path).servos:
        motor = SimServo(servo.profile, servo.can_id, options=servo.profile_options())
        motor.disable(0.0)
        for k, msg in enumerate(sent):
            motor.receive(msg, 0.01 * (k + 1))
        assert not motor.enabled and motor.commands == 0, (servo.name, sent)


@pytest.mark.parametrize("config_name", ["cubemars-mit.yaml", "robstride.yaml"])
def test_doctor_never_enables_or_moves_without_allow_enable(
    config_name: str, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """The families whose motors answer only when enabled: without the flag the doctor says
    so and sends nothing that enables them."""
    path = REPO / "config" / config_name
    code, out, log = run_doctor(capsys, path, tmp_path, "--no-bitrate-search")
    assert code == 1 and "--allow-enable" in out, out
    assert_nothing_enabled_or_moved(path, log)


def test_allow_enable_is_what_sends_the_enable_frame(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """The check above can fail: with --allow-enable the same log holds enter-motor-mode."""
    path = REPO / "config" / "cubemars-mit.yaml"
    _, _, log = run_doctor(capsys, path, tmp_path, "--no-bitrate-search", "--allow-enable")
    assert any(bytes(m.data) == ENTER_MOTOR_MODE for m in _frames_sent(log))


MISTAKES = {
    "wrong bitrate (slcan)": (
        "can:\n  buses:\n    - {name: bus0, interface: slcan, channel: sim, bitrate: 1000000,\n"
        "       options: {sleep_after_open: 0}}\n"
        "servos:\n  - {name: a, profile: rmd-x, can_id: 1}\n"
        "simulation:\n  bus_bitrates: {bus0: 500000}\n",
        ["WRONG BITRATE", "valid traffic at 500 kbit/s", "`bitrate: 500000`"],
    ),
    "wrong id": (
        "servos:\n  - {name: a, profile: rmd-x, can_id: 1}\n  - {name: b, profile: rmd-x, "
        "can_id: 2}\nsimulation:\n  servos:\n    b: {can_id: 7}\n",
        ["b            rmd-x id 2: wrong id", "answered on id 7", "set `can_id: 7`"],
    ),
    "servo mode under a MIT config": (
        "servos:\n  - {name: c, profile: cubemars-ak-mit, can_id: 3}\n"
        "simulation:\n  servos:\n    c: {profile: cubemars-ak}\n",
        ["wrong mode: heard cubemars-ak from id 3", "servo mode", "`profile: cubemars-ak`"],
    ),
    "wrong bitrate (aa55, pushing servo)": (
        "can:\n  buses:\n    - {name: bus0, interface: aa55, channel: sim, bitrate: 1000000}\n"
        "servos:\n  - {name: c, profile: cubemars-ak, can_id: 3}\n"
        "simulation:\n  bus_bitrates: {bus0: 250000}\n",
        ["WRONG BITRATE", "valid traffic at 250 kbit/s"],
    ),
}


@pytest.mark.parametrize("name", list(MISTAKES))
def test_doctor_names_each_injected_mistake_and_its_fix_runs_clean(
    name: str, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    text, expected = MISTAKES[name]
    path = write_config(tmp_path, text)
    code, out, _ = run_doctor(capsys, path, tmp_path, listen=0.4)
    assert code == 1, out
    for phrase in expected:
        assert phrase in out, (phrase, out)
    # the block replaces the config's sections: `check` accepts it, and the bridge then runs
    # with every servo answering, nothing lost
    document = yaml.safe_load(text)
    document.update(suggested(out))
    fixed = tmp_path / "fixed.yaml"
    fixed.write_text(yaml.safe_dump(document))
    config = load_config(fixed)
    bridge = Bridge(config, log_dir=False)
    bridge.start()
    try:
        assert wait_until(lambda: all(r["online"] for r in bridge.status_rows()), 10.0), out
        time.sleep(0.5)
    finally:
        summary = bridge.stop()
    for servo in config.servos:
        frames = summary["servos"][servo.name]["frames"]
        assert frames["received"] > 0 and frames["lost"] == 0, (servo.name, frames)


def test_odrive_in_error_and_on_another_id(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    path = write_config(
        tmp_path,
        "servos:\n  - {name: pan, profile: odrive, can_id: 1}\n"
        "  - {name: tilt, profile: odrive, can_id: 2}\n"
        "simulation:\n  servos:\n    pan: {faults: {over_current: true}}\n    tilt: {can_id: 5}\n",
    )
    code, out, _ = run_doctor(capsys, path, tmp_path, "--no-bitrate-search")
    assert code == 1
    assert "pan          odrive id 1: ODrive in error: CURRENT_LIMIT_VIOLATION" in out, out
    assert "Clear_Errors" in out
    assert "tilt         odrive id 2: wrong id" in out and "set `can_id: 5`" in out
    assert suggested(out)["servos"][1]["can_id"] == 5


def test_dronecan_node_alive_with_another_actuator_id(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    path = write_config(
        tmp_path,
        "servos:\n  - {name: a, profile: dronecan, can_id: 11, options: {actuator_id: 1}}\n"
        "simulation:\n  servos:\n    a: {options: {actuator_id: 4}}\n",
    )
    code, out, _ = run_doctor(capsys, path, tmp_path, "--no-bitrate-search")
    assert code == 1
    assert "node 11 is alive and reports actuator 4, configured 1" in out, out
    assert "DroneCAN node 11: NodeStatus OK, OPERATIONAL" in out
    assert suggested(out)["servos"][0]["options"]["actuator_id"] == 4


def test_scan_finds_an_unconfigured_servo_and_lists_it(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """``--scan rmd-x --ids 1-32`` with one RMD-X configured and a second one on the bus that
    nobody configured (simulated as a servo whose real id differs and another kept)."""
    path = write_config(
        tmp_path,
        "servos:\n  - {name: a, profile: rmd-x, can_id: 1}\n  - {name: b, profile: lk, can_id: 2}\n"
        "simulation:\n  servos:\n    b: {profile: rmd-x, can_id: 9}\n",
    )
    code, out, log = run_doctor(
        capsys, path, tmp_path, "--no-bitrate-search", "--scan", "rmd-x", "--ids", "1-32"
    )
    assert "rmd-x 9" in out, out
    # found by the scan, not configured: said with who it is (the reads below were not shown)
    assert (
        "(not configured) rmd-x id 9: answered the doctor's requests; "
        "model X8S2V10, software 2022-02-06" in out
    ), out
    # every id is polled; only the ids that answered get the model and software-date reads
    # (MyActuator V4.2 0xB5, 0xB2), which would triple a scan's time on every id
    sent = [(m.arbitration_id, m.data[0]) for m in _frames_sent(log) if not m.is_extended_id]
    assert {i for i, command in sent if command == 0x9C} >= set(range(0x141, 0x161))
    assert {i for i, command in sent if command in (0xB5, 0xB2)} == {0x141, 0x149}
    names = [entry["name"] for entry in suggested(out)["servos"]]
    assert "rmd_x_9" in names or any(e.get("can_id") == 9 for e in suggested(out)["servos"]), out


def test_an_invalid_config_is_refused_with_its_line(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    path = write_config(tmp_path, "servos:\n  - {name: a, profile: rmd-x, can_id: 99}\n")
    assert doctor_main([str(path)]) == 2
    assert "bus.yaml:2:" in capsys.readouterr().err


# ---------------------------------------------------------------- wire facts, independently


def test_odrive_tables_match_odrives_own_dbc() -> None:
    cantools = pytest.importorskip("cantools")
    odrive_can = pytest.importorskip("odrive_can")
    dbc = Path(odrive_can.__file__).parent / "dbc" / "odrive-cansimple-0.6.10.dbc"
    heartbeat = cantools.database.load_file(str(dbc)).get_message_by_name("Axis0_Heartbeat")
    states = {int(v): str(n) for v, n in heartbeat.get_signal_by_name("Axis_State").choices.items()}
    errors = {int(v): str(n) for v, n in heartbeat.get_signal_by_name("Axis_Error").choices.items()}
    for value, name in ODRIVE_AXIS_STATES.items():
        assert states[value] == name
    for bit, name in ODRIVE_ERRORS.items():
        assert errors[bit] == name


def test_node_status_decoding_matches_the_dronecan_package() -> None:
    dronecan = pytest.importorskip("dronecan")
    message = dronecan.uavcan.protocol.NodeStatus(uptime_sec=1234, health=2, mode=1)
    transfer = dronecan.transport.Transfer(
        transfer_id=5, source_node_id=42, payload=message, transfer_priority=16
    )
    [raw] = transfer.to_frames()
    frame = can.Message(arbitration_id=raw.message_id, data=bytes(raw.bytes), is_extended_id=True)
    status = node_status(frame)
    assert status is not None
    assert (status.node_id, status.uptime_s, status.health, status.mode) == (
        42,
        1234,
        "ERROR",
        "INITIALIZATION",
    )
    assert node_status(can.Message(arbitration_id=42, is_extended_id=False)) is None


def test_odrive_version_answer_matches_the_dbc() -> None:
    cantools = pytest.importorskip("cantools")
    odrive_can = pytest.importorskip("odrive_can")
    dbc = Path(odrive_can.__file__).parent / "dbc" / "odrive-cansimple-0.6.10.dbc"
    message = cantools.database.load_file(str(dbc)).get_message_by_name("Axis0_Get_Version")
    data = message.encode(
        {
            "Protocol_Version": 2,
            "Hw_Version_Major": 3,
            "Hw_Version_Minor": 6,
            "Hw_Version_Variant": 56,
            "Fw_Version_Major": 0,
            "Fw_Version_Minor": 6,
            "Fw_Version_Revision": 10,
            "Fw_Version_Unreleased": 0,
        }
    )
    answer = can.Message(arbitration_id=3 << 5 | message.frame_id, data=data, is_extended_id=False)
    assert odrive_version(answer) == (3, "hardware 3.6-56, firmware 0.6.10")
    request = odrive_version_request(3)
    assert request.is_remote_frame and request.arbitration_id == 0x60


def test_robstride_device_id_answer() -> None:
    answer = can.Message(
        arbitration_id=0 << 24 | 0x07 << 8 | 0xFE, data=bytes(range(8)), is_extended_id=True
    )
    assert robstride_device_id(answer) == (7, "MCU id 0x0001020304050607")
    feedback = can.Message(arbitration_id=2 << 24 | 0x07 << 8 | 0xFD, data=bytes(8))
    assert robstride_device_id(feedback) is None


def test_rmdx_identity_reads_are_the_documents_bytes() -> None:
    """MyActuator "Servo Motor Control Protocol" V4.2 (2024.05): 2.32.2 (B5) and 2.29.2 (B2)
    are the command byte and seven zeros on 0x140 + id; the replies of 2.32.4 and 2.29.4 read
    as the document reads them; a garbled or foreign answer reads as nothing."""
    requests = rmdx_identity_requests(1)
    assert [(m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in requests] == [
        (0x141, False, bytes.fromhex("B5 00 00 00 00 00 00 00")),
        (0x141, False, bytes.fromhex("B2 00 00 00 00 00 00 00")),
    ]

    def reply(can_id: int, hex_data: str, *, extended: bool = False) -> can.Message:
        return can.Message(
            arbitration_id=can_id, data=bytes.fromhex(hex_data), is_extended_id=extended
        )

    assert rmdx_identity(reply(0x241, "B5 58 38 53 32 56 31 30")) == (1, "model X8S2V10")
    assert rmdx_identity(reply(0x241, "B2 00 00 00 2E 89 34 01")) == (1, "software 2022-02-06")
    assert rmdx_identity(reply(0x260, "B5 58 38 00 00 00 00 00")) == (32, "model X8")
    for foreign in (
        reply(0x241, "B5 58 0A 53 32 56 31 30"),  # a control character: not a model name
        reply(0x241, "B5 00 00 00 00 00 00 00"),  # no name
        reply(0x241, "B2 00 00 00 FF FF FF FF"),  # not a date
        reply(0x241, "B2 01 00 00 2E 89 34 01"),  # bytes 1..3 are zero in the document
        reply(0x141, "B5 58 38 53 32 56 31 30"),  # a request, not a reply
        reply(0x261, "B5 58 38 53 32 56 31 30"),  # id 33: outside 1..32
        reply(0x241, "B5 58 38 53 32 56 31 30", extended=True),
        reply(0x241, "9C 00 00 00 00 00 00 00"),
    ):
        assert rmdx_identity(foreign) is None, foreign


@given(
    st.integers(0, 0x1FFFFFFF),
    st.booleans(),
    st.booleans(),
    st.booleans(),
    st.binary(max_size=8),
)
@settings(max_examples=300, deadline=None)
def test_hostile_frames_never_break_the_recognisers(
    arbitration_id: int, extended: bool, remote: bool, error: bool, data: bytes
) -> None:
    """Whatever a bus delivers, the doctor's readers answer or say no; they never raise."""
    msg = can.Message(
        arbitration_id=arbitration_id if extended else arbitration_id & 0x7FF,
        is_extended_id=extended,
        is_remote_frame=remote,
        is_error_frame=error,
        data=b"" if remote else data,
        dlc=len(data),
        check=False,
    )
    for read in (
        announcements,
        actuator_status,
        odrive_version,
        robstride_device_id,
        rmdx_identity,
    ):
        read(msg)
    _RECOGNISER.whose(msg)
    _NODE_INFO.push(msg, 0.0)


_NODE_INFO = NodeInfoReader(127)
_RECOGNISER = Recogniser(
    {name: [] for name in ("rmd-x", "lk", "cubemars-ak", "damiao-dm", "odrive", "dronecan")},
    ids={"cubemars-ak": range(0, 8), "damiao-dm": range(1, 8), "dronecan": range(1, 8)},
)


def test_doctor_listens_listen_only_before_it_sends_anything() -> None:
    """On the simulated slcan adapter: the first open is LAWICEL ``L`` (listen-only), and no
    frame reaches the bus from the host until the probes."""
    config = load_config(REPO / "config" / "slcan.yaml")
    bus = config.can.buses[0]
    emulator = SlcanEmulator(wired_servos(config, bus.name)).start()
    sent_while_listening: list[int] = []
    try:

        def opener(request: BusRequest) -> OpenedBus:
            if request.listen_only:
                sent_while_listening.append(emulator.frames_from_host)
            return open_bus(dataclasses.replace(request, channel=emulator.path))

        doctor = BusDoctor(bus, config.servos, opener, lambda *a: None, listen_s=0.3)
        assert doctor._listen(bus.bitrate)
        assert emulator.listen_opens == 1 and emulator.frames_from_host == 0
        assert wait_until(lambda: emulator.mode == "closed", 2.0)  # python-can sent C at close
    finally:
        emulator.stop()
    assert sent_while_listening == [0]


def test_an_adapter_that_is_not_there_is_said_once(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    missing = tmp_path / "ttyUSB9"
    path = write_config(
        tmp_path,
        f"can:\n  buses:\n    - {{name: bus0, interface: aa55, channel: '{missing}'}}\n"
        "servos:\n  - {name: a, profile: rmd-x, can_id: 1}\n",
    )
    code, out, _ = run_doctor(capsys, path, tmp_path)
    assert code == 1
    # the lines `mavservo run` prints: the bus, its line, the device and the usual causes
    assert out.count(f"cannot open aa55 {missing}") == 1 and "no adapter there" in out, out
    assert f"bus bus0 ({path}:3: can.buses[0].channel)" in out and "usual causes:" in out
    assert "what bus bus0 needs" not in out  # nothing learnt, nothing to paste


def test_robstride_in_the_other_protocol_found_with_allow_enable(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """A Robstride switched to MIT under a private-protocol config answers nothing safe: without
    the flag the doctor says it may be in MIT; with it, it names the protocol and the fix."""
    path = write_config(
        tmp_path,
        "servos:\n  - {name: hip, profile: robstride, can_id: 1, options: {protocol: private}}\n"
        "simulation:\n  servos:\n    hip: {options: {protocol: mit}}\n",
    )
    code, out, _ = run_doctor(capsys, path, tmp_path, "--no-bitrate-search", listen=0.4)
    assert code == 1 and "silent" in out and "MIT protocol" in out, out
    code, out, _ = run_doctor(
        capsys, path, tmp_path / "enabled", "--no-bitrate-search", "--allow-enable", listen=0.4
    )
    assert "wrong mode: heard robstride (protocol: mit) from id 1" in out, out
    assert suggested(out)["servos"][0]["options"] == {"protocol": "mit"}


def _odrive_node_commands(log: Path, node: int) -> list[can.Message]:
    """Frames the doctor sent into ODrive node ``node``'s block (ODrive CANSimple: an ODrive
    takes every 11-bit id whose upper six bits are its node id) that are not remote frames:
    each is a command to that ODrive (0x0C Set_Input_Pos, 0x16 Reboot, 0x1F Enter_DFU_Mode...)."""
    return [
        m
        for m in _frames_sent(log)
        if not m.is_extended_id and m.arbitration_id >> 5 == node and not m.is_remote_frame
    ]


@pytest.mark.parametrize("odrive_at", ["configured", "heard only"])
def test_a_scan_never_lands_on_another_familys_commands(
    odrive_at: str, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """RMD-X / LK reads go to 0x140 + id, which is ODrive node 10's block: an RMD-X scan sent
    its 0x9C read as node 10's Set_Input_Pos, Set_Limits, Reboot and Enter_DFU_Mode. The
    doctor now spares the ids of every device it knows (configured, or heard by heartbeat)."""
    text = "servos:\n  - {name: arm, profile: odrive, can_id: 10}\n"
    if odrive_at == "heard only":  # configured on 11, answering on 10: a wrong-id mistake
        text = (
            "servos:\n  - {name: arm, profile: odrive, can_id: 11}\n"
            "simulation:\n  servos:\n    arm: {can_id: 10}\n"
        )
    path = write_config(tmp_path, text)
    _, out, log = run_doctor(
        capsys, path, tmp_path, "--no-bitrate-search", "--scan", "rmd-x", "--scan", "lk", listen=0.5
    )
    assert "ODrive node 10: heartbeat" in out, out
    assert _odrive_node_commands(log, 10) == []
    assert "requests whose id is odrive 10's" in out, out
    # the rest of the range is still scanned: id 32 (0x160) is outside node 10's block
    assert any(m.arbitration_id == 0x160 for m in _frames_sent(log))


def test_a_flood_of_random_ids_keeps_the_unknown_count_bounded(tmp_path: Path) -> None:
    """Every frame no family reads was counted by id in an unbounded Counter: a hostile
    stream of random 29-bit ids grew it by one entry per frame."""
    from mavservo.app.doctor.findings import MAX_UNKNOWN_IDS

    path = write_config(tmp_path, "servos:\n  - {name: a, profile: rmd-x, can_id: 1}\n")
    config = load_config(path)
    doctor = BusDoctor(config.can.buses[0], config.servos, open_bus, lambda *_: None)
    frames = 3 * MAX_UNKNOWN_IDS
    for k in range(frames):
        msg = can.Message(arbitration_id=0x1ABC0000 + k, is_extended_id=True, data=b"\x01")
        doctor.reader.read(msg, 1_000_000, "heard")
    findings = doctor.findings
    assert len(findings.unknown_ids) <= MAX_UNKNOWN_IDS
    assert sum(findings.unknown_ids.values()) + findings.unknown_overflow == frames


def test_scan_ids_are_clipped_to_the_family_range(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """``--ids`` took any range up to 0x1FFFFFFF and built a candidate per id: a 29-bit range
    for a 32-id family ran for hours. Now only the family's own ids are probed; a range with
    none of them is refused."""
    path = write_config(tmp_path, "servos:\n  - {name: a, profile: rmd-x, can_id: 1}\n")
    code, out, _ = run_doctor(
        capsys,
        path,
        tmp_path,
        "--no-bitrate-search",
        "--scan",
        "rmd-x",
        "--ids",
        "0-0x1FFFFFFF",
        listen=0.3,
    )
    assert code == 0 and "probed 32 ids" in out, out
    # ... and the skipped ids are named with the reason, not left out quietly
    assert (
        "--scan rmd-x: probing ids 1-32 only, rmd-x ids are 1-32; skipped 0, 33-536870911" in out
    ), out
    code = doctor_main([str(path), "--scan", "rmd-x", "--ids", "100-200"])
    assert code == 2 and "rmd-x ids are 1-32" in capsys.readouterr().err


def test_skipped_ids_are_named_as_ranges() -> None:
    from mavservo.app.doctor import _skipped_ids

    assert _skipped_ids(range(1, 81), range(1, 33)) == "33-80"
    assert _skipped_ids(range(0, 33), range(1, 33)) == "0"
    assert _skipped_ids(range(1, 33), range(1, 33)) == ""
    assert _skipped_ids(range(0, 34), range(1, 33)) == "0, 33"


def test_a_foreign_flood_adds_no_phantom_servos_to_the_yaml(tmp_path: Path) -> None:
    """20,000 random frames (2.5 s of a busy foreign bus) fitted some family's reply layout
    often enough that the printed servos: block listed ~250 servos that do not exist (every
    ODrive node, Damiao ids, LK ids...). On a bus where most frames are no family's, a motor
    only heard, never answering a request, is not listed; the configured ones still are."""
    import random

    from mavservo.app.doctor.verdict import extra_entries, judge

    path = write_config(
        tmp_path,
        "servos:\n  - {name: a, profile: rmd-x, can_id: 1}\n"
        "  - {name: e, profile: odrive, can_id: 9}\n",
    )
    config = load_config(path)
    doctor = BusDoctor(config.can.buses[0], config.servos, open_bus, lambda *_: None)
    rng = random.Random(1)
    for _ in range(20_000):
        extended = rng.random() < 0.5
        size = rng.choice([8, 8, rng.randint(0, 8)])
        msg = can.Message(
            arbitration_id=rng.getrandbits(29 if extended else 11),
            is_extended_id=extended,
            data=bytes(rng.getrandbits(8) for _ in range(size)),
        )
        doctor.reader.read(msg, 1_000_000, "heard")
    findings = doctor.findings
    findings.working_bitrate = 1_000_000
    heard = {(s.profile, s.can_id) for s in findings.sightings.values()}
    assert len(heard) > 20  # the flood does fit other ids' layouts: the attack is real
    assert findings.noisy
    verdicts = judge(findings, config.servos)
    assert extra_entries(findings, verdicts) == []


@pytest.mark.parametrize("family", ["rmd-x", "lk"])
def test_the_silence_advice_names_the_id_the_family_answers_on(family: str) -> None:
    """The LK advice said replies come on 0x240 + id (RMD-X V4's); LK answers on the
    request's own id 0x140 + id (LK-TECH CAN protocol; the profile's own identifiers)."""
    import re

    from mavservo.app.doctor.families import facts
    from mavservo.servos import get_profile

    [named] = re.findall(r"0x([0-9A-Fa-f]+) \+ id", facts(family).silence)
    profile = get_profile(family)(1)
    replies = [f.arbitration_id for f in profile.identifiers() if f.direction == "from_servo"]
    assert int(named, 16) + 1 in replies, (named, [hex(r) for r in replies])


@pytest.mark.parametrize("listen", ["nan", "-1", "0", "1e9", "inf"])
def test_listen_seconds_are_bounded(listen: str, capsys: pytest.CaptureFixture[str]) -> None:
    """``--listen nan`` made every receive deadline unreachable (``left <= 0`` is never true
    for NaN); ``--listen 1e9`` listened at one bitrate for decades."""
    with pytest.raises(SystemExit) as caught:
        doctor_main(["--listen", listen])
    assert caught.value.code == 2
    assert "--listen" in capsys.readouterr().err


_KNEE = "  - {name: knee, profile: cubemars-ak-mit, can_id: 3}\n"


def _doctor_on(
    make_bus: Callable[[], can.BusABC], servos: str, *, listen_s: float = 0.5, **kwargs: Any
) -> BusDoctor:
    """A doctor (no bitrate search, no log) on one bus of ``servos`` (YAML list items), whose
    adapter is ``make_bus`` (reopened by the bus wrapper as a real one would be)."""
    from mavservo.transport.resilient_bus import ResilientBus

    def open_request(request: BusRequest) -> OpenedBus:
        return OpenedBus(ResilientBus(make_bus))

    config = load_config_text(f"servos:\n{servos}", "doctor.yaml")
    return BusDoctor(
        config.can.buses[0],
        config.servos,
        open_request,
        lambda *_: None,
        listen_s=listen_s,
        try_bitrates=False,
        **kwargs,
    )


def test_a_refused_disable_after_allow_enable_is_retried_and_reported(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """--allow-enable sends enter-motor-mode, then exit-motor-mode; a bus that refused the
    exit (a full transmit queue, bus-off) left the motor in motor mode, silently. Now the
    exit is retried and a motor still enabled is a WARNING in the report."""
    from can.interfaces.virtual import VirtualBus

    from mavservo.app.doctor import print_bus
    from mavservo.app.doctor.families import EXIT_MOTOR_MODE

    refused: list[bytes] = []

    class RefusesDisable(VirtualBus):  # the adapter failing exactly the undo
        def send(self, msg: can.Message, timeout: float | None = None) -> None:
            if bytes(msg.data) == EXIT_MOTOR_MODE:
                refused.append(bytes(msg.data))
                raise can.CanOperationError("transmit queue full")
            super().send(msg, timeout)

    channel = f"refuse-{time.monotonic_ns()}"

    doctor = _doctor_on(
        lambda: RefusesDisable(channel=channel), _KNEE, listen_s=0.05, allow_enable=True
    )
    findings = doctor.run()
    assert findings.enable_sent >= 1
    assert len(refused) >= 2  # tried again once the adapter was reopened
    assert findings.left_enabled == ["cubemars-ak-mit 3"]
    assert not print_bus(findings, [])
    assert "WARNING: cubemars-ak-mit 3 was enabled" in capsys.readouterr().out


def test_ctrl_c_while_an_enabled_motor_is_heard_still_disables_it() -> None:
    """An interrupt in the listen after enter-motor-mode skipped the exit: the motor stayed
    in motor mode. The exit now goes out in a ``finally``."""
    from can.interfaces.virtual import VirtualBus

    from mavservo.app.doctor.families import ENTER_MOTOR_MODE, EXIT_MOTOR_MODE

    sent: list[bytes] = []

    class InterruptedAfterEnable(VirtualBus):  # the user presses Ctrl-C right then
        interrupted = False

        def send(self, msg: can.Message, timeout: float | None = None) -> None:
            sent.append(bytes(msg.data))
            super().send(msg, timeout)

        def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
            if ENTER_MOTOR_MODE in sent and not InterruptedAfterEnable.interrupted:
                InterruptedAfterEnable.interrupted = True
                raise KeyboardInterrupt
            return super()._recv_internal(timeout)

    channel = f"interrupt-{time.monotonic_ns()}"

    doctor = _doctor_on(
        lambda: InterruptedAfterEnable(channel=channel), _KNEE, listen_s=0.05, allow_enable=True
    )
    with pytest.raises(KeyboardInterrupt):
        doctor.run()
    assert sent.index(EXIT_MOTOR_MODE) > sent.index(ENTER_MOTOR_MODE)


class _DroneCanNodes:
    """DroneCAN nodes on a python-can virtual bus, written with the ``dronecan`` package
    alone: each sends NodeStatus every 0.1 s and answers GetNodeInfo as the DSDL says; the
    requests they received are kept. Bounded: it stops after ``seconds``."""

    def __init__(
        self, channel: str, nodes: dict[int, str], seconds: float = 6.0, answers: bool = True
    ) -> None:
        import threading

        import dronecan

        self.dronecan = dronecan
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.nodes = nodes
        self.answers = answers
        self.requests: list[tuple[int, int]] = []
        self.deadline = time.monotonic() + seconds
        self.stopped = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _send(self, transfer: Any) -> None:
        for frame in transfer.to_frames():
            self.bus.send(
                can.Message(
                    arbitration_id=frame.message_id, data=bytes(frame.bytes), is_extended_id=True
                )
            )

    def _run(self) -> None:
        dronecan = self.dronecan
        protocol = dronecan.uavcan.protocol
        next_status = 0.0
        while not self.stopped.is_set() and time.monotonic() < self.deadline:
            if time.monotonic() >= next_status:
                next_status = time.monotonic() + 0.1
                for node in self.nodes:
                    status = protocol.NodeStatus(uptime_sec=3, health=0, mode=0)
                    self._send(
                        dronecan.transport.Transfer(
                            transfer_id=0, source_node_id=node, payload=status
                        )
                    )
            msg = self.bus.recv(0.02)
            if msg is None or not msg.is_extended_id or not msg.arbitration_id & 0x80:
                continue
            transfer = dronecan.transport.Transfer()
            transfer.from_frames([dronecan.transport.Frame(msg.arbitration_id, bytes(msg.data))])
            node = transfer.dest_node_id
            if node not in self.nodes or transfer.data_type_id != 1:
                continue
            self.requests.append((node, transfer.source_node_id))
            if not self.answers:
                continue
            answer = protocol.GetNodeInfo.Response(name=self.nodes[node])
            answer.software_version.major, answer.software_version.minor = 1, 4
            answer.software_version.optional_field_flags = 1
            answer.software_version.vcs_commit = 0x2B6F11C4
            answer.hardware_version.major = 2
            answer.hardware_version.unique_id = list(range(16))
            self._send(
                dronecan.transport.Transfer(
                    transfer_id=transfer.transfer_id,
                    source_node_id=node,
                    dest_node_id=transfer.source_node_id,
                    payload=answer,
                    service_not_message=True,
                    request_not_response=False,
                )
            )

    def stop(self) -> None:
        self.stopped.set()
        self.thread.join(timeout=2.0)
        self.bus.shutdown()


def _doctor_on_virtual_bus(channel: str, servos: str, **kwargs: Any) -> BusDoctor:
    return _doctor_on(lambda: can.Bus(interface="virtual", channel=channel), servos, **kwargs)


def test_dronecan_get_node_info_names_each_node_heard(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Every node heard by NodeStatus is asked GetNodeInfo from node 127 (the id the
    DroneCAN specification reserves for tools), configured or not; the answers, encoded by
    the ``dronecan`` package, print name, software and hardware version and unique id."""
    pytest.importorskip("dronecan")
    from mavservo.app.doctor import print_bus
    from mavservo.app.doctor.verdict import judge

    channel = f"nodeinfo-{time.monotonic_ns()}"
    nodes = _DroneCanNodes(channel, {42: "org.ardupilot.ap_periph", 43: "com.example.\x1b[2Jx"})
    try:
        doctor = _doctor_on_virtual_bus(channel, "  - {name: a, profile: dronecan, can_id: 42}\n")
        findings = doctor.run()
    finally:
        nodes.stop()
    assert sorted(nodes.requests) == [(42, 127), (43, 127)]
    said = findings.node_infos[42].text()
    assert said == (
        "GetNodeInfo: org.ardupilot.ap_periph, software 1.4 (vcs 0x2b6f11c4), hardware 2.0, "
        "unique id 000102030405060708090a0b0c0d0e0f"
    )
    # a name is printed, never a terminal escape from a hostile node
    assert findings.node_infos[43].name == "com.example.?[2Jx"
    print_bus(findings, judge(findings, doctor.servos))
    out = capsys.readouterr().out
    assert f"DroneCAN node 42: NodeStatus OK, OPERATIONAL, up 3 s; {said}" in out, out
    assert "frames no family reads" not in out, out  # the answers' frames are read
    servo_line = out.split("a            dronecan id 42:", 1)[1]
    assert said in servo_line, out


def test_get_node_info_from_another_node_id_and_never_from_a_taken_one() -> None:
    """``--node-id`` picks the doctor's id; when a node on the bus has it, the doctor asks
    nothing (two nodes with one id would garble each other's transfers) and says why."""
    pytest.importorskip("dronecan")
    channel = f"nodeinfo-taken-{time.monotonic_ns()}"
    nodes = _DroneCanNodes(channel, {42: "org.node", 100: "org.other"})
    try:
        servo = "  - {name: a, profile: dronecan, can_id: 42}\n"
        taken = _doctor_on_virtual_bus(channel, servo, node_id=100).run()
        asked_before = list(nodes.requests)
        free = _doctor_on_virtual_bus(channel, servo, node_id=101).run()
    finally:
        nodes.stop()
    assert asked_before == [] and taken.node_infos == {}
    assert "node id 100, the doctor's, is taken" in taken.node_info_said(42)
    assert sorted(nodes.requests) == [(42, 101), (100, 101)]
    assert free.node_infos[42].name == "org.node"


def test_the_simulated_dronecan_node_is_asked_who_it_is_and_says(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """The built-in simulated DroneCAN node answers GetNodeInfo (written from the DSDL, through
    the ``dronecan`` package, not from the doctor's reader): the doctor asks each node (the
    requests are in its CAN log: service frames, GetNodeInfo, from node 127) and prints the
    name, versions and unique id the node gave; the request enables and moves nothing."""
    from mavservo.servos.dronecan import wire

    path = REPO / "config" / "dronecan.yaml"
    code, out, log = run_doctor(capsys, path, tmp_path, "--no-bitrate-search")
    assert code == 0, out
    requests = [wire.service_fields(m) for m in _frames_sent(log)]
    asked = {
        f.destination
        for f in requests
        if f is not None and f.dtid == wire.DTID_GET_NODE_INFO and f.request and f.source == 127
    }
    nodes = {servo.can_id for servo in load_config(path).servos}
    assert asked == nodes
    for node in nodes:
        assert f"DroneCAN node {node}: NodeStatus OK, OPERATIONAL" in out
        said = out.split(f"DroneCAN node {node}: NodeStatus", 1)[1].splitlines()[0]
        unique = (b"mavservo-sim" + node.to_bytes(4, "big")).hex()
        assert (
            f"GetNodeInfo: org.mavservo.sim.actuator, software 1.0, hardware 1.0, "
            f"unique id {unique}" in said
        ), said
    assert_nothing_enabled_or_moved(path, log)


def test_a_node_that_does_not_answer_get_node_info_is_said_so() -> None:
    """A node heard by NodeStatus that ignores GetNodeInfo: asked once, then 'no GetNodeInfo
    answer' (whatever the built-in simulation does)."""
    pytest.importorskip("dronecan")
    channel = f"nodeinfo-silent-{time.monotonic_ns()}"
    nodes = _DroneCanNodes(channel, {42: "org.node"}, answers=False)
    try:
        doctor = _doctor_on_virtual_bus(channel, "  - {name: a, profile: dronecan, can_id: 42}\n")
        findings = doctor.run()
    finally:
        nodes.stop()
    assert nodes.requests == [(42, 127)]
    assert findings.node_infos == {}
    assert findings.node_info_said(42) == "no GetNodeInfo answer"


@pytest.mark.parametrize("node_id", ["0", "128", "x"])
def test_node_id_must_be_a_dronecan_node_id(
    node_id: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as caught:
        doctor_main(["--node-id", node_id])
    assert caught.value.code == 2
    assert "--node-id" in capsys.readouterr().err
