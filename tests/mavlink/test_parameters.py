"""The parameter table, the overlay file and the parameter protocol, without a running bridge.

The table must stand for the config keys it names (a value set is the value read back, and every
config the table produces passes the same validation as a YAML file); the overlay must survive a
restart and refuse, with FILE:LINE, what no longer fits its config; the protocol must answer as
ground stations expect and refuse unsigned or unknown requests without raising.
"""

from __future__ import annotations

import math
import os
import stat
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mavservo.config import load_config
from mavservo.config.loader import ConfigError, default_config_path
from mavservo.config.overlay import (
    clear_overlay,
    load_config_with_overlay,
    overlay_path,
    read_overlay,
    write_overlay,
)
from mavservo.config.parameters import (
    MAX_NAME_LENGTH,
    ParameterError,
    current_values,
    parameter_table,
    with_values,
)
from mavservo.config.schema import Config
from mavservo.mavlink.connection import mavlink2
from mavservo.mavlink.origin import tag
from mavservo.mavlink.params import (
    FTP_ERROR_UNKNOWN_COMMAND,
    FTP_OPCODE_NAK,
    RATE_LIMITED_ANSWER_BURST,
    RATE_LIMITED_ANSWERS_PER_S,
    SET_BURST,
    SETS_PER_S,
    ParameterServer,
    SetResult,
    WritePolicy,
)
from tests.support.mavlink_doubles import wire

SIM = load_config(default_config_path())
GCS = (255, 190)


def test_every_name_fits_param_id_and_is_unique() -> None:
    table = parameter_table(SIM)
    names = [p.name for p in table]
    assert len(names) == len(set(names))
    assert all(len(name) <= MAX_NAME_LENGTH for name in names)
    # 8 per servo a channel drives (5 for the others: no TRIM/REV/SLEW), 6 per gimbal,
    # 4 telemetry rates
    driven = sum(any(ch.servo == s.name for ch in SIM.channels) for s in SIM.servos)
    undriven = len(SIM.servos) - driven
    assert undriven  # the simulation's gimbal axes
    assert len(table) == 8 * driven + 5 * undriven + 6 * len(SIM.gimbals) + 4


def test_a_value_set_is_the_value_read_back_and_lands_in_the_config() -> None:
    updated = with_values(SIM, {"SRV1_TRIM": 3.0, "SRV2_MIN": -20.0, "TEL_NVF_HZ": 1.0})
    values = current_values(updated)
    assert values["SRV1_TRIM"] == 3.0
    aileron_channels = [ch for ch in updated.channels if ch.servo == SIM.servos[0].name]
    assert aileron_channels and all(ch.trim_deg == 3.0 for ch in aileron_channels)
    assert updated.servos[1].limits_deg == (-20.0, SIM.servos[1].limits_deg[1])
    assert updated.mavlink.telemetry.named_value_float_hz == 1.0
    assert SIM.servos[1].limits_deg != updated.servos[1].limits_deg  # the original is untouched


@pytest.mark.parametrize(
    ("values", "reason"),
    [
        ({"SRV1_TRIM": 100.0}, "outside output_deg"),
        ({"SRV1_MIN": 30.0}, "low < high"),
        ({"SRV1_REV": 0.5}, "not a whole number"),
        ({"SRV1_FS_ACT": 7.0}, "outside 0..3"),
        ({"SRV1_TRIM": math.nan}, "not a finite number"),
        ({"SRV1_TRIM": math.inf}, "not a finite number"),
        ({"NO_SUCH": 1.0}, "no such parameter"),
        ({"TEL_AOS_HZ": -1.0}, "outside 0..100"),
    ],
)
def test_refused_values_say_why(values: dict[str, float], reason: str) -> None:
    with pytest.raises(ParameterError, match=reason):
        with_values(SIM, values)


def test_a_value_the_cross_checks_refuse_is_refused() -> None:
    """The failsafe position must lie inside the limits: a check across keys (semantic.py)."""
    with pytest.raises(ParameterError, match="inside limits_deg"):
        with_values(SIM, {"SRV3_FS_POS": 80.0, "SRV3_MAX": 60.0})


@settings(max_examples=150, deadline=None)
@given(
    index=st.integers(min_value=0, max_value=10_000),
    value=st.one_of(
        st.floats(allow_nan=True, allow_infinity=True),
        st.integers(min_value=-40_000, max_value=40_000).map(float),
    ),
)
def test_any_value_is_either_a_valid_config_or_a_parameter_error(index: int, value: float) -> None:
    """Hostile PARAM_SET values never raise anything but ParameterError, and whatever is
    accepted is a config the YAML validation accepts too."""
    table = parameter_table(SIM)
    name = table[index % len(table)].name
    try:
        updated = with_values(SIM, {name: value})
    except ParameterError:
        return
    assert current_values(updated)[name] == pytest.approx(value)
    assert Config.model_validate(updated.model_dump()) == updated


# --------------------------------------------------------------------------------- overlay


def _config_file(tmp_path: Path) -> Path:
    path = tmp_path / "rig.yaml"
    path.write_text(default_config_path().read_text())
    return path


def test_overlay_round_trip_is_private_and_laid_over_the_config(tmp_path: Path) -> None:
    path = _config_file(tmp_path)
    overlay = overlay_path(path)
    assert overlay == tmp_path / "rig.params.yaml"
    write_overlay(overlay, {"SRV1_TRIM": 2.5, "SRV1_REV": 1.0}, path.name)
    assert stat.S_IMODE(os.stat(overlay).st_mode) == 0o600
    assert read_overlay(overlay) == {"SRV1_TRIM": 2.5, "SRV1_REV": 1.0}
    loaded = load_config_with_overlay(path)
    assert current_values(loaded.config)["SRV1_TRIM"] == 2.5
    assert current_values(loaded.base)["SRV1_TRIM"] == 0.0
    assert loaded.overlay == {"SRV1_TRIM": 2.5, "SRV1_REV": 1.0}
    assert clear_overlay(path) == overlay
    assert not overlay.exists()
    assert load_config_with_overlay(path).overlay == {}


def test_an_overlay_that_no_longer_fits_names_its_line(tmp_path: Path) -> None:
    path = _config_file(tmp_path)
    overlay_path(path).write_text("SRV1_TRIM: 1\nSRV99_TRIM: 2\nSRV2_MIN: yes\n")
    with pytest.raises(ConfigError) as caught:
        load_config_with_overlay(path)
    text = str(caught.value)
    assert "rig.params.yaml:3: SRV2_MIN: expected a finite number" in text
    overlay_path(path).write_text("SRV1_TRIM: 1\nSRV99_TRIM: 2\n")
    with pytest.raises(ConfigError, match=r"rig.params.yaml:2: SRV99_TRIM: no such parameter"):
        load_config_with_overlay(path)
    overlay_path(path).write_text("SRV1_TRIM: 1\nSRV1_MIN: 30\n")
    with pytest.raises(ConfigError, match=r"rig.params.yaml:2: SRV1_MIN: .*low < high"):
        load_config_with_overlay(path)


def test_write_leaves_no_temporary_file_behind(tmp_path: Path) -> None:
    path = _config_file(tmp_path)
    for k in range(5):
        write_overlay(overlay_path(path), {"SRV1_TRIM": float(k)}, path.name)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rig.params.yaml", "rig.yaml"]


# -------------------------------------------------------------------------------- protocol


class Store:
    """A parameter store of two names on component 140 that refuses negative values."""

    def __init__(self) -> None:
        self.values = {"A_ONE": 1.0, "B_TWO": 2.0}
        self.sets: list[tuple[str, float, tuple[int, int]]] = []

    def names(self, component_id: int) -> list[str]:
        return list(self.values) if component_id == 140 else []

    def value(self, name: str) -> float:
        return self.values[name]

    def set(self, name: str, value: float, sender: tuple[int, int]) -> SetResult:
        self.sets.append((name, value, sender))
        if value < 0:
            return SetResult(False, self.values[name], f"{name}: must not be negative")
        self.values[name] = value
        return SetResult(True, value)


def _server(signing: bool = False) -> tuple[ParameterServer, Store, list[str]]:
    store, texts = Store(), []
    server = ParameterServer(store, (140, 154), signing=signing, announce=texts.append)
    return server, store, texts


def _handle(server: ParameterServer, msg: Any, signed: bool = False) -> list[Any]:
    decoded = wire(msg, GCS)
    decoded._signed = signed  # what pymavlink sets on a frame whose signature verified
    return [m for _, m in server.handle(decoded, 1, GCS)]


def test_list_is_complete_and_indexed() -> None:
    """The whole list at once: the core paces it per requester within the link budget
    (tests/e2e/test_param_answers.py)."""
    server, _, _ = _server()
    values = _handle(server, mavlink2.MAVLink_param_request_list_message(1, 140))
    assert [(v.param_id, v.param_index, v.param_count) for v in values] == [
        ("A_ONE", 0, 2),
        ("B_TWO", 1, 2),
    ]
    assert all(v.param_type == mavlink2.MAV_PARAM_TYPE_REAL32 for v in values)


def test_a_component_without_parameters_answers_an_empty_list_and_others_nothing() -> None:
    server, _, _ = _server()
    assert _handle(server, mavlink2.MAVLink_param_request_list_message(1, 154)) == []
    assert _handle(server, mavlink2.MAVLink_param_request_list_message(1, 77)) == []
    assert _handle(server, mavlink2.MAVLink_param_request_list_message(9, 140)) == []


def test_read_by_name_by_index_and_unknown() -> None:
    server, _, _ = _server()
    (by_name,) = _handle(server, mavlink2.MAVLink_param_request_read_message(1, 140, b"B_TWO", -1))
    assert (by_name.param_id, by_name.param_value, by_name.param_index) == ("B_TWO", 2.0, 1)
    (by_index,) = _handle(server, mavlink2.MAVLink_param_request_read_message(1, 140, b"", 0))
    assert by_index.param_id == "A_ONE"
    (error,) = _handle(server, mavlink2.MAVLink_param_request_read_message(1, 140, b"NOPE", -1))
    assert error.get_type() == "PARAM_ERROR"
    assert error.error == mavlink2.MAV_PARAM_ERROR_DOES_NOT_EXIST
    (error,) = _handle(server, mavlink2.MAVLink_param_request_read_message(1, 140, b"", 9))
    assert (error.get_type(), error.param_index) == ("PARAM_ERROR", 9)


def test_set_answers_the_value_in_force_and_a_refusal_says_why() -> None:
    server, store, texts = _server()
    (ok,) = _handle(server, mavlink2.MAVLink_param_set_message(1, 140, b"A_ONE", 5.0, 9))
    assert (ok.param_id, ok.param_value) == ("A_ONE", 5.0)
    error, refused = _handle(server, mavlink2.MAVLink_param_set_message(1, 140, b"A_ONE", -3.0, 9))
    # PARAM_ERROR first (MAVSDK and QGroundControl say why), then the old value (older clients)
    assert (error.get_type(), error.param_id, error.error) == (
        "PARAM_ERROR",
        "A_ONE",
        mavlink2.MAV_PARAM_ERROR_VALUE_OUT_OF_RANGE,
    )
    assert (error.target_system, error.target_component) == GCS
    assert refused.get_type() == "PARAM_VALUE" and refused.param_value == 5.0
    assert texts == ["A_ONE -3 refused: must not be negative"]
    assert server.counters["set_refused"] == 1
    assert store.sets[-1][2] == GCS


def test_every_refused_set_says_why_with_its_code_and_the_value_in_force() -> None:
    """A type that carries no value, and a sender not allowed to write: each a PARAM_ERROR with
    its own code, then the PARAM_VALUE still in force; an unknown name only the error."""
    server, store, _ = _server()
    int64 = mavlink2.MAV_PARAM_TYPE_INT64
    error, value = _handle(server, mavlink2.MAVLink_param_set_message(1, 140, b"A_ONE", 5.0, int64))
    assert (error.error, value.get_type()) == (
        6,  # MAV_PARAM_ERROR_TYPE_UNSUPPORTED (common.xml; not in pymavlink 2.4.50)
        "PARAM_VALUE",
    )
    (unknown,) = _handle(server, mavlink2.MAVLink_param_set_message(1, 140, b"NOPE", 5.0, 9))
    assert unknown.error == mavlink2.MAV_PARAM_ERROR_DOES_NOT_EXIST
    closed = ParameterServer(store, [140], signing=False, announce=len, writers=WritePolicy())
    msg = wire(mavlink2.MAVLink_param_set_message(1, 140, b"A_ONE", 5.0, 9), GCS)
    error, value = [m for _cid, m in closed.handle(msg, 1, GCS, 0.0)]
    before = len(store.sets)
    assert error.error == mavlink2.MAV_PARAM_ERROR_PERMISSION_DENIED
    assert value.get_type() == "PARAM_VALUE" and value.param_id == "A_ONE"
    assert len(store.sets) == before


def test_a_rate_limited_set_gets_permission_denied_a_few_times_a_second_per_requester() -> None:
    """A set over the rate (``SETS_PER_S``) is refused: before, with no answer at all (MAVSDK
    retried and reported a time-out). Now PARAM_ERROR PERMISSION_DENIED, then the value in
    force, as every other refusal; but a flood is not answered in full: a few a second per
    requester (ids and origin), the rest counted. The same ids from another address are
    another requester, answered from their own bucket."""
    server, store, _ = _server()

    def set_from(origin: tuple[str, int], value: float, now: float) -> list[Any]:
        msg = wire(mavlink2.MAVLink_param_set_message(1, 140, b"A_ONE", value, 9), GCS)
        tag(msg, origin, pinned=True)
        return [m for _, m in server.handle(msg, 1, GCS, now)]

    flood_s, per_s = 3.0, 100
    station, other = ("127.0.0.1", 14550), ("127.0.0.66", 14550)
    answers = [set_from(station, 1.0, i / per_s) for i in range(int(flood_s * per_s))]
    applied = len(store.sets)
    assert applied <= SET_BURST + SETS_PER_S * flood_s + 1
    answered = [a for a in answers if a and a[0].get_type() == "PARAM_ERROR"]
    assert 0 < len(answered) <= RATE_LIMITED_ANSWER_BURST + RATE_LIMITED_ANSWERS_PER_S * flood_s
    for error, value in answered:
        assert (error.param_id, error.error) == (
            "A_ONE",
            mavlink2.MAV_PARAM_ERROR_PERMISSION_DENIED,
        )
        assert (error.target_system, error.target_component) == GCS
        assert (value.get_type(), value.param_id, value.param_value) == (
            "PARAM_VALUE",
            "A_ONE",
            1.0,
        )
    unanswered = len(answers) - applied - len(answered)
    assert sum(not a for a in answers) == unanswered > 0
    assert server.counters["set_rate_limited_unanswered"] == unanswered
    # the same ids from another address: their own set bucket, then their own answers
    for _ in range(SET_BURST):
        set_from(other, 2.0, flood_s)
    error, value = set_from(other, 2.0, flood_s)
    assert error.error == mavlink2.MAV_PARAM_ERROR_PERMISSION_DENIED
    assert value.param_value == 2.0


def test_unsigned_requests_on_a_signing_link_are_refused_and_counted() -> None:
    server, store, _ = _server(signing=True)
    assert _handle(server, mavlink2.MAVLink_param_set_message(1, 140, b"A_ONE", 5.0, 9)) == []
    assert _handle(server, mavlink2.MAVLink_param_request_list_message(1, 140)) == []
    assert store.sets == []
    assert server.counters["unsigned_refused"] == 2
    (ok,) = _handle(server, mavlink2.MAVLink_param_set_message(1, 140, b"A_ONE", 5.0, 9), True)
    assert ok.param_value == 5.0


def test_ftp_gets_an_immediate_nak_and_a_mission_list_unsupported() -> None:
    server, _, _ = _server()
    request = [0] * 251
    request[0:2] = [7, 0]  # sequence 7
    request[3] = 4  # OpenFileRO
    (nak,) = _handle(server, mavlink2.MAVLink_file_transfer_protocol_message(0, 1, 140, request))
    payload = bytes(nak.payload)
    assert int.from_bytes(payload[0:2], "little") == 8
    assert (payload[3], payload[5], payload[12]) == (FTP_OPCODE_NAK, 4, FTP_ERROR_UNKNOWN_COMMAND)
    assert (nak.target_system, nak.target_component) == GCS
    (ack,) = _handle(server, mavlink2.MAVLink_mission_request_list_message(1, 140, 0))
    assert (ack.get_type(), ack.type) == ("MISSION_ACK", mavlink2.MAV_MISSION_UNSUPPORTED)


@settings(max_examples=200, deadline=None)
@given(
    kind=st.sampled_from(["list", "read", "set", "ftp"]),
    name=st.binary(max_size=16),
    index=st.integers(min_value=-(2**15), max_value=2**15 - 1),
    value=st.floats(width=32),
    # any 251 bytes, drawn as bytes (a list of 251 drawn integers spans the same inputs at
    # ten times the cost)
    payload=st.binary(min_size=251, max_size=251),
)
def test_hostile_requests_never_raise(
    kind: str, name: bytes, index: int, value: float, payload: bytes
) -> None:
    server, _, _ = _server()
    msg = {
        "list": lambda: mavlink2.MAVLink_param_request_list_message(1, 0),
        "read": lambda: mavlink2.MAVLink_param_request_read_message(1, 140, name, index),
        "set": lambda: mavlink2.MAVLink_param_set_message(1, 140, name, value, 9),
        "ftp": lambda: mavlink2.MAVLink_file_transfer_protocol_message(0, 1, 140, list(payload)),
    }[kind]()
    _handle(server, msg)
    server.periodic(1.0)


# ------------------------------------------------------------------------------------ CLI


def test_params_cli_lists_marks_overlay_values_writes_metadata_and_clears(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import json

    from mavservo.cli import main

    path = _config_file(tmp_path)
    write_overlay(overlay_path(path), {"SRV1_TRIM": 2.0}, path.name)
    assert main(["params", str(path)]) == 0
    listing = capsys.readouterr().out
    assert "SRV1_TRIM" in listing and "2*" in listing and "rig.params.yaml" in listing

    assert main(["check", str(path)]) == 0
    assert "SRV1_TRIM 2 (file: 0)" in capsys.readouterr().out

    metadata_file = tmp_path / "params.json"
    assert main(["params", "--metadata", str(metadata_file), str(path)]) == 0
    metadata = json.loads(metadata_file.read_text())
    by_name = {p["name"]: p for p in metadata["parameters"]}
    assert by_name["SRV1_TRIM"]["units"] == "deg"
    assert by_name["SRV1_FS_ACT"]["values"][3] == {"value": 3, "description": "release"}
    assert len(by_name) == len(parameter_table(load_config(path)))

    assert main(["params", "--clear", str(path)]) == 0
    assert not overlay_path(path).exists()
    capsys.readouterr()
    assert main(["check", str(path)]) == 0
    assert "parameters set from a ground station" not in capsys.readouterr().out


def test_check_refuses_a_stale_overlay_with_its_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from mavservo.cli import main

    path = _config_file(tmp_path)
    overlay_path(path).write_text("SRV1_TRIM: 1\nSRV42_MIN: 0\n")
    assert main(["check", str(path)]) == 2
    assert "rig.params.yaml:2: SRV42_MIN: no such parameter" in capsys.readouterr().err


# ------------------------------------------------------------------------ STATUSTEXT queue


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 7), st.booleans()), max_size=200))
def test_essential_texts_are_never_dropped_and_go_first(entries: list[tuple[int, bool]]) -> None:
    from mavservo.mavlink.statustext_queue import CRITICAL, TextQueue

    queue = TextQueue(8)
    for n, (severity, essential) in enumerate(entries):
        queue.put(severity, f"{n}", essential)
    wanted = [f"{n}" for n, (sev, ess) in enumerate(entries) if ess or sev <= CRITICAL]
    out = []
    while (item := queue.pop()) is not None:
        out.append(item[1])
    assert out[: len(wanted)] == wanted
    assert len(out) <= max(8, len(wanted))


class GimbalStore(Store):
    """Component 140 serves every name, the gimbal 154 its own (as the bridge's store)."""

    def __init__(self) -> None:
        super().__init__()
        self.values["G_PIT"] = 3.0

    def names(self, component_id: int) -> list[str]:
        return {140: list(self.values), 154: ["G_PIT"]}.get(component_id, [])


def test_a_broadcast_set_is_applied_once_by_the_owner_and_an_unknown_one_not_at_all() -> None:
    store, texts = GimbalStore(), []
    server = ParameterServer(store, (140, 154), signing=False, announce=texts.append)
    (answer,) = server.handle(
        wire(mavlink2.MAVLink_param_set_message(1, 0, b"G_PIT", 4.0, 9), GCS), 1, GCS
    )
    assert answer[0] == 154 and len(store.sets) == 1
    (answer,) = server.handle(
        wire(mavlink2.MAVLink_param_set_message(1, 0, b"A_ONE", 4.0, 9), GCS), 1, GCS
    )
    assert answer[0] == 140 and len(store.sets) == 2
    unknown = mavlink2.MAVLink_param_request_read_message(1, 0, b"NOPE", -1)
    assert server.handle(wire(unknown, GCS), 1, GCS) == []
    assert server.counters["broadcast_unowned"] == 1
