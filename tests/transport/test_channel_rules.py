"""The per-interface channel and bitrate rules ``check`` and ``run`` share (issue 37, item 2):
facts of the config are errors, facts of this machine are warnings."""

from __future__ import annotations

from pathlib import Path

from mavservo.transport import bus_problems, device_problems, reaches_hardware
from mavservo.transport.channel_rules import RULES, InterfaceRule


def _net(tmp_path: Path, **flags: str) -> Path:
    for name, value in flags.items():
        (tmp_path / name).mkdir(parents=True)
        (tmp_path / name / "flags").write_text(value + "\n")
    return tmp_path


def test_a_socketcan_interface_down_or_absent_is_a_warning_with_the_fix(tmp_path: Path) -> None:
    net = _net(tmp_path, can0="0x80", can1="0x1")  # can0 down, can1 up (IFF_UP)
    [down] = device_problems("socketcan", "can0", 250_000, sys_class_net=net)
    assert down.warning and down.key == "channel"
    assert "`sudo ip link set can0 up type can bitrate 250000`" in down.message
    assert device_problems("socketcan", "can1", 250_000, sys_class_net=net) == []
    [absent] = device_problems("socketcan", "can2", 250_000, sys_class_net=net)
    assert absent.warning and "gs_usb" in absent.message


def test_a_missing_serial_device_is_a_warning_a_url_is_not_looked_at(tmp_path: Path) -> None:
    [missing] = device_problems("aa55", str(tmp_path / "ttyUSB7"), 1_000_000)
    assert missing.warning and "/dev/serial/by-id/" in missing.message
    assert device_problems("slcan", "socket://127.0.0.1:7", 500_000) == []
    assert device_problems("aa55", "sim", 1_000_000) == []


def test_an_interface_without_rules_is_not_judged_here() -> None:
    assert "kvaser" not in RULES
    assert bus_problems("kvaser", 0, 1_234_567) == []
    assert device_problems("kvaser", 0, 1_234_567) == []


def test_a_new_interface_slots_in_with_one_table_entry(monkeypatch) -> None:
    monkeypatch.setitem(RULES, "newcan", InterfaceRule("netdev", "can0", lambda: (500_000,)))
    problems = bus_problems("newcan", "/dev/ttyACM0", 1_000_000)
    assert [p.key for p in problems] == ["channel", "bitrate"]
    assert "interface newcan takes a network interface name" in problems[0].message


def test_only_the_simulation_and_software_buses_are_not_hardware() -> None:
    assert not reaches_hardware("aa55", "sim") and not reaches_hardware("slcan", "sim")
    assert not reaches_hardware("virtual", "bench")
    for interface, channel in [
        ("aa55", "/dev/ttyUSB0"),
        ("socketcan", "can0"),
        ("udp_multicast", "x"),
    ]:
        assert reaches_hardware(interface, channel)
