"""One error root, typed start-up errors, and failures that say what failed (issue 16, item 4).

Real parts: the adapter emulator's pty for the AA-55 port, python-can ``virtual`` buses behind
the reconnecting bus, a real UDP socket holding a port. Time in the reopen test is the bus's
injected clock, so the rate limit is checked without sleeping.
"""

from __future__ import annotations

import errno
import logging
import os
import re
import socket
import uuid
from pathlib import Path

import can
import pytest

from mavservo.app import run
from mavservo.app.report import ReportError
from mavservo.config import ConfigError, OverrideError
from mavservo.config.yamlsource import YamlSyntaxError
from mavservo.errors import DeviceMissingError, EndpointBusyError, MavservoError, StartupError
from mavservo.mavlink.link import REOPEN_WARNING_INTERVAL_S as LINK_REOPEN_INTERVAL_S
from mavservo.mavlink.link import LinkBusyError, MavlinkLink, UdpServer
from mavservo.scheduling.schedule_core import ScheduleError
from mavservo.servos import UnknownProfileError
from mavservo.sim.adapter import AdapterEmulator
from mavservo.sim.autopilot.replay import TlogError
from mavservo.sim.servo import SimServo
from mavservo.transport.aa55.bus import AA55Bus, AdapterBusyError, AdapterMissingError
from mavservo.transport.resilient_bus import REOPEN_WARNING_INTERVAL_S, ResilientBus
from tests.support.waiting import wait_until


@pytest.mark.parametrize(
    "error",
    [
        ConfigError,
        OverrideError,
        YamlSyntaxError,
        ScheduleError,
        UnknownProfileError,
        ReportError,
        TlogError,
        LinkBusyError,
        AdapterBusyError,
        AdapterMissingError,
    ],
)
def test_what_the_project_raises_on_purpose_has_one_root(error: type[Exception]) -> None:
    assert issubclass(error, MavservoError)


def test_errors_keep_the_contracts_their_callers_rely_on() -> None:
    """A caller of a socket API still catches OSError, a caller of can.Bus() CanError, a
    pydantic validator ValueError."""
    assert issubclass(LinkBusyError, OSError) and issubclass(LinkBusyError, EndpointBusyError)
    assert issubclass(AdapterBusyError, can.CanInitializationError)
    assert issubclass(AdapterMissingError, can.CanInitializationError)
    assert issubclass(AdapterMissingError, DeviceMissingError)
    assert issubclass(EndpointBusyError, StartupError)
    for error in (OverrideError, ScheduleError, UnknownProfileError, TlogError):
        assert issubclass(error, ValueError)


def test_a_busy_udp_port_is_a_typed_start_up_error() -> None:
    holder = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    holder.bind(("127.0.0.1", 0))
    try:
        port = holder.getsockname()[1]
        with pytest.raises(EndpointBusyError, match=f"127.0.0.1:{port} is in use") as caught:
            UdpServer("127.0.0.1", port)
        assert caught.value.errno == errno.EADDRINUSE
    finally:
        holder.close()


def test_a_missing_adapter_is_a_typed_start_up_error_naming_the_path(tmp_path: Path) -> None:
    path = str(tmp_path / "ttyUSB-gone")
    with pytest.raises(AdapterMissingError, match="ttyUSB-gone"):
        AA55Bus(channel=path)


@pytest.fixture
def emulator():
    started = AdapterEmulator([SimServo("rmd-x", 1)]).start()
    yield started
    started.stop()
    assert started.error is None


def test_a_busy_adapter_is_a_typed_start_up_error(emulator: AdapterEmulator) -> None:
    with (
        AA55Bus(channel=emulator.path),
        pytest.raises(AdapterBusyError, match="in use by another process"),
    ):
        AA55Bus(channel=emulator.path)


def test_fileno_is_the_ports_descriptor_and_a_closed_port_raises(
    emulator: AdapterEmulator,
) -> None:
    """python-can lets a bus without a descriptor answer -1; a closed port is not that bus."""
    bus = AA55Bus(channel=emulator.path)
    fd = bus.fileno()
    assert fd >= 0 and os.isatty(fd)
    bus.shutdown()
    with pytest.raises(can.CanOperationError, match="gone"):
        bus.fileno()


def test_fileno_of_a_url_port_without_descriptor_is_minus_one() -> None:
    with AA55Bus(channel="loop://") as bus:
        assert bus.fileno() == -1


# ------------------------------------------------------------------ start-up failures of `run`


def test_an_unexpected_start_up_failure_prints_its_traceback(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A bug at start-up (here: one planted in Bridge.start) must be reportable: its type, its
    message and where it happened, at the default log level."""
    from mavservo.app import bridge

    def broken_start(self: bridge.Bridge) -> bridge.Bridge:
        raise ZeroDivisionError("planted bug")

    monkeypatch.setattr(bridge.Bridge, "start", broken_start)
    assert run.main(["--quiet", "--no-log", "--duration", "0.1"]) == 1
    err = capsys.readouterr().err
    assert "cannot start: unexpected ZeroDivisionError: planted bug" in err
    assert "Traceback" in err and "broken_start" in err


def test_an_expected_start_up_failure_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    holder = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    holder.bind(("127.0.0.1", 0))
    port = holder.getsockname()[1]
    try:
        code = run.main(
            ["--quiet", "--no-log", "--duration", "0.1", "--mavlink", f"udpin:127.0.0.1:{port}"]
        )
    finally:
        holder.close()
    err = capsys.readouterr().err
    assert code == 1
    assert "cannot start: the autopilot link (" in err  # which link, its FILE:LINE and key
    assert f"UDP port 127.0.0.1:{port} is in use" in err
    assert "Traceback" not in err


# ------------------------------------------------------------------ reopen of a lost adapter


class Adapter:
    """A device behind the factory: a python-can virtual bus while plugged in."""

    def __init__(self) -> None:
        self.channel = f"errors-{uuid.uuid4().hex}"
        self.plugged = True
        self.opened: list[can.BusABC] = []

    def open(self) -> can.BusABC:
        if not self.plugged:
            raise OSError(errno.ENOENT, "No such file or directory", "/dev/ttyUSB0")
        bus = can.Bus(interface="virtual", channel=self.channel, receive_own_messages=False)
        self.opened.append(bus)
        return bus

    def unplug(self) -> None:
        self.plugged = False
        for bus in self.opened:
            bus.shutdown()


def test_a_reopen_that_keeps_failing_is_a_warning_at_a_bounded_rate(
    caplog: pytest.LogCaptureFixture,
) -> None:
    adapter = Adapter()
    now = [0.0]
    bus = ResilientBus(
        adapter.open, name="bus0", clock=lambda: now[0], initial_backoff_s=1.0, max_backoff_s=1.0
    )
    try:
        adapter.unplug()
        caplog.set_level(logging.WARNING, logger="mavservo.transport.resilient_bus")
        bus.recv(0)  # the inner bus is closed: the loss is noticed here
        attempts = 70  # one a simulated second, 70 s in all
        for _ in range(attempts):
            now[0] += 1.0
            bus.recv(0)
        warnings = [r.getMessage() for r in caplog.records if "cannot reopen" in r.getMessage()]
    finally:
        bus.shutdown()
    assert bus.failed_reopens == attempts
    # the first failure at once, then one per interval: 70 s of outage -> 3 warnings
    assert len(warnings) == 1 + int(attempts // REOPEN_WARNING_INTERVAL_S)
    assert adapter.channel in warnings[0] and "No such file or directory" in warnings[0]
    assert "(1 failed attempts" in warnings[0]
    assert f"({1 + int(REOPEN_WARNING_INTERVAL_S)} failed attempts" in warnings[1]


def test_a_mavlink_reopen_that_keeps_failing_is_a_warning_at_a_bounded_rate(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A serial telemetry link behind a symlink (as udev names a USB radio): unplugged, its
    reopen fails; that is a warning naming the path, repeated only after the interval."""
    master, slave = os.openpty()
    path = tmp_path / "ttyACM-radio"
    os.symlink(os.ttyname(slave), path)
    now = [0.0]
    link = MavlinkLink(str(path), lambda msg, t: None, clock=lambda: now[0])
    caplog.set_level(logging.WARNING, logger="mavservo.mavlink.link")
    link.start()
    try:
        path.unlink()
        os.close(master)
        os.close(slave)
        assert wait_until(lambda: link.failed_reopens >= 2, timeout=10.0)
        seen = link.failed_reopens
        now[0] += LINK_REOPEN_INTERVAL_S
        assert wait_until(lambda: link.failed_reopens > seen, timeout=10.0)
    finally:
        link.stop()
    warnings = [r.getMessage() for r in caplog.records if "cannot reopen" in r.getMessage()]
    assert len(warnings) == 2, warnings
    assert str(path) in warnings[0] and "(1 failed attempts" in warnings[0]
    later = re.search(r"\((\d+) failed attempts", warnings[1])
    assert later is not None and int(later.group(1)) > seen >= 2
