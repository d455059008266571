"""Start-up errors name their place and fix (issue 37, item 3).

A device that does not open is said with the bus or link it is (its config key and FILE:LINE),
the device, and the usual causes for that kind of device; ``mavservo doctor`` prints the same
lines as ``mavservo run``; never a traceback. The runs here fail at their first open, so they
are cheap (no bridge ever runs).
"""

from __future__ import annotations

import errno
import socket
from pathlib import Path

import can
import pytest

from mavservo.app import doctor, run
from mavservo.transport import BusRequest, open_bus, open_causes, serial_causes
from mavservo.transport.bus_factory import LinkDownError
from mavservo.transport.open_advice import failure_errno

SERVO = "servos: [{name: a, profile: rmd-x, can_id: 1, bus: surfaces}]\n"
MISSING = "/dev/ttyUSB-mavservo-missing"


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "hw.yaml"
    path.write_text(text)
    return path


def _run(path: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    status = run.main([str(path), "--no-log", "--duration", "1", "-q"])
    return status, capsys.readouterr().err


def test_a_bus_that_does_not_open_is_named_with_its_line_and_fixes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _write(
        tmp_path,
        "mavlink: {url: 'udpin:127.0.0.1:0'}\n"
        "can:\n  buses:\n"
        "    - {name: other, channel: sim}\n"
        f"    - {{name: surfaces, interface: aa55, channel: {MISSING}}}\n" + SERVO,
    )
    status, err = _run(path, capsys)
    assert status == 1
    first = err.splitlines()[0]
    assert first.startswith(
        f"mavservo: cannot start: bus surfaces ({path}:5: can.buses[1].channel): "
        f"cannot open aa55 {MISSING}: "
    )
    assert "usual causes:" in err and "/dev/serial/by-id/" in err
    assert "Traceback" not in err


def test_the_autopilot_link_is_named_as_such_with_the_pi_uart_fix(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _write(
        tmp_path,
        "mavlink: {url: /dev/ttyAMA0, baud: 921600}\n"
        "servos: [{name: a, profile: rmd-x, can_id: 1}]\n",
    )
    if Path("/dev/ttyAMA0").exists():  # a Raspberry Pi running the tests: nothing to show
        pytest.skip("this machine has a /dev/ttyAMA0")
    status, err = _run(path, capsys)
    assert status == 1
    assert err.startswith(
        f"mavservo: cannot start: the autopilot link ({path}:1: mavlink.url): "
        "cannot open /dev/ttyAMA0: "
    )
    assert "enable_uart=1" in err and "raspi-config" in err
    assert "Traceback" not in err


def test_a_taken_udp_port_names_the_link_and_who_may_hold_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as holder:
        holder.bind(("127.0.0.1", 0))
        port = holder.getsockname()[1]
        path = _write(
            tmp_path,
            f"mavlink: {{url: 'udpin:127.0.0.1:{port}'}}\n"
            "servos: [{name: a, profile: rmd-x, can_id: 1}]\n",
        )
        status, err = _run(path, capsys)
    assert status == 1
    assert f"the autopilot link ({path}:1: mavlink.url)" in err
    assert "MAVProxy" in err and "Traceback" not in err


def test_doctor_prints_the_lines_run_prints(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _write(
        tmp_path,
        "mavlink: {url: 'udpin:127.0.0.1:0'}\n"
        f"can: {{buses: [{{name: surfaces, interface: aa55, channel: {MISSING}}}]}}\n" + SERVO,
    )
    _status, run_err = _run(path, capsys)
    said = run_err.removeprefix("mavservo: cannot start: ").splitlines()
    assert doctor.main([str(path), "--listen", "0.1", "--log-dir", str(tmp_path)]) == 1
    out = capsys.readouterr().out
    printed = {line.strip() for line in out.splitlines()}
    assert len(said) >= 3 and all(line.strip() in printed for line in said), out
    assert f"bus surfaces ({path}:2: can.buses[0].channel)" in out


# -- the causes per kind of device ----------------------------------------------------------


def _os_error(number: int, text: str = "") -> OSError:
    return OSError(number, text or errno.errorcode.get(number, "?"))


def test_serial_causes_follow_the_errno() -> None:
    denied = serial_causes("/dev/ttyUSB0", _os_error(errno.EACCES))
    assert "dialout" in denied[0]
    missing = serial_causes("/dev/ttyUSB0", _os_error(errno.ENOENT))
    assert "/dev/serial/by-id/" in missing[0] and "cable" in missing[0]
    busy = serial_causes("/dev/ttyUSB0", "aa55: /dev/ttyUSB0 is in use by another process")
    assert "fuser" in busy[0]
    assert "is the adapter plugged in" in missing[0]
    link = serial_causes("/dev/ttyACM0", _os_error(errno.ENOENT), what="the autopilot")
    assert "is the autopilot plugged in" in link[0] and "adapter" not in link[0]
    pi = serial_causes("/dev/serial0", _os_error(errno.ENOENT))
    assert "enable_uart=1" in pi[0] and len(pi) == 1


def test_the_errno_is_found_through_the_drivers_wrapping() -> None:
    try:
        try:
            raise _os_error(errno.EACCES)
        except OSError as inner:
            raise can.CanInitializationError("aa55: cannot open /dev/ttyUSB0") from inner
    except can.CanInitializationError as outer:
        assert failure_errno(outer) == errno.EACCES
    assert failure_errno("could not open port: [Errno 13] Permission denied") == errno.EACCES
    assert failure_errno("no number here") is None


def test_socketcan_causes() -> None:
    down = open_causes("socketcan", "can0", 500_000, _os_error(errno.ENETDOWN))
    assert down == [
        "interface can0 is down: `sudo ip link set can0 up type can bitrate 500000` "
        "(SocketCAN takes the bitrate from the link)"
    ]
    absent = open_causes("socketcan", "can0", 500_000, _os_error(errno.ENODEV))
    assert "candleLight CANable" in absent[0] and "`can0` on socketcan" in absent[0]
    slcan = open_causes("slcan", "/dev/ttyACM0@115200", 500_000, _os_error(errno.ENOENT))
    assert "nothing at /dev/ttyACM0:" in slcan[0]


def test_a_socketcan_interface_that_is_down_is_refused_at_the_open(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """python-can opens a down interface and every send fails later: refused at the open."""
    net = tmp_path / "net"
    (net / "can7").mkdir(parents=True)
    (net / "can7" / "flags").write_text("0x80\n")  # IFF_NOARP, not IFF_UP
    monkeypatch.setattr("mavservo.transport.bus_factory.SYS_CLASS_NET", net)
    with pytest.raises(LinkDownError, match="can7 is down"):
        open_bus(BusRequest("tail", "socketcan", "can7", 500_000))
    assert (
        "ip link set can7 up type can bitrate 500000"
        in open_causes("socketcan", "can7", 500_000, "socketcan: interface can7 is down")[0]
    )


def test_a_missing_usb_autopilot_is_not_called_an_adapter(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    missing = tmp_path / "ttyACM-gone"
    path = _write(
        tmp_path,
        f"mavlink: {{url: {missing}, baud: 115200}}\n"
        "servos: [{name: a, profile: rmd-x, can_id: 1}]\n",
    )
    status, err = _run(path, capsys)
    assert status == 1 and f"the autopilot link ({path}:1: mavlink.url)" in err
    assert "is the autopilot (its USB cable" in err and "is the adapter" not in err


def test_a_failing_command_line_override_is_named_not_the_files_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # the file's url is fine; the --mavlink that replaced it is what did not open
    gone = tmp_path / "ttyACM-gone"
    path = _write(
        tmp_path,
        "mavlink: {url: 'udpin:127.0.0.1:0'}\nservos: [{name: a, profile: rmd-x, can_id: 1}]\n",
    )
    status = run.main([str(path), "--mavlink", str(gone), "--no-log", "--duration", "1", "-q"])
    err = capsys.readouterr().err
    assert status == 1
    assert f"the autopilot link (--mavlink {gone}, replacing mavlink.url): cannot open" in err
    assert f"{path}:1" not in err
