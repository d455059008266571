"""The doctor's parts alone (app/doctor: frame_reader, occupants): frames and findings in,
findings and answers out, with no bus, no adapter and no timing. test_doctor.py covers them
through whole doctor runs."""

from __future__ import annotations

import can

from mavservo.app.doctor.findings import BusFindings
from mavservo.app.doctor.frame_reader import FrameReader
from mavservo.app.doctor.occupants import Occupants
from mavservo.app.doctor.recognise import Recogniser, options_key
from mavservo.config import Config, load_config_text

CONFIG = "servos:\n  - {name: a, profile: rmd-x, can_id: 1}\n"
#: RMD-X id 1's "read status 2" reply (0x240 + id, command 0x9C); it also fits ODrive node 18's
#: layout (a look-alike, the reason a configured servo's reading wins).
RMDX_REPLY = can.Message(
    arbitration_id=0x241, is_extended_id=False, data=bytes([0x9C, 30] + [0] * 6)
)


def _config() -> Config:
    return load_config_text(CONFIG)


def _reader(configured: bool) -> FrameReader:
    config = _config()
    findings = BusFindings(config.can.buses[0], listen_only=True)
    recogniser = Recogniser({"rmd-x": [{}], "odrive": []})
    keys = {("rmd-x", 1, options_key({}))} if configured else set()
    return FrameReader(findings, recogniser, keys, node_id=127, clock=lambda: 0.0)


def test_a_configured_servos_reading_of_a_frame_wins_over_its_look_alikes() -> None:
    reader = _reader(configured=True)
    reader.read(RMDX_REPLY, 1_000_000, "answered", asked={("rmd-x", 1)})
    [sighting] = reader.findings.sightings.values()
    assert (sighting.profile, sighting.can_id, sighting.how) == ("rmd-x", 1, "answered")
    assert sighting.states == 1 and not sighting.alternatives


def test_without_a_configured_servo_every_look_alike_is_kept_with_its_alternatives() -> None:
    reader = _reader(configured=False)
    reader.read(RMDX_REPLY, 500_000, "answered", asked={("odrive", 18)})
    seen = {(s.profile, s.can_id): s for s in reader.findings.sightings.values()}
    assert set(seen) == {("rmd-x", 1), ("odrive", 18)}
    assert seen["rmd-x", 1].how == "heard"  # not the one asked: only heard
    assert seen["odrive", 18].how == "answered"
    assert seen["rmd-x", 1].alternatives == {"odrive 18"}
    assert {s.bitrate for s in seen.values()} == {500_000}


def test_a_frame_no_family_reads_is_counted_by_id() -> None:
    reader = _reader(configured=True)
    stranger = can.Message(arbitration_id=0x1ABC0000, is_extended_id=True, data=b"\x01")
    for _ in range(3):
        reader.read(stranger, 1_000_000, "heard")
    assert reader.findings.unknown_ids == {(0x1ABC0000, True): 3}
    assert not reader.findings.sightings


def test_another_familys_device_owns_a_probe_that_lands_on_its_ids() -> None:
    """0x14C is in an LK / RMD-X read's id range and ODrive node 10's Set_Input_Pos
    (10 << 5 | 0x0C); node 10 is known only by its heartbeat, read by the frame reader."""
    reader = _reader(configured=True)
    occupants = Occupants(_config().servos, reader.findings)
    probe = can.Message(arbitration_id=0x14C, is_extended_id=False, data=bytes(8))
    assert occupants.owner("lk", [probe]) is None  # nothing known on 0x14C yet
    heartbeat = bytes([0, 0, 0, 0, 8, 0, 0, 0])  # no error, CLOSED_LOOP_CONTROL
    reader.read(
        can.Message(arbitration_id=10 << 5 | 0x01, data=heartbeat, is_extended_id=False),
        1_000_000,
        "heard",
    )
    occupants = Occupants(_config().servos, reader.findings)
    assert occupants.owner("lk", [probe]) == "odrive 10"
    assert occupants.owner("odrive", [probe]) is None  # a device's own family may send it
    rmdx_read = can.Message(arbitration_id=0x141, is_extended_id=False, data=bytes(8))  # id 1
    assert occupants.owner("odrive", [rmdx_read]) == "rmd-x 1"
