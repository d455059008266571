"""tlog reading and replay, against the real ArduPlane SITL recordings in tests/data."""

from __future__ import annotations

import hashlib
import json
import os
import re
import signal
import subprocess
import sys
import threading
from collections import Counter
from functools import cache
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mavservo.sim.autopilot.replay import (
    BRIDGE_TYPES,
    TlogError,
    iter_tlog,
    iter_tlog_records,
    replay,
)
from mavservo.sim.autopilot.sitl_command import main
from tests.support.autopilot import collect, of_type, peer
from tests.support.paths import REPO, TEST_DATA
from tests.support.signals import default_signal_dispositions
from tests.support.waiting import free_udp_port

DATA = TEST_DATA
SERVOS = DATA / "plane-servos.tlog"
GIMBAL = DATA / "plane-gimbal.tlog"
CHANNELS = [f"servo{i}_raw" for i in range(1, 17)]


def _channels(msg) -> tuple[int, ...]:
    return tuple(getattr(msg, name) for name in CHANNELS)


def test_fixtures_match_the_sizes_and_hashes_documented_in_their_readme() -> None:
    readme = (DATA / "README.md").read_text()
    rows = re.findall(r"`([\w-]+\.tlog)` \| (\d+) \| `([0-9a-f]{64})`", readme)
    assert {name for name, _, _ in rows} == {SERVOS.name, GIMBAL.name}
    for name, size, digest in rows:
        data = (DATA / name).read_bytes()
        assert len(data) == int(size)
        assert hashlib.sha256(data).hexdigest() == digest


def test_iter_tlog_reads_every_message_of_both_recordings() -> None:
    servos = Counter(m.get_type() for _, m in iter_tlog(SERVOS, None))
    gimbal = Counter(m.get_type() for _, m in iter_tlog(GIMBAL, None))
    assert sum(servos.values()) == 4462 and servos["SERVO_OUTPUT_RAW"] == 1785
    assert sum(gimbal.values()) == 7164 and gimbal["GIMBAL_DEVICE_SET_ATTITUDE"] == 2708
    assert gimbal["AUTOPILOT_STATE_FOR_GIMBAL_DEVICE"] == 2548
    times = [t for t, _ in iter_tlog(SERVOS, None)]
    assert times[0] == 0.0 and times == sorted(times)
    assert times[-1] == pytest.approx(89.96, abs=0.01)


def test_iter_tlog_filters_types_and_keeps_original_bytes() -> None:
    default = Counter(m.get_type() for _, m in iter_tlog(SERVOS))
    assert set(default) <= BRIDGE_TYPES and default["SERVO_OUTPUT_RAW"] == 1785
    records = [frame for _, frame in iter_tlog_records(SERVOS.read_bytes())]
    sent = {bytes(m.get_msgbuf()) for _, m in iter_tlog(SERVOS, {"SERVO_OUTPUT_RAW"})}
    assert len(sent) == 1785 and sent <= set(records)


def _reference_servo_outputs(path: Path) -> list[list[int]]:
    """SERVO_OUTPUT_RAW channels as pymavlink's own tlog reader sees them (a separate process,
    because mavutil's tlog reader flips pymavlink's process-wide MAVLink 1/2 switch)."""
    code = (
        "import json, sys\n"
        "from pymavlink import mavutil\n"
        "log = mavutil.mavlink_connection(sys.argv[1], dialect='ardupilotmega')\n"
        "out = []\n"
        "while True:\n"
        "    m = log.recv_match(type='SERVO_OUTPUT_RAW')\n"
        "    if m is None: break\n"
        f"    out.append([getattr(m, n) for n in {CHANNELS!r}])\n"
        "print(json.dumps(out))\n"
    )
    env = {**os.environ, "MAVLINK20": "1"}
    done = subprocess.run(
        [sys.executable, "-c", code, str(path)],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
        check=True,
    )
    return json.loads(done.stdout)


def test_iter_tlog_agrees_with_pymavlinks_own_reader() -> None:
    ours = [list(_channels(m)) for _, m in iter_tlog(SERVOS, {"SERVO_OUTPUT_RAW"})]
    assert ours == _reference_servo_outputs(SERVOS)


def test_replay_delivers_every_servo_output_in_order_with_identical_values() -> None:
    port = free_udp_port()
    conn = peer(port)
    expected = [(m.time_usec, _channels(m)) for _, m in iter_tlog(SERVOS, {"SERVO_OUTPUT_RAW"})]
    results = {}
    worker = threading.Thread(
        target=lambda: results.setdefault(
            "r", replay(SERVOS, f"udpout:127.0.0.1:{port}", speed=40.0, max_duration_s=20.0)
        )
    )
    try:
        worker.start()
        messages = collect(
            conn,
            20.0,
            until=lambda m: m.get_type() == "SERVO_OUTPUT_RAW" and m.time_usec == expected[-1][0],
        )
        worker.join(20.0)
    finally:
        conn.close()
    outputs = of_type(messages, "SERVO_OUTPUT_RAW")
    assert [(m.time_usec, _channels(m)) for m in outputs] == expected
    assert {(m.get_srcSystem(), m.get_srcComponent()) for m in outputs} == {(1, 1)}
    assert {m.get_type() for _, m in messages} <= BRIDGE_TYPES
    result = results["r"]
    assert result.per_type["SERVO_OUTPUT_RAW"] == 1785 and not result.stopped


def test_replay_of_the_gimbal_session_delivers_every_set_attitude() -> None:
    port = free_udp_port()
    conn = peer(port, component=154)
    wanted = {"GIMBAL_DEVICE_SET_ATTITUDE"}
    expected = [bytes(m.get_msgbuf()) for _, m in iter_tlog(GIMBAL, wanted)]
    worker = threading.Thread(
        target=replay,
        args=(GIMBAL, f"udpout:127.0.0.1:{port}"),
        kwargs={"speed": 40.0, "types": wanted, "max_duration_s": 20.0},
    )
    try:
        worker.start()
        messages = collect(conn, 20.0, limit=len(expected))
        worker.join(20.0)
    finally:
        conn.close()
    assert [bytes(m.get_msgbuf()) for _, m in messages] == expected


class _FakeClock:
    """Time that only moves when the replay sleeps: pacing becomes exact and instant."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += seconds


class _Sink:
    def __init__(self, clock: _FakeClock) -> None:
        self.clock = clock
        self.writes: list[tuple[float, bytes]] = []

    def write(self, data: bytes) -> None:
        self.writes.append((self.clock(), bytes(data)))


@pytest.mark.parametrize("speed", [1.0, 4.0, 25.0])
def test_replay_paces_messages_by_their_recorded_times_over_speed(speed: float) -> None:
    clock = _FakeClock()
    sink = _Sink(clock)
    wanted = {"HEARTBEAT"}
    result = replay(
        SERVOS,
        sink,
        speed=speed,
        types=wanted,
        start_s=10.0,
        end_s=40.0,
        clock=clock,
        sleep=clock.sleep,
    )
    recorded = [t for t, _ in iter_tlog(SERVOS, wanted) if 10.0 <= t <= 40.0]
    assert result.sent == len(recorded) == len(sink.writes)
    for (sent_at, _), t_rel in zip(sink.writes, recorded, strict=True):
        assert sent_at - 100.0 == pytest.approx((t_rel - recorded[0]) / speed, abs=1e-6)


def test_replay_is_bounded_by_max_duration_and_by_stop() -> None:
    clock = _FakeClock()
    sink = _Sink(clock)
    result = replay(SERVOS, sink, speed=1.0, max_duration_s=5.0, clock=clock, sleep=clock.sleep)
    assert result.stopped and 0 < result.sent < 1785
    assert all(t - 100.0 <= 5.0 for t, _ in sink.writes)
    stop = threading.Event()
    stop.set()
    stopped = replay(SERVOS, _Sink(clock), stop=stop, clock=clock, sleep=clock.sleep)
    assert stopped.stopped and stopped.sent == 0


def test_as_fast_sends_everything_without_sleeping() -> None:
    clock = _FakeClock()
    sink = _Sink(clock)
    result = replay(SERVOS, sink, as_fast=True, clock=clock, sleep=clock.sleep)
    assert clock.now == 100.0 and result.sent == sum(1 for _ in iter_tlog(SERVOS))


@cache
def _all_frames() -> list[bytes]:
    return [bytes(m.get_msgbuf()) for _, m in iter_tlog(SERVOS, None)]


@settings(max_examples=60, deadline=None)
@given(cut=st.integers(min_value=1, max_value=4000), garbage=st.binary(max_size=30))
def test_damaged_tlog_raises_tlog_error_or_yields_a_clean_prefix(
    cut: int, garbage: bytes, tmp_path_factory
) -> None:
    data = SERVOS.read_bytes()[:4000]
    path = tmp_path_factory.mktemp("tlog") / "damaged.tlog"
    path.write_bytes(data[:cut] + garbage)
    full = _all_frames()
    got: list[bytes] = []
    try:
        for _, msg in iter_tlog(path, None):
            got.append(bytes(msg.get_msgbuf()))
    except TlogError:
        pass
    assert got == full[: len(got)] or got[:-1] == full[: len(got) - 1]


def test_cli_replay_reports_a_bad_file_with_status_2(tmp_path, capsys) -> None:
    bad = tmp_path / "bad.tlog"
    bad.write_bytes(b"\x00" * 8 + b"\x42" * 20)
    assert main(["replay", str(bad), "--url", "udpout:127.0.0.1:9", "--as-fast"]) == 2
    assert "offset" in capsys.readouterr().err


def test_cli_replay_as_fast_sends_the_selected_types(capsys) -> None:
    port = free_udp_port()
    before = signal.getsignal(signal.SIGINT)
    assert (
        main(
            [
                "replay",
                str(SERVOS),
                "--url",
                f"udpout:127.0.0.1:{port}",
                "--as-fast",
                "--types",
                "heartbeat",
                "--end",
                "10",
            ]
        )
        == 0
    )
    assert "'HEARTBEAT'" in capsys.readouterr().out
    assert signal.getsignal(signal.SIGINT) is before  # the caller's handler is restored


@pytest.mark.parametrize(
    "command",
    [
        ["stream", "--profile", "staircase"],
        ["replay", str(SERVOS)],
    ],
)
def test_cli_exits_zero_on_sigint(command: list[str]) -> None:
    port = free_udp_port()
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "mavservo.sim.autopilot", *command]
        + ["--url", f"udpout:127.0.0.1:{port}"],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=default_signal_dispositions,  # SIGINT is ignored in a background job
    )
    try:
        banner = proc.stdout.readline()  # printed once the signal handlers are in place
        assert banner.startswith("sitl: ")
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=15)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
    assert proc.returncode == 0, err
    assert "Traceback" not in err


def test_cli_stream_scripted_and_on_demand_dropouts() -> None:
    port = free_udp_port()
    conn = peer(port)
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "mavservo.sim.autopilot",
            "stream",
            "--profile",
            "hold",
            "--url",
            f"udpout:127.0.0.1:{port}",
            "--duration",
            "4",
            "--dropout",
            "0.5:0.6",
            "--dropout-seconds",
            "1.0",
        ],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=default_signal_dispositions,  # SIGINT is ignored in a background job
    )
    try:
        assert proc.stdout.readline().startswith("sitl: streaming")
        messages = collect(conn, 2.0)
        proc.send_signal(signal.SIGUSR1)
        for _ in range(60):  # until the stream ends by itself (--duration 4), at most ~12 s
            messages += collect(conn, 0.2)
            if proc.poll() is not None:
                break
        out, err = proc.communicate(timeout=15)
    finally:
        conn.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
    assert proc.returncode == 0, err
    assert out.count("drop-out") == 2
    stamps = [m.time_usec for m in of_type(messages, "SERVO_OUTPUT_RAW")]
    gaps = sorted((b - a for a, b in zip(stamps, stamps[1:], strict=False)), reverse=True)
    assert gaps[0] >= 1.0e6 and gaps[1] >= 0.6e6  # both silences show in the autopilot's clock


pwm = st.integers(min_value=0, max_value=65535)


@settings(max_examples=40, deadline=None)
@given(
    frames=st.lists(
        st.tuples(st.integers(0, 10**6), st.lists(pwm, min_size=16, max_size=16), st.booleans()),
        min_size=1,
        max_size=30,
    )
)
def test_written_tlog_reads_back_exactly(frames, tmp_path_factory) -> None:
    """Round trip: messages packed as MAVLink 2 (or 1) into tlog records come back unchanged."""
    from mavservo.mavlink.connection import mavlink2

    encoder = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    stamp = 1_795_302_091_605_568
    blob = bytearray()
    expected = []
    for i, (gap_us, channels, as_v1) in enumerate(frames):
        stamp += gap_us
        if as_v1:
            msg = mavlink2.MAVLink_heartbeat_message(1, 3, 81, i, 3, 3)
            buf = msg.pack(encoder, force_mavlink1=True)
            expected.append((stamp, "HEARTBEAT", (i,)))
        else:
            msg = mavlink2.MAVLink_servo_output_raw_message(i, 0, *channels)
            buf = msg.pack(encoder)
            expected.append((stamp, "SERVO_OUTPUT_RAW", tuple(channels)))
        blob += stamp.to_bytes(8, "big") + buf
    path = tmp_path_factory.mktemp("rt") / "roundtrip.tlog"
    path.write_bytes(bytes(blob))
    got = []
    for t_rel, msg in iter_tlog(path, None):
        content = (msg.custom_mode,) if msg.get_type() == "HEARTBEAT" else _channels(msg)
        got.append((t_rel, msg.get_type(), content))
    first = expected[0][0]
    assert [(name, content) for _, name, content in got] == [(n, c) for _, n, c in expected]
    for (t_rel, _, _), (stamp_us, _, _) in zip(got, expected, strict=True):
        assert t_rel == pytest.approx((stamp_us - first) / 1e6, abs=1e-9)
