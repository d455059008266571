"""Ground-station parameters end to end: a real bridge on UDP, a pymavlink GCS, and MAVProxy.

What an integrator does in the field: fetch the list, set a trim, see the servo move by it at the
same input (no faster than its slew rate), restart, find the trim still there; and what an
attacker tries: unsigned sets on a signing bridge, sets from a source not allowed.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from mavservo.app.bridge import Bridge
from mavservo.config.overlay import load_config_with_overlay, overlay_path
from mavservo.config.parameters import parameter_table
from mavservo.mavlink.connection import mavlink2
from tests.support.bridge import MAV_CMD_DO_SET_SERVO, MAV_RESULT_ACCEPTED, Peer
from tests.support.waiting import free_udp_port, wait_until

CONFIG = """\
mavlink:
  url: udpin:127.0.0.1:{port}
{extra}servos:
  - name: aileron
    profile: rmd-x
    can_id: 1
    limits_deg: [-30, 30]
  - name: elevator
    profile: rmd-x
    can_id: 2
    limits_deg: [-25, 25]
channels:
  - {{source: servo_output, channel: 1, servo: aileron, output_deg: [-30, 30], max_slew_dps: 40}}
  - {{source: servo_output, channel: 2, servo: elevator}}
"""
KEY = "42" * 32
#: Who may set parameters in these tests (issue 32: only verified senders write): the pymavlink
#: GCS (255/190) and MAVProxy (255/230, its default source component).
WRITERS = "  allowed_sources: [{system: 255, component: 190}, {system: 255, component: 230}]\n"


class Timeline:
    """Scheduler observer: every accepted setpoint of a servo with its time."""

    def __init__(self) -> None:
        self.points: dict[str, list[tuple[float, float]]] = {}
        self._lock = threading.Lock()

    def on_setpoint(self, servo: str, seq: int, angle_deg: float, source: str, t: float) -> None:
        with self._lock:
            self.points.setdefault(servo, []).append((t, angle_deg))

    def on_tx(self, *args: Any) -> None: ...
    def on_rx(self, *args: Any) -> None: ...
    def on_lost(self, *args: Any) -> None: ...
    def on_reject(self, *args: Any) -> None: ...

    def angles(self, servo: str) -> list[float]:
        with self._lock:
            return [a for _, a in self.points.get(servo, [])]


@contextmanager
def bridge_from_file(path: Path, observers: tuple[Any, ...] = ()) -> Iterator[Bridge]:
    """The bridge as ``mavservo run --config PATH`` builds it: overlay laid over the file."""
    loaded = load_config_with_overlay(path)
    bridge = Bridge(
        loaded.config,
        config_path=path,
        log_dir=False,
        observers=observers,
        parameter_base=loaded.base,
        overlay=loaded.overlay,
    ).start()
    try:
        yield bridge
    finally:
        bridge.stop()


def write_config(tmp_path: Path, port: int, extra: str = WRITERS) -> Path:
    path = tmp_path / "rig.yaml"
    path.write_text(CONFIG.format(port=port, extra=extra))
    return path


def param_value(peer: Peer, start: int, name: str, component: int = 140) -> Any:
    found: list[Any] = []

    def arrived() -> bool:
        found[:] = [
            m
            for m in peer.since(start, "PARAM_VALUE")
            if m.param_id == name and m.get_srcComponent() == component
        ]
        return bool(found)

    return found[-1] if wait_until(arrived, 5.0) else None


def set_param(peer: Peer, name: str, value: float, **sender: int) -> Any:
    start = peer.count()
    peer.send(mavlink2.MAVLink_param_set_message(1, 140, name.encode(), value, 9), **sender)
    return param_value(peer, start, name)


def test_list_read_set_moves_the_servo_by_the_trim_and_survives_a_restart(tmp_path: Path) -> None:
    port = free_udp_port()
    path = write_config(tmp_path, port)
    timeline = Timeline()
    with bridge_from_file(path, (timeline,)) as bridge:
        peer = Peer(port)
        try:
            peer.start_heartbeats()
            expected = [p.name for p in parameter_table(bridge.config)]
            start = peer.count()
            peer.send(mavlink2.MAVLink_param_request_list_message(1, 140))
            assert wait_until(
                lambda: (
                    len({m.param_index for m in peer.since(start, "PARAM_VALUE")}) == len(expected)
                )
            )
            values = peer.since(start, "PARAM_VALUE")
            assert [m.param_id for m in sorted(values, key=lambda m: m.param_index)] == expected
            assert {m.param_count for m in values} == {len(expected)}

            assert peer.command(MAV_CMD_DO_SET_SERVO, [1, 1500]) == MAV_RESULT_ACCEPTED
            assert wait_until(lambda: timeline.angles("aileron")[-1:] == [0.0])
            before = len(timeline.angles("aileron"))

            answer = set_param(peer, "SRV1_TRIM", 3.0)
            assert answer is not None and answer.param_value == 3.0
            # same input (1500 us, no new command), the servo goes to 0 + 3 deg, in slew steps
            assert wait_until(lambda: timeline.angles("aileron")[-1:] == [3.0])
            steps = timeline.points["aileron"][before - 1 :]
            assert len(steps) > 2, "a 3-deg trim at 40 deg/s takes several command periods"
            largest = max(abs(b[1] - a[1]) for a, b in zip(steps, steps[1:], strict=False))
            period = bridge.config.scheduler.command_period_s
            assert largest <= 40 * period + 1e-9
        finally:
            peer.close()
    assert "SRV1_TRIM: 3" in overlay_path(path).read_text()

    with bridge_from_file(path, ()) as bridge:
        peer = Peer(port)
        try:
            start = peer.count()
            peer.send(mavlink2.MAVLink_param_request_read_message(1, 140, b"SRV1_TRIM", -1))
            answer = param_value(peer, start, "SRV1_TRIM")
            assert answer is not None and answer.param_value == 3.0
        finally:
            peer.close()


def test_out_of_range_set_keeps_the_old_value_says_why_and_counts(tmp_path: Path) -> None:
    port = free_udp_port()
    with bridge_from_file(write_config(tmp_path, port)) as bridge:
        peer = Peer(port)
        try:
            start = peer.count()
            answer = set_param(peer, "SRV1_MIN", 50.0)
            assert answer is not None and answer.param_value == -30.0
            texts = lambda: peer.statustexts(start)  # noqa: E731
            assert wait_until(lambda: any("SRV1_MIN 50 refused" in t for t in texts()))
            nan = set_param(peer, "SRV1_TRIM", float("nan"))
            assert nan is not None and nan.param_value == 0.0
            counters = bridge.mavlink.stats()["parameters"]
            assert counters["set_refused"] == 2
            assert not overlay_path(tmp_path / "rig.yaml").exists()
        finally:
            peer.close()


def test_unsigned_set_on_a_signing_bridge_is_ignored_and_counted(tmp_path: Path) -> None:
    port = free_udp_port()
    extra = f"  signing: {{key: '{KEY}', accept_unsigned: true}}\n"
    with bridge_from_file(write_config(tmp_path, port, extra)) as bridge:
        peer = Peer(port)
        try:
            peer.send(mavlink2.MAVLink_param_set_message(1, 140, b"SRV1_TRIM", 3.0, 9))
            peer.send(mavlink2.MAVLink_param_request_list_message(1, 140))
            assert wait_until(
                lambda: bridge.mavlink.stats()["parameters"].get("unsigned_refused") == 2
            )
            assert bridge.parameters is not None and bridge.parameters.value("SRV1_TRIM") == 0.0
            assert peer.messages("PARAM_VALUE") == []
        finally:
            peer.close()


def test_set_from_a_source_not_allowed_is_rejected(tmp_path: Path) -> None:
    port = free_udp_port()
    extra = "  allowed_sources: [{system: 255, component: 190}]\n"
    with bridge_from_file(write_config(tmp_path, port, extra)) as bridge:
        peer = Peer(port)
        try:
            start = peer.count()
            peer.send(
                mavlink2.MAVLink_param_set_message(1, 140, b"SRV1_TRIM", 2.0, 9),
                system=255,
                component=77,
            )
            assert wait_until(lambda: bridge.mavlink.stats()["core"].get("rejected_source", 0))
            # a marker: a permitted set sent after it goes the same way; once its answer is
            # here, an answer to the refused set would be too (no fixed wait for nothing)
            marker = set_param(peer, "SRV2_TRIM", 1.0)
            assert marker is not None and marker.param_value == 1.0
            refused = [m for m in peer.since(start, "PARAM_VALUE") if m.param_id == "SRV1_TRIM"]
            assert refused == []
            assert bridge.parameters is not None and bridge.parameters.value("SRV1_TRIM") == 0.0
            answer = set_param(peer, "SRV1_TRIM", 2.0)
            assert answer is not None and answer.param_value == 2.0
        finally:
            peer.close()


NO_INTEROP_ENV = "MAVSERVO_NO_INTEROP"
"""Set to 1 where the interop extra (MAVProxy) is knowingly not installed: its tests skip.
Otherwise a missing MAVProxy fails them: the README's test command installs it."""
MAVPROXY_WAIT_S = 20.0
"""Bound of each wait for MAVProxy's answer (its start loads a dozen modules)."""
SHOW_TRIES = 40
"""``param show`` is asked again (each answer awaited ``MAVPROXY_WAIT_S / SHOW_TRIES``) until
MAVProxy's cache holds the acknowledged value."""


def find_mavproxy() -> Path | None:
    """``mavproxy.py`` of the environment running the tests (its bin dir beside
    ``sys.executable``, found even when that is not on PATH, as with ``.venv/bin/python -m
    pytest``), else the one on PATH."""
    beside = Path(sys.executable).parent / "mavproxy.py"
    if beside.is_file():
        return beside
    found = shutil.which("mavproxy.py")
    return Path(found) if found else None


def mavproxy_or_fail() -> Path:
    """MAVProxy, or a skip when ``MAVSERVO_NO_INTEROP=1`` says it is not installed, or a
    failure that says how to install it."""
    found = find_mavproxy()
    if found is not None:
        return found
    if os.environ.get(NO_INTEROP_ENV) == "1":
        pytest.skip(f"{NO_INTEROP_ENV}=1: the interop extra (MAVProxy) is not installed")
    pytest.fail(
        f"mavproxy.py is neither beside {sys.executable} nor on PATH: install the interop "
        "extra (pip install '.[test,interop]', the README's test command), or set "
        f"{NO_INTEROP_ENV}=1 to skip the tests that need it",
        pytrace=False,
    )


class MavproxyConsole:
    """MAVProxy's console: commands go to its stdin, a thread collects its output lines (it
    ends when MAVProxy closes its stdout), and every wait for an answer is bounded."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        assert proc.stdin is not None and proc.stdout is not None
        self.proc = proc
        self._lines: list[str] = []
        self._lock = threading.Lock()
        self._reader = threading.Thread(target=self._read, name="mavproxy-out", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            with self._lock:
                self._lines.append(line)

    def mark(self) -> int:
        with self._lock:
            return len(self._lines)

    def text(self, start: int = 0) -> str:
        with self._lock:
            return "".join(self._lines[start:])

    def send(self, command: str) -> int:
        """Send ``command``; the mark of the output that follows it."""
        start = self.mark()
        assert self.proc.stdin is not None
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()
        return start

    def wait_for(self, text: str, start: int, timeout: float = MAVPROXY_WAIT_S) -> bool:
        return wait_until(lambda: text in self.text(start), timeout, interval=0.05)

    def close(self) -> str:
        """``exit`` and end of input; killed if it does not go in time. All it printed."""
        assert self.proc.stdin is not None
        try:
            self.send("exit")
            self.proc.stdin.close()
            self.proc.wait(timeout=MAVPROXY_WAIT_S)
        except (OSError, subprocess.TimeoutExpired):
            self.proc.kill()
            self.proc.wait(timeout=5)
        self._reader.join(5)
        return self.text()


def test_mavproxy_fetches_sets_and_shows_with_no_time_out(tmp_path: Path) -> None:
    """MAVProxy with its default modules: FTP is answered NAK at once (it falls back to the
    list), the list arrives complete, the set is acknowledged, nothing times out. Each step
    waits (bounded) for MAVProxy's answer to the one before; no fixed sleeps."""
    mavproxy = mavproxy_or_fail()
    port = free_udp_port()
    path = write_config(tmp_path, port)
    with bridge_from_file(path) as bridge:
        received = f"Received {len(parameter_table(bridge.config))} parameters"
        console = MavproxyConsole(
            subprocess.Popen(
                [
                    sys.executable,
                    str(mavproxy),
                    f"--master=udpout:127.0.0.1:{port}",
                    "--target-system=1",
                    "--target-component=140",
                    "--nowait",
                    f"--state-basedir={tmp_path}",
                ],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
                cwd=tmp_path,
            )
        )
        try:
            # MAVProxy loads its modules, sees the bridge and fetches the list by itself
            assert console.wait_for("Detected vehicle 1:140", 0), console.text()
            assert console.wait_for(received, 0), console.text()
            start = console.send("param fetch")
            assert console.wait_for(received, start), console.text(start)
            console.send("param set SRV1_TRIM 3")
            # acknowledged by a PARAM_VALUE, which MAVProxy's cache (param show) then holds
            for _ in range(SHOW_TRIES):
                start = console.send("param show SRV1_TRIM")
                if console.wait_for("SRV1_TRIM        3.0", start, MAVPROXY_WAIT_S / SHOW_TRIES):
                    break
            else:
                raise AssertionError(f"SRV1_TRIM never showed 3.0:\n{console.text()}")
            start = console.send("param set SRV2_MIN 99")
            assert console.wait_for("SRV2_MIN 99 refused", start), console.text(start)
        finally:
            output = console.close()
        lowered = output.lower()
        assert "timeout" not in lowered and "timed out" not in lowered, output
        # MAVProxy first asks FTP for @PARAM/param.pck: "file not found" at once, then the list
        assert bridge.mavlink.stats()["ftp"]["140"].get("not_found", 0) >= 1
    assert "SRV1_TRIM: 3" in overlay_path(path).read_text()
