"""The bus factory (issue 29): ``options:`` passed to any python-can interface and checked
against it with FILE:LINE errors, a foreign bus's extra attributes never read (the typed
``TransportCounters`` contract), and python-can's real ``slcan`` interface against the
simulated LAWICEL adapter, end to end."""

from __future__ import annotations

import os
import time
import uuid
from pathlib import Path

import can
import can.util
import pytest
from can.interfaces.slcan import slcanBus
from can.interfaces.virtual import VirtualBus
from hypothesis import given
from hypothesis import strategies as st

from mavservo.app.bridge import Bridge, free_udp_port
from mavservo.config import ConfigError, load_config_text
from mavservo.sim.servo import SimServo
from mavservo.sim.slcan import SlcanEmulator, format_frame, parse_frame
from mavservo.sim.virtual import VirtualServoBus
from mavservo.transport.bus_factory import BusRequest, open_bus
from mavservo.transport.counters import transport_stats
from tests.support.waiting import wait_until

SERVO = "servos:\n  - {name: s1, profile: rmd-x, can_id: 1}\n"


def _bus_yaml(interface: str, options: str, channel: str = "/dev/ttyACM0") -> str:
    return (
        "can:\n"
        "  buses:\n"
        f"    - name: bus0\n"
        f"      interface: {interface}\n"
        f"      channel: {channel}\n"
        "      options:\n"
        f"{options}" + SERVO
    )


def test_an_options_typo_is_an_error_on_its_line() -> None:
    text = _bus_yaml("slcan", "        sleep_after_open: 0\n        tty_baudrat: 921600\n")
    with pytest.raises(ConfigError) as caught:
        load_config_text(text, "bus.yaml")
    message = str(caught.value)
    assert "bus.yaml:8:" in message, message  # the line of the misspelt key
    assert "'tty_baudrat'" in message and "did you mean 'tty_baudrate'" in message


def test_an_option_of_the_wrong_type_and_a_reserved_key_are_errors() -> None:
    text = _bus_yaml("slcan", "        listen_only: maybe\n        bitrate: 500000\n")
    with pytest.raises(ConfigError) as caught:
        load_config_text(text, "bus.yaml")
    message = str(caught.value)
    assert "bus.yaml:7:" in message and "takes bool" in message, message
    assert "bus.yaml:8:" in message and "bus's own `bitrate:` key" in message, message


def test_valid_options_load_and_reach_the_interface_unchanged() -> None:
    config = load_config_text(
        _bus_yaml("pcan", "        fd: true\n        f_clock_mhz: 80\n", "PCAN_USBBUS1"), "x"
    )
    assert config.can.buses[0].options == {"fd": True, "f_clock_mhz": 80}
    request = BusRequest("bus0", "pcan", "PCAN_USBBUS1", 500_000, config.can.buses[0].options)
    assert request.kwargs("PCAN_USBBUS1") == {
        "interface": "pcan",
        "channel": "PCAN_USBBUS1",
        "bitrate": 500_000,
        "fd": True,
        "f_clock_mhz": 80,
        "ignore_config": True,  # python-can's own config files and CAN_CONFIG do not apply
    }


def test_an_unknown_interface_and_a_simulation_it_does_not_have_are_errors() -> None:
    with pytest.raises(ConfigError, match=r"x:4:.*did you mean 'slcan'"):
        load_config_text(_bus_yaml("slcn", "        {}\n"), "x")
    with pytest.raises(ConfigError, match=r"x:5:.*only aa55 and slcan"):
        load_config_text(_bus_yaml("socketcan", "        {}\n", channel="sim"), "x")


class _VendorBus(VirtualBus):
    """A python-can bus of some vendor with attributes of its own: a ``stats`` that is data,
    not the bridge's method (what crashed the bridge at stop, issue 29)."""

    stats = {"rx_overruns": 0}
    protocol_version = "2.1"


def test_a_bus_with_a_non_callable_stats_runs_and_stops_with_its_summary(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setitem(can.interfaces.BACKENDS, "vendorbus", (__name__, "_VendorBus"))
    valid = can.interfaces.VALID_INTERFACES | {"vendorbus"}
    monkeypatch.setattr(can.interfaces, "VALID_INTERFACES", valid)
    monkeypatch.setattr(can.util, "VALID_INTERFACES", valid)
    channel = f"vendor-{uuid.uuid4().hex}"
    config = load_config_text(
        f"mavlink: {{url: 'udpin:127.0.0.1:{free_udp_port()}'}}\n"
        f"can: {{buses: [{{name: bus0, interface: vendorbus, channel: {channel}}}]}}\n" + SERVO,
        "<vendor>",
    )
    with VirtualServoBus([SimServo("rmd-x", 1)], channel=channel):
        bridge = Bridge(config, log_dir=tmp_path)
        bridge.start()
        try:
            assert wait_until(
                lambda: (
                    bridge.schedulers["bus0"].metrics()["servos"]["s1"]["frames"]["received"] > 5
                ),
                10.0,
            )
        finally:
            summary = bridge.stop()
    assert summary["servos"]["s1"]["frames"]["received"] > 5
    transport = summary["buses"]["bus0"]["transport"]
    assert transport["connected"] is True and transport["disconnects"] == 0
    assert "rx_overruns" not in transport  # the foreign attribute was never read
    assert transport_stats(_VendorBus(channel="unused")) == {}


# ------------------------------------------------------------------ the simulated slcan adapter


def _command(port: int, line: bytes, timeout: float = 2.0) -> bytes:
    """Write ``line`` + CR to the adapter, return its answer up to CR or BEL."""
    os.write(port, line + b"\r")
    answer = b""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not answer.endswith((b"\r", b"\a")):
        try:
            answer += os.read(port, 1)
        except BlockingIOError:
            time.sleep(0.001)
    return answer


@pytest.fixture
def slcan_port() -> object:
    with SlcanEmulator([SimServo("rmd-x", 1)]).start() as emulator:
        port = os.open(emulator.path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            yield emulator, port
        finally:
            os.close(port)


def test_slcan_commands_and_their_error_replies(slcan_port: tuple[SlcanEmulator, int]) -> None:
    emulator, port = slcan_port
    assert _command(port, b"V") == b"V1013\r"
    assert _command(port, b"N") == b"NSIM1\r"
    assert _command(port, b"F") == b"\a"  # status flags only while open
    assert _command(port, b"t1410") == b"\a"  # closed: nothing is sent
    assert _command(port, b"S9") == b"\a"  # no such standard bitrate
    assert _command(port, b"s031C") == b"\a"  # raw BTR registers: not simulated
    assert _command(port, b"S6") == b"\r" and emulator.bitrate == 500_000
    assert _command(port, b"L") == b"\r" and emulator.mode == "silent"
    assert _command(port, b"t1410") == b"\a"  # listen-only never transmits
    assert _command(port, b"O") == b"\a"  # already open
    assert _command(port, b"C") == b"\r"
    assert _command(port, b"S8") == b"\r" and _command(port, b"O") == b"\r"
    assert _command(port, b"S6") == b"\a"  # bitrate only while closed
    assert _command(port, b"F") == b"F00\r"
    for malformed in (
        b"t14",
        b"t1419",
        b"t14110",
        b"t1410AA",
        b"t1_10",
        b"T1234567G0",
        b"t800",
        b"x",
    ):
        assert _command(port, malformed) == b"\a", malformed
    assert _command(port, b"t" + b"0" * 40) == b"\a"  # an overlong line is discarded
    assert emulator.frames_from_host == 0
    # a well-formed request (RMD-X read status 1, 0x9A) is sent, acknowledged with "z", and
    # the servo's answer comes back in LAWICEL notation
    assert _command(port, b"t14189A00000000000000") == b"z\r"
    answer = b""
    for _ in range(200):
        chunk = _command(port, b"", timeout=0.02)
        answer += chunk
        if answer.startswith(b"\rt241"):
            break
    assert b"t2418" in answer, answer
    assert emulator.frames_from_host == 1 and emulator.errors >= 14


@given(
    st.integers(0, 0x7FF),
    st.integers(0, 0x1FFFFFFF),
    st.booleans(),
    st.booleans(),
    st.binary(max_size=8),
)
def test_slcan_frame_notation_round_trips(
    std_id: int, ext_id: int, extended: bool, remote: bool, data: bytes
) -> None:
    msg = can.Message(
        arbitration_id=ext_id if extended else std_id,
        is_extended_id=extended,
        is_remote_frame=remote,
        dlc=len(data),
        data=b"" if remote else data,
    )
    back = parse_frame(format_frame(msg).decode())
    assert back is not None
    assert back.equals(msg, timestamp_delta=None)


def test_python_can_slcan_reads_the_version_and_talks_to_servos() -> None:
    """python-can's own slcan driver against the simulated adapter: its version query and a
    servo's answer through the real interface."""
    with SlcanEmulator([SimServo("rmd-x", 1)]).start() as emulator:
        opened = open_bus(
            BusRequest("bus0", "slcan", emulator.path, 1_000_000, {"sleep_after_open": 0})
        )
        try:
            bus = opened.bus.inner
            assert isinstance(bus, slcanBus)
            assert bus.get_version(1.0) == (10, 13)
            opened.bus.send(
                can.Message(
                    arbitration_id=0x141, data=bytes([0x9A]) + bytes(7), is_extended_id=False
                )
            )
            reply = opened.bus.recv(2.0)
            assert reply is not None and reply.arbitration_id == 0x241
        finally:
            opened.close()


def test_slcan_at_the_wrong_bitrate_hears_nothing() -> None:
    """An injected mistake: the servos run at 1 Mbit/s, the host opens at 500 kbit/s."""
    with SlcanEmulator([SimServo("rmd-x", 1)], nodes_bitrate=1_000_000).start() as emulator:
        opened = open_bus(
            BusRequest("bus0", "slcan", emulator.path, 500_000, {"sleep_after_open": 0})
        )
        try:
            opened.bus.send(
                can.Message(
                    arbitration_id=0x141, data=bytes([0x9A]) + bytes(7), is_extended_id=False
                )
            )
            assert opened.bus.recv(0.5) is None
            assert emulator.canbus.bitrate_mismatches >= 1
        finally:
            opened.close()


# config/slcan.yaml run as shipped (python-can's slcan interface on the simulated LAWICEL
# adapter): tests/app/test_run_family_configs.py, beside the other examples' runs.


def test_an_aa55_key_given_as_an_option_is_refused() -> None:
    """``serial_baud`` has its own key on an aa55 bus: one setting, one place."""
    text = _bus_yaml("aa55", "        serial_baud: 115200\n", channel="sim")
    with pytest.raises(ConfigError, match=r"bus.yaml:7:.*own `serial_baud:` key"):
        load_config_text(text, "bus.yaml")


@pytest.mark.parametrize(
    ("options", "says"),
    [
        ("        sleep_after_open: -1\n", "finite number >= 0"),  # time.sleep(-1): traceback
        ("        sleep_after_open: .nan\n", "finite number >= 0"),
        ("        tty_baudrate: -5\n", "finite number >= 0"),
        ('        can_filters: "xx"\n', "takes a list of"),  # the bridge heard nothing
        ("        can_filters: {a: {b: 1}}\n", "takes a list of"),
        ("        can_filters: [{can_id: 0x141}]\n", "takes a list of"),
        ("        can_filters: [{can_id: 0x141, can_mask: 0x7FF, open: 1}]\n", "takes a list of"),
        ("        can_filters: [{can_id: -1, can_mask: 0x7FF}]\n", "is not a CAN id"),
    ],
)
def test_hostile_option_values_are_errors_on_their_line(options: str, says: str) -> None:
    """Values check let through: a negative or NaN sleep stopped the bridge's start with
    python-can's traceback; a malformed can_filters loaded, ran, and received 0 frames."""
    with pytest.raises(ConfigError) as caught:
        load_config_text(_bus_yaml("slcan", options), "bus.yaml")
    message = str(caught.value)
    assert "bus.yaml:7:" in message and says in message, message


def test_a_well_formed_filter_list_still_loads() -> None:
    text = _bus_yaml(
        "slcan", "        can_filters: [{can_id: 0x240, can_mask: 0x7E0, extended: false}]\n"
    )
    bus = load_config_text(text, "bus.yaml").can.buses[0]
    assert bus.options["can_filters"][0]["can_mask"] == 0x7E0


class _GarblingSlcan(SlcanEmulator):
    """An slcan adapter whose first line to the host has a non-hex data digit (line noise on
    a UART adapter, a firmware glitch): python-can's slcan ``recv`` raises ValueError on it."""

    garbled_lines = 0

    def _to_host(self, frames: list[tuple[float, can.Message]]) -> None:
        if self.garbled_lines or not frames or self.state == "closed":
            super()._to_host(frames)
            return
        self.garbled_lines += 1
        line = bytearray(format_frame(frames[0][1]))
        line[-1:] = b"G"
        self._write(bytes(line) + b"\r", 1)
        super()._to_host(frames[1:])


def test_a_garbled_slcan_line_drops_one_frame_not_the_receiver() -> None:
    """python-can's slcan raised ValueError out of ``recv`` for a line with a non-hex digit;
    the bus wrapper let it through and the bridge's receiving thread (which catches CanError
    only) died: every servo offline for the rest of the run. Now the frame is counted as
    garbled and dropped; the device is not taken for lost and the next frame arrives."""
    request = can.Message(arbitration_id=0x141, data=bytes([0x9A]) + bytes(7), is_extended_id=False)
    with _GarblingSlcan([SimServo("rmd-x", 1)]).start() as emulator:
        opened = open_bus(
            BusRequest("bus0", "slcan", emulator.path, 1_000_000, {"sleep_after_open": 0})
        )
        try:
            opened.bus.send(request)
            for _ in range(30):  # bounded: 3 s
                if opened.bus.recv(0.1) is None and opened.bus.stats()["garbled"]:
                    break
            assert emulator.garbled_lines == 1
            opened.bus.send(request)
            replies = [opened.bus.recv(0.2) for _ in range(10)]
            assert any(r is not None and r.arbitration_id == 0x241 for r in replies)
            stats = opened.bus.stats()
            assert stats["garbled"] == 1 and stats["disconnects"] == 0, stats
        finally:
            opened.close()


def test_python_cans_own_config_sources_cannot_change_a_bus(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """``can.Bus`` merges CAN_CONFIG (JSON in the environment), ``~/.canrc`` and
    ``/etc/can.conf`` into the keys it was not given: CAN_CONFIG={"listen_only": true} opened
    the bridge's slcan adapter listen-only (it sent nothing, every servo silent) although
    the YAML, which `check` validated, said nothing of it."""
    monkeypatch.setenv("CAN_CONFIG", '{"listen_only": true}')
    with SlcanEmulator([SimServo("rmd-x", 1)]).start() as emulator:
        opened = open_bus(
            BusRequest("bus0", "slcan", emulator.path, 1_000_000, {"sleep_after_open": 0})
        )
        try:
            assert wait_until(lambda: emulator.mode != "closed"), "the adapter was never opened"
            assert emulator.mode == "normal", emulator.mode
        finally:
            opened.close()


def test_python_cans_config_keys_are_not_options() -> None:
    text = _bus_yaml("slcan", "        sleep_after_open: 0\n        config_context: other\n")
    with pytest.raises(ConfigError, match=r"bus.yaml:8:.*config_context"):
        load_config_text(text, "bus.yaml")
