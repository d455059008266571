"""The run log's parts, each alone: the bounded queue and its writer thread, the problem
report, a buffered sink, the CAN logs of several formats and the event files.

The whole ``RunLog`` is tested in test_runlog.py and test_runlog_disk_failures.py; here each
part is driven through its own narrow interface (a list stands in for the files behind the
queue; ``/dev/full`` behind a symlink is a real full disk). No test waits on time: a thread is
stopped, and ``stop`` drains what was queued.
"""

from __future__ import annotations

import errno
from pathlib import Path

import can
import pytest

from mavservo.records.can_log import CanFrameLogs, read_can_log
from mavservo.records.event_pump import EventPump
from mavservo.records.problems import RunLogProblems
from mavservo.records.run_events import LOST, MAV_IN, REJECT, SETPOINT, TX, Event
from mavservo.records.run_files import TLOG_FILE, TRACE_FILE, RunFiles
from mavservo.records.sink import BufferedSink

DEV_FULL = Path("/dev/full")
needs_dev_full = pytest.mark.skipif(not DEV_FULL.exists(), reason="no /dev/full")


class ListWriter:
    """The files behind the queue, as a list; ``fail`` makes chosen events raise."""

    def __init__(self, fail: dict[int, Exception] | None = None) -> None:
        self.items: list[Event] = []
        self.capped = False
        self.flushes = 0
        self._fail = fail or {}

    def write(self, item: Event) -> None:
        if item[1] in self._fail:
            raise self._fail[item[1]]
        self.items.append(item)

    def flush(self) -> None:
        self.flushes += 1


def test_pump_writes_every_queued_event_in_order_when_stopped() -> None:
    writer = ListWriter()
    pump = EventPump(writer, RunLogProblems(), queue_size=100)
    events = [(SETPOINT, n, 1.0, float(n)) for n in range(50)]
    for event in events:
        pump.put(event)
    pump.start()
    pump.stop(5.0)
    assert writer.items == events
    assert pump.written == {"trace": 50} and not pump.dropped


def test_pump_drops_and_counts_past_its_bound_without_blocking_the_caller() -> None:
    writer = ListWriter()
    pump = EventPump(writer, RunLogProblems(), queue_size=3)  # not started: nothing drains
    for n in range(5):
        pump.put((SETPOINT, n, 1.0, 0.0))
    pump.put((MAV_IN, b"\xfd", 0.0))
    pump.start()
    pump.stop(5.0)
    assert [item[1] for item in writer.items] == [0, 1, 2]
    assert pump.dropped == {"trace": 2, "mavlink": 1}


def test_pump_counts_failed_and_odd_events_and_goes_on() -> None:
    problems = RunLogProblems()
    writer = ListWriter(fail={1: OSError(errno.ENOSPC, "full"), 2: ValueError("odd")})
    pump = EventPump(writer, problems, queue_size=10)
    for n in range(4):
        pump.put((SETPOINT, n, 1.0, 0.0))
    pump.start()
    pump.stop(5.0)
    assert [item[1] for item in writer.items] == [0, 3]
    assert pump.dropped == {"write_failed": 1}
    assert problems.write_errors == 1 and problems.last_error == "ValueError: odd"


def test_pump_drops_everything_once_the_writer_is_capped() -> None:
    writer = ListWriter()
    writer.capped = True
    pump = EventPump(writer, RunLogProblems(), queue_size=10)
    pump.put((SETPOINT, 0, 1.0, 0.0))
    pump.start()
    pump.stop(5.0)
    assert writer.items == [] and pump.dropped == {"cap": 1} and not pump.written


def test_problems_name_each_file_once_and_tell_each_kind_once() -> None:
    said: list[str] = []
    problems = RunLogProblems(on_problem=said.append)
    full = OSError(errno.ENOSPC, "No space left on device")
    problems.file_failed("trace.csv", full)
    problems.file_failed("trace.csv", full)  # the same file again: not counted again
    problems.file_failed("latency.csv", full)  # the same kind: kept, not told again
    assert problems.failed_files == {
        "trace.csv": "No space left on device",
        "latency.csv": "No space left on device",
    }
    assert problems.write_errors == 2 and len(problems.problems) == 2
    assert len(said) == 1 and "cannot write trace.csv" in said[0]
    problems.report("cap", "size cap")
    assert said[-1] == "size cap"


def test_problems_survive_a_broken_listener() -> None:
    def broken(text: str) -> None:
        raise RuntimeError("listener down")

    problems = RunLogProblems(on_problem=broken)
    problems.report("cap", "size cap")  # does not raise
    assert problems.problems == ["size cap"]


def test_sink_writes_records_on_flush_only(tmp_path: Path) -> None:
    sink = BufferedSink(tmp_path / "rows.csv", text=True)
    sink.write("a,1\n")
    sink.write("b,2\n")
    assert (tmp_path / "rows.csv").read_text() == ""
    sink.flush()
    assert (tmp_path / "rows.csv").read_text() == "a,1\nb,2\n"
    assert sink.good_size == 8
    sink.close()


@needs_dev_full
def test_sink_on_a_full_disk_fails_once_and_refuses_more(tmp_path: Path) -> None:
    (tmp_path / "rows.csv").symlink_to(DEV_FULL)
    sink = BufferedSink(tmp_path / "rows.csv", text=True)
    sink.write("a,1\n")
    with pytest.raises(OSError) as failed:
        sink.flush()
    assert failed.value.errno == errno.ENOSPC and sink.error is failed.value
    with pytest.raises(OSError):
        sink.write("b,2\n")
    sink.close()  # closing a failed sink does not raise


def _frames(n: int) -> list[can.Message]:
    return [
        can.Message(
            timestamp=1_700_000_000.0 + i * 0.001,
            arbitration_id=0x141 + i % 3,
            data=bytes([i % 256] * 8),
            is_extended_id=False,
        )
        for i in range(n)
    ]


def test_can_logs_hold_every_frame_in_every_format(tmp_path: Path) -> None:
    failures: list[tuple[str, OSError]] = []
    logs = CanFrameLogs(tmp_path, ("asc", "blf"), 1 << 20, 1_700_000_000.0, failures.append)
    frames = _frames(30)
    for frame in frames:
        logs.write(frame)
    logs.close()
    assert not failures
    for fmt in ("asc", "blf"):
        back = read_can_log(tmp_path, fmt)
        assert [(m.arbitration_id, bytes(m.data)) for m in back] == [
            (m.arbitration_id, bytes(m.data)) for m in frames
        ]


def _files(tmp_path: Path, problems: RunLogProblems, **options: object) -> RunFiles:
    settings: dict[str, object] = {
        "start_wall": 1_700_000_000.0,
        "offset": 1_000.0,
        "tlog": True,
        "channel_of": lambda bus: 3,
        "problems": problems,
        "max_run_bytes": 1 << 30,
    }
    settings.update(options)
    return RunFiles(tmp_path, ("asc",), 1 << 20, **settings)  # type: ignore[arg-type]


def test_run_files_turn_events_into_rows_frames_and_tlog_records(tmp_path: Path) -> None:
    files = _files(tmp_path, RunLogProblems())
    files.write((SETPOINT, "a", 12.5, 1.0))
    files.write((LOST, "bus0", "a", 2.0))  # a lost reply carries the last setpoint
    files.write((TX, "bus0", 0x141, False, False, 2, b"\x01\x02", 3.0))
    files.write((REJECT, "bus0", "bad_end", b"\xaa\x00", 4.0))
    files.write((MAV_IN, b"\xfd\x01", 5.0))
    files.close()
    trace = (tmp_path / TRACE_FILE).read_text().splitlines()
    assert trace[1:] == [
        "1.000000,a,setpoint,12.5000,,,,,",
        "2.000000,a,lost,12.5000,,,,,",
    ]
    (frame,) = read_can_log(tmp_path, "asc")
    assert frame.arbitration_id == 0x141 and bytes(frame.data) == b"\x01\x02"
    assert frame.channel == 3 and frame.timestamp == pytest.approx(1_003.0)
    assert (tmp_path / TLOG_FILE).read_bytes() == (1_005 * 10**6).to_bytes(8, "big") + b"\xfd\x01"
    assert "bus0 bad_end aa 00" in (tmp_path / "rejections.log").read_text()


def test_run_files_cap_the_run_at_its_size_and_say_so(tmp_path: Path) -> None:
    problems = RunLogProblems()
    files = _files(tmp_path, problems, max_run_bytes=64)
    for n in range(10):
        files.write((SETPOINT, "a", float(n), float(n)))
    assert not files.capped
    files.flush()
    assert files.capped and files.flushes == 1
    assert any("size cap" in text for text in problems.problems)
    files.close()


@needs_dev_full
def test_run_files_report_a_full_file_then_raise(tmp_path: Path) -> None:
    (tmp_path / TLOG_FILE).symlink_to(DEV_FULL)
    problems = RunLogProblems()
    files = _files(tmp_path, problems)
    files.write((MAV_IN, b"\xfd", 1.0))
    files.flush()  # the failure is reported, never raised, by a flush
    assert TLOG_FILE in problems.failed_files
    with pytest.raises(OSError):
        files.write((MAV_IN, b"\xfd", 2.0))  # the dead file refuses; the pump counts a drop
    files.write((SETPOINT, "a", 1.0, 3.0))  # the other files go on
    files.close()
    assert "setpoint" in (tmp_path / TRACE_FILE).read_text()


def test_the_run_logs_size_cap_is_one_value_its_files_judge_by(tmp_path: Path) -> None:
    """``RunLog.max_run_bytes`` is what the files are capped at, read when they are judged.

    Before the split (dc16de4) the writer read the run log's own ``max_run_bytes`` at each size
    check; the split handed a copy to ``RunFiles`` at construction, so a cap changed afterwards
    was reported by ``counters()`` and written in ``run.json`` but never applied (the review of
    the split, issue 31 item 4)."""
    from mavservo.records.runlog import RunLog

    log = RunLog(tmp_path, formats=("asc",), autostart=False, max_run_bytes=10**9)
    log.max_run_bytes = 1  # any file at all is over it
    log._files.flush()  # noqa: SLF001 - the writer thread's once-a-second flush and size check
    assert log.capped
    assert log.counters()["max_run_bytes"] == 1
    log.close()
