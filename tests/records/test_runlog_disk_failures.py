"""The run log when the disk fails it: full disk, file-size limit, size cap, SIGKILL, modes.

Real failures, no mocks: ``/dev/full`` (every write is ENOSPC) behind a symlink for one file,
``RLIMIT_FSIZE`` in a child process (writes past the limit fail with EFBIG, as on a full
disk, after a part of the file was written), a real SIGKILL. Every wait is bounded in count
and time; nothing asserts how long anything took.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import stat
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import can
import pytest

from mavservo.config import ConfigError, load_config_text
from mavservo.records.runlog import (
    METRICS_FILE,
    RUN_HEADER,
    TRACE_FILE,
    RunLog,
    can_log_files,
    new_run_dir,
    read_can_log,
)
from tests.support.paths import REPO

DEV_FULL = Path("/dev/full")
needs_dev_full = pytest.mark.skipif(not DEV_FULL.exists(), reason="no /dev/full")
ROOT = REPO


def _frame(i: int) -> can.Message:
    return can.Message(
        arbitration_id=0x140 + i % 4, data=bytes([i % 256] * 8), is_extended_id=False
    )


def _wait_for(condition, timeout: float = 20.0) -> bool:
    """Poll ``condition`` (bounded: ``timeout`` seconds, 0.02 s steps)."""
    for _ in range(int(timeout / 0.02)):
        if condition():
            return True
        time.sleep(0.02)
    return condition()


def _no_tmp_files(*directories: Path) -> list[Path]:
    return [p for d in directories for p in d.rglob("*.tmp")]


def test_run_directory_is_0700_and_every_file_0600_whatever_the_umask(tmp_path: Path) -> None:
    old = os.umask(0o002)
    try:
        run_dir = new_run_dir(tmp_path / "runs")
        log = RunLog(run_dir, formats=("asc", "blf"), rotate_bytes=2000)
        for i in range(400):  # enough to rotate both CAN logs several times
            log.on_tx("bus0", _frame(i), time.monotonic(), "command", "a", i)
            log.on_setpoint("a", i, 1.0, "test", time.monotonic())
        log.close()
    finally:
        os.umask(old)
    assert stat.S_IMODE(run_dir.stat().st_mode) == 0o700
    files = sorted(run_dir.iterdir())
    assert len(can_log_files(run_dir, "blf")) > 1, "the test meant to rotate"
    assert {p.name: oct(stat.S_IMODE(p.stat().st_mode)) for p in files} == {
        p.name: "0o600" for p in files
    }


@needs_dev_full
def test_a_full_disk_is_said_once_the_other_files_go_on_and_metrics_are_written(
    tmp_path: Path,
) -> None:
    (tmp_path / TRACE_FILE).symlink_to(DEV_FULL)
    said: list[str] = []
    log = RunLog(tmp_path, formats=("asc",), on_problem=said.append)
    for i in range(50):
        log.on_setpoint("a", i, float(i), "test", time.monotonic())
        log.on_tx("bus0", _frame(i), time.monotonic(), "command", "a", i)
    assert _wait_for(lambda: said), "the full disk was never reported"
    for i in range(50):  # more rows for the dead file: counted, not said again
        log.on_setpoint("a", i, float(i), "test", time.monotonic())
    assert _wait_for(lambda: log.flushes >= 2)
    log.close({"marker": 1})
    assert len(said) == 1
    assert TRACE_FILE in said[0] and "No space left on device" in said[0]
    metrics = json.loads((tmp_path / METRICS_FILE).read_text())
    assert metrics["marker"] == 1
    assert metrics["runlog"]["write_errors"] >= 1
    assert TRACE_FILE in metrics["runlog"]["failed_files"]
    assert metrics["runlog"]["dropped"]["write_failed"] >= 50
    assert len(read_can_log(tmp_path, "asc")) == 50  # the CAN log was not affected
    outcome = log.outcome()
    assert outcome["complete"] is False
    assert outcome["metrics_path"] == str(tmp_path / METRICS_FILE)
    assert _no_tmp_files(tmp_path) == []


@needs_dev_full
def test_metrics_go_to_the_fallback_when_the_run_directory_is_full(tmp_path: Path) -> None:
    run_dir, fallback = tmp_path / "run", tmp_path / "fallback"
    run_dir.mkdir()
    fallback.mkdir()
    said: list[str] = []
    log = RunLog(run_dir, formats=(), on_problem=said.append, fallback_dir=fallback)
    (run_dir / (METRICS_FILE + ".tmp")).symlink_to(DEV_FULL)
    log.close({"marker": 2})
    outcome = log.outcome()
    assert outcome["metrics_path"] == str(fallback / f"mavservo-run-{METRICS_FILE}")
    assert json.loads(Path(outcome["metrics_path"]).read_text())["marker"] == 2
    assert stat.S_IMODE(Path(outcome["metrics_path"]).stat().st_mode) == 0o600
    assert not (run_dir / METRICS_FILE).exists()
    assert any("written to" in text and str(fallback) in text for text in said)
    assert _no_tmp_files(run_dir, fallback) == []


@needs_dev_full
def test_a_header_that_cannot_be_rewritten_leaves_the_start_header_and_no_tmp(
    tmp_path: Path,
) -> None:
    said: list[str] = []
    log = RunLog(tmp_path, formats=(), on_problem=said.append)
    (tmp_path / (RUN_HEADER + ".tmp")).symlink_to(DEV_FULL)
    log.close()
    header = json.loads((tmp_path / RUN_HEADER).read_text())
    assert header["format"] == "mavservo-run" and header["end_wall"] is None
    assert any(RUN_HEADER in text for text in said)
    assert _no_tmp_files(tmp_path) == []
    assert (tmp_path / METRICS_FILE).exists()


def test_the_size_cap_stops_every_file_growing_and_says_so(tmp_path: Path) -> None:
    said: list[str] = []
    log = RunLog(tmp_path, formats=("asc", "blf"), max_run_bytes=40_000, on_problem=said.append)
    t0 = time.monotonic()
    for batch in range(100):  # bounded: 100 batches of 200 frames, ~9 KB of ASC per batch
        for i in range(200):
            log.on_tx("bus0", _frame(i), t0 + batch + i * 1e-3, "command", "a", i)
        flushes = log.flushes
        assert _wait_for(lambda: log.flushes > flushes)  # noqa: B023 - read at once
        if log.capped:
            break
    assert log.capped, "never reached the cap"
    sizes = {p.name: p.stat().st_size for p in tmp_path.iterdir()}
    for i in range(2000):
        log.on_tx("bus0", _frame(i), t0 + 200 + i * 1e-3, "command", "a", i)
    log.close()
    after = {p.name: p.stat().st_size for p in tmp_path.iterdir()}
    growing = {n for n in sizes if n not in (RUN_HEADER,) and after[n] > sizes[n]}
    # Stopping a writer closes its file (the ASC end line, the BLF's last container): only that.
    assert all(after[n] - sizes[n] < 1000 for n in growing), (sizes, after)
    assert log.counters()["dropped"]["cap"] >= 2000
    assert len(said) == 1 and "size cap" in said[0]
    assert json.loads((tmp_path / METRICS_FILE).read_text())["runlog"]["capped"] is True


def test_the_cap_is_a_logging_setting_with_a_safe_default() -> None:
    servo = "servos:\n  - {name: a, profile: rmd-x, can_id: 1, limits_deg: [-30, 30]}\n"
    assert load_config_text(servo).logging.max_run_mb == 1024
    assert load_config_text(servo + "logging: {max_run_mb: 5}\n").logging.max_run_mb == 5
    with pytest.raises(ConfigError, match=r"<config>:3: logging.max_run_mb"):
        load_config_text(servo + "logging: {max_run_mb: 0}\n")


# ------------------------------------------------------------ real failures in a child process

_FSIZE_CHILD = textwrap.dedent(
    """
    import json, resource, signal, sys, time
    import can
    from mavservo.records.runlog import RunLog
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # past the limit: EFBIG, like a full disk
    limit = int(sys.argv[2])
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    said = []
    log = RunLog(sys.argv[1], formats=("asc", "blf"), on_problem=said.append)
    t0 = time.monotonic()
    for n in range(400_000):  # bounded; stops as soon as every event file has failed
        t = t0 + n * 1e-3
        msg = can.Message(arbitration_id=0x141, data=bytes([n % 256] * 8), is_extended_id=False)
        log.on_tx("bus0", msg, t, "command", "a", n)
        log.on_setpoint("a", n, n * 0.01, "test", t)
        if len(log.failed_files) >= 3:
            break
        if n % 500 == 0:
            time.sleep(0.01)
    log.close({"sent": n})
    print(json.dumps({"said": said, "outcome": {k: v for k, v in log.outcome().items()
                                                if k != "metrics"}}))
    """
)


def test_files_that_hit_a_write_limit_end_on_whole_rows_and_stay_readable(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    proc = subprocess.run(
        [sys.executable, "-c", _FSIZE_CHILD, str(run_dir), str(60_000)],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
    )
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert len(result["said"]) == 1, result["said"]  # one line per kind of problem
    assert "File too large" in result["said"][0]
    failed = result["outcome"]["failed_files"]
    assert {"can.asc", TRACE_FILE} <= set(failed)
    with open(run_dir / TRACE_FILE, newline="") as handle:
        rows = list(csv.reader(handle))
    assert len(rows) > 100
    assert all(len(row) == 9 for row in rows), rows[-3:]  # no torn last row
    asc = read_can_log(run_dir, "asc")
    blf = read_can_log(run_dir, "blf")
    assert len(asc) > 100 and len(blf) > 100
    for frames in (asc, blf):
        assert [m.data[0] for m in frames] == [n % 256 for n in range(len(frames))]
    metrics = json.loads((run_dir / METRICS_FILE).read_text())
    assert metrics["runlog"]["write_errors"] >= 3
    assert _no_tmp_files(run_dir) == []


_KILL_CHILD = textwrap.dedent(
    """
    import sys, time
    import can
    from mavservo.records.runlog import RunLog
    log = RunLog(sys.argv[1], formats=("asc", "blf"))
    t0 = time.monotonic()
    count = 300
    for n in range(count):
        msg = can.Message(arbitration_id=0x141, data=bytes([n % 256] * 8), is_extended_id=False)
        log.on_tx("bus0", msg, t0 + n * 1e-3, "command", "a", n)
    for _ in range(2000):  # bounded: until every frame is written and flushed twice after
        if log.written["can"] == count:
            break
        time.sleep(0.01)
    flushes = getattr(log, "flushes", None)  # (the code before flushes were counted: 3 s)
    for _ in range(2000 if flushes is not None else 300):
        if flushes is not None and log.flushes >= flushes + 2:
            break
        time.sleep(0.01)
    print("flushed", log.wall_offset + t0, flush=True)
    time.sleep(60)
    """
)


def test_a_killed_run_keeps_its_blf_frames_with_wall_clock_times(tmp_path: Path) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-c", _KILL_CHILD, str(tmp_path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    try:
        line = proc.stdout.readline()  # bounded by the child's own loops
        assert line.startswith("flushed"), proc.stderr.read() if proc.poll() is not None else line
        first_wall = float(line.split()[1])
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(30)
    with can.BLFReader(tmp_path / "can.blf") as reader:
        frames = list(reader)
    assert len(frames) == 300
    assert [m.data[0] for m in frames] == [n % 256 for n in range(300)]
    # times are wall clock (BLF keeps milliseconds for its start): not counted from 1970
    assert frames[0].timestamp == pytest.approx(first_wall, abs=0.002)
    assert frames[-1].timestamp == pytest.approx(first_wall + 0.299, abs=0.002)
    assert len(read_can_log(tmp_path, "asc")) == 300


_RUN_CHILD = textwrap.dedent(
    """
    import resource, signal, sys
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    limit = int(sys.argv[1])
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    from mavservo.app.run import main
    sys.exit(main(sys.argv[2:]))
    """
)


def test_mavservo_run_says_at_once_that_its_log_failed_and_the_summary_says_incomplete(
    tmp_path: Path,
) -> None:
    proc = subprocess.run(
        # half the size and half the time of the first version: the CAN text log (about 26 kB
        # a second on the default simulation) still passes the limit about 3 s into the run,
        # and metrics.json (about 33 kB) is still written whole at the end
        [sys.executable, "-c", _RUN_CHILD, str(75_000), "--duration", "4", "--quiet"]
        + ["--log-dir", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
    )
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout
    events = [
        line
        for line in proc.stdout.splitlines()
        if line.startswith("[") and "run log: cannot write" in line
    ]
    assert len(events) == 1, proc.stdout  # the bridge's event line (also sent as STATUSTEXT)
    assert "File too large" in events[0]
    # the console's one line format: [HH:MM:SS] LEVEL source: text
    assert proc.stderr.count("ERROR   records.runlog: run log: cannot write") == 1, proc.stderr
    summary = proc.stdout[proc.stdout.index("mavservo summary") :]
    assert "INCOMPLETE" in summary
    [run_dir] = list(tmp_path.iterdir())
    assert json.loads((run_dir / METRICS_FILE).read_text())["runlog"]["failed_files"]
    assert _no_tmp_files(tmp_path) == []


def test_a_run_log_problem_reaches_the_autopilot_as_statustext(tmp_path: Path) -> None:
    """The size cap (0.001 MiB: reached at the first check) through the real bridge and link."""
    from pymavlink import mavutil

    from mavservo.app.bridge import Bridge, free_udp_port

    port = free_udp_port()
    listener = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255)
    config = load_config_text(
        f'mavlink: {{url: "udpout:127.0.0.1:{port}"}}\n'
        "can:\n  buses:\n    - {name: a, interface: virtual, channel: runlog-cap-test}\n"
        "servos:\n  - {name: s, profile: rmd-x, can_id: 1, limits_deg: [-30, 30]}\n"
        "logging: {max_run_mb: 0.001, can_formats: [asc]}\n",
        "cap.yaml",
    )
    events: list[str] = []
    bridge = Bridge(config, log_dir=tmp_path, status=events.append)
    texts: list[str] = []
    try:
        bridge.start()
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not any("size cap" in t for t in texts):
            msg = listener.recv_match(type="STATUSTEXT", blocking=True, timeout=0.5)
            if msg is not None:
                texts.append(msg.text)
    finally:
        summary = bridge.stop()
        listener.close()
    assert any(t.startswith("run log reached its size cap") for t in texts), texts
    assert sum("size cap" in e for e in events) == 1
    assert summary["runlog"]["capped"] is True and summary["runlog"]["complete"] is False


def test_a_blf_log_on_disk_lacks_at_most_blf_flush_frames_between_flushes(tmp_path: Path) -> None:
    """Issue 37: after ``kill -9`` can.blf was 714 of 17,997 frames short (flushed once a second
    only, late on a loaded machine). What is on disk without any timed flush (what a killed
    process leaves) lacks fewer than ``BLF_FLUSH_FRAMES`` of the frames handed in."""
    from mavservo.records.can_log import BLF_FLUSH_FRAMES, CanFrameLogs

    logs = CanFrameLogs(tmp_path, ("blf",), 10**8, time.time(), lambda *_: None)
    count = 3 * BLF_FLUSH_FRAMES + 17
    for n in range(count):
        logs.write(can.Message(arbitration_id=0x141, data=bytes([n % 256] * 8), timestamp=n))
    frames = read_can_log(tmp_path, "blf")  # the writer still open: no stop, no timed flush
    assert count - BLF_FLUSH_FRAMES < len(frames) <= count
    assert [m.data[0] for m in frames] == [n % 256 for n in range(len(frames))]
    logs.close()
    assert len(read_can_log(tmp_path, "blf")) == count
