"""``mavservo check`` and ``mavservo run``'s start-up give the same verdict (issue 37, item 2).

``check`` called configs valid that ``run`` refused at start (an slcan bitrate python-can does
not set, a SocketCAN channel that is a tty path), and a hardware config without
``mavlink.url`` valid while ``run`` drove it from the simulated autopilot. Every shipped config
and a set of common mistakes go through both: ``check_main`` and ``run.main`` (which returns
before any device is touched for an invalid config) print the same problems, and a valid one
gets the same warnings from ``check`` as from run's start-up (``run.startup_config``). The
mistakes python-can judges are also shown to be refused by python-can itself, so ``check``'s
rule is python-can's and not a guess.
"""

from __future__ import annotations

import io
import shutil
from pathlib import Path

import can
import pytest

from mavservo.app import run
from mavservo.app.check import check_main
from mavservo.config import Preflight
from tests.support.paths import REPO

SERVO = "servos: [{name: a, profile: rmd-x, can_id: 1}]\n"
LINK = "mavlink: {url: 'udpin:127.0.0.1:0'}\n"
MISSING = "/dev/ttyUSB-mavservo-missing"


def _bus(**keys: object) -> str:
    inner = ", ".join(f"{k}: {v}" for k, v in {"name": "bus0", **keys}.items())
    return f"can: {{buses: [{{{inner}}}]}}\n"


#: (name, YAML, what check's stderr must say; None = valid). At least 20 mistakes.
MISTAKES: list[tuple[str, str, str | None]] = [
    ("no url, aa55 device", _bus(channel=MISSING) + SERVO, "mavlink.url is not set"),
    ("no url, slcan", _bus(interface="slcan", channel="/dev/ttyACM0") + SERVO, "is not set"),
    (
        "url sim, socketcan",
        "mavlink: {url: sim}\n" + _bus(interface="socketcan", channel="can0") + SERVO,
        "mavlink.url is 'sim'",
    ),
    (
        "no url, pcan",
        _bus(interface="pcan", channel="PCAN_USBBUS1", bitrate=500000) + SERVO,
        "simulated autopilot",
    ),
    (
        "slcan bitrate 1000001",
        LINK + _bus(interface="slcan", channel="'loop://'", bitrate=1000001) + SERVO,
        "python-can's slcan interface sets only the bitrates",
    ),
    (
        "slcan bitrate 83333",
        LINK + _bus(interface="slcan", channel="'loop://'", bitrate=83333) + SERVO,
        "83300",
    ),
    (
        "socketcan on a tty",
        LINK + _bus(interface="socketcan", channel="/dev/ttyACM0") + SERVO,
        "network interface name",
    ),
    (
        "socketcan name too long",
        LINK + _bus(interface="socketcan", channel="can_interface_one") + SERVO,
        "at most 15 characters",
    ),
    ("aa55 on can0", LINK + _bus(channel="can0") + SERVO, "`interface: socketcan, channel: can0`"),
    ("slcan on can0", LINK + _bus(interface="slcan", channel="can0") + SERVO, "serial device"),
    ("aa55 channel a number", LINK + _bus(channel=0) + SERVO, "serial device"),
    ("aa55 bitrate 1000001", LINK + _bus(channel=MISSING, bitrate=1000001) + SERVO, "aa55"),
    ("bitrate 0", LINK + _bus(channel="sim", bitrate=0) + SERVO, "greater than 0"),
    (
        "interface typo",
        LINK + _bus(interface="socketcna", channel="can0") + SERVO,
        "did you mean 'socketcan'",
    ),
    ("sim on socketcan", LINK + _bus(interface="socketcan", channel="sim") + SERVO, "only aa55"),
    (
        "slcan option typo",
        LINK + _bus(interface="slcan", channel="sim", options="{tty_baudrat: 115200}") + SERVO,
        "did you mean 'tty_baudrate'",
    ),
    ("url port 99999", "mavlink: {url: 'udpin:0.0.0.0:99999'}\n" + SERVO, "99999"),
    ("url without host", "mavlink: {url: 'udp:14550'}\n" + SERVO, "udp:HOST:PORT"),
    ("profile typo", "servos: [{name: a, profile: rmdx, can_id: 1}]\n", "rmd-x"),
    ("frame id as can_id", "servos: [{name: a, profile: rmd-x, can_id: 0x141}]\n", "321"),
    ("key typo", "servos: [{name: a, profile: rmd-x, can_id: 1, limts_deg: [0, 1]}]\n", "limts"),
    (
        "two servos one id",
        "servos: [{name: a, profile: rmd-x, can_id: 1}, {name: b, profile: rmd-x, can_id: 1}]\n",
        "servos[1]",
    ),
    ("unknown bus", "servos: [{name: a, profile: rmd-x, can_id: 1, bus: tail}]\n", "tail"),
    (
        "yes as a number",
        "servos: [{name: a, profile: rmd-x, can_id: 1, max_speed_dps: yes}]\n",
        "YAML",
    ),
    # valid: machine facts are warnings; the simulation needs no link
    ("device not plugged in", LINK + _bus(channel=MISSING) + SERVO, None),
    ("socketcan absent", LINK + _bus(interface="socketcan", channel="can9") + SERVO, None),
    (
        "slcan baud suffix",
        LINK + _bus(interface="slcan", channel="/dev/ttyACM0@115200") + SERVO,
        None,
    ),
    # `mavservo sim --link adapter` makes ./adapter, the path docs/first-run.md uses
    ("relative device link", LINK + _bus(channel="./adapter-not-here") + SERVO, None),
    ("slcan loop url", LINK + _bus(interface="slcan", channel="'loop://'") + SERVO, None),
    ("virtual bus on sim url", _bus(interface="virtual", channel="bench") + SERVO, None),
    ("the quick start", SERVO, None),
]


def _check(path: Path) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    status = check_main([str(path)], out=out, err=err)
    return status, out.getvalue(), err.getvalue()


def _warnings(out: str) -> list[str]:
    lines = out.splitlines()
    if "warnings:" not in lines:
        return []
    start = lines.index("warnings:") + 1
    return [line.strip() for line in lines[start : lines.index("", start)]]


def _agree(path: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    """Both verdicts on ``path``; asserts they agree, returns check's status and stderr."""
    capsys.readouterr()
    status, out, err = _check(path)
    if status != 0:
        assert run.main([str(path), "--no-log", "--duration", "0.1", "-q"]) == 2
        run_err = capsys.readouterr().err
        assert run_err == f"mavservo: invalid configuration\n{err}"
        return status, err
    started = run.startup_config(path, None, None)
    assert isinstance(started, Preflight), capsys.readouterr().err
    assert _warnings(out) == [w.format(str(path)) for w in started.warnings]
    return status, err


def test_there_are_at_least_twenty_mistakes() -> None:
    assert sum(1 for _name, _yaml, said in MISTAKES if said is not None) >= 20


@pytest.mark.parametrize(("name", "text", "said"), MISTAKES, ids=[m[0] for m in MISTAKES])
def test_check_and_run_agree_on_a_mistake(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str, text: str, said: str | None
) -> None:
    path = tmp_path / "config.yaml"
    path.write_text(text)
    status, err = _agree(path, capsys)
    if said is None:
        assert status == 0, err
    else:
        assert status == 2 and said in err, err
        assert "Traceback" not in err


SHIPPED = sorted((REPO / "config").glob("*.yaml")) + [REPO / "mavservo" / "data" / "sim.yaml"]


@pytest.mark.parametrize("shipped", SHIPPED, ids=lambda p: str(p.relative_to(REPO)))
def test_check_and_run_agree_on_every_shipped_config(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], shipped: Path
) -> None:
    path = tmp_path / shipped.name
    shutil.copy(shipped, path)
    (tmp_path / "signing.key").write_text("ab" * 32 + "\n")  # the hardware examples read one
    (tmp_path / "signing.key").chmod(0o600)
    status, err = _agree(path, capsys)
    assert status == 0, err  # every shipped config is one a user can start from


def test_python_can_itself_refuses_what_check_refuses() -> None:
    """The rules are python-can's: its slcan driver refuses the bitrate check refuses and takes
    its neighbour, on a pyserial loop:// port (no device)."""
    with pytest.raises(can.CanInitializationError, match="Invalid bitrate"):
        can.Bus(interface="slcan", channel="loop://", bitrate=1_000_001, sleep_after_open=0)
    with can.Bus(interface="slcan", channel="loop://", bitrate=1_000_000, sleep_after_open=0):
        pass
    with pytest.raises(OSError):  # no such interface, or no CAN sockets: never a bus on a tty
        can.Bus(interface="socketcan", channel="/dev/ttyACM0")
