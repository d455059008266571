"""RunLog: what goes in comes back out of python-can's readers, pymavlink's tlog reader and CSV."""

from __future__ import annotations

import csv
import json
import os
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import can
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mavservo.records.runlog import (
    METRICS_FILE,
    RUN_HEADER,
    RunLog,
    can_log_files,
    new_run_dir,
    read_can_log,
)

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mavlink2  # noqa: E402


def _state(position: float) -> SimpleNamespace:
    return SimpleNamespace(
        position_deg=position, velocity_dps=12.5, current_a=0.25, temperature_c=35.0, faults=None
    )


frames_strategy = st.lists(
    st.tuples(
        st.booleans(),  # extended
        st.integers(min_value=0, max_value=0x1FFFFFFF),
        st.binary(min_size=0, max_size=8),
        st.booleans(),  # rx
        st.sampled_from(["bus0", "bus1"]),
    ),
    min_size=1,
    max_size=40,
)


def _write_frames(directory: Path, frames, rotate_bytes: int = 0) -> RunLog:
    log = RunLog(
        directory,
        rotate_bytes=rotate_bytes,
        buses={"bus0": {"bitrate": 1_000_000}, "bus1": {"bitrate": 500_000}},
    )
    t0 = time.monotonic()
    for i, (extended, arb_id, data, rx, bus) in enumerate(frames):
        arb_id = arb_id if extended else arb_id & 0x7FF
        msg = can.Message(arbitration_id=arb_id, is_extended_id=extended, data=data)
        t = t0 + i * 1e-3
        if rx:
            log.on_rx(bus, msg, t, None, None)
        else:
            log.on_tx(bus, msg, t, "command", None, None)
    log.close()
    return log


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(frames=frames_strategy)
def test_frames_read_back_frame_for_frame_in_asc_and_blf(frames):
    with tempfile.TemporaryDirectory() as tmp:
        directory = Path(tmp)
        _write_frames(directory, frames)
        header = json.loads((directory / RUN_HEADER).read_text())
        channels = {name: info["channel"] for name, info in header["buses"].items()}
        for fmt in ("asc", "blf"):
            back = read_can_log(directory, fmt)
            assert len(back) == len(frames), fmt
            for (extended, arb_id, data, rx, bus), msg in zip(frames, back, strict=True):
                assert msg.is_extended_id == extended
                assert msg.arbitration_id == (arb_id if extended else arb_id & 0x7FF)
                assert bytes(msg.data) == data
                assert msg.is_rx == rx
                assert msg.channel == channels[bus]


def test_rotation_splits_files_and_loses_no_frame(tmp_path):
    frames = [(False, 0x140 + i % 4, bytes([i % 256] * 8), i % 2 == 1, "bus0") for i in range(400)]
    _write_frames(tmp_path, frames, rotate_bytes=3000)
    for fmt in ("asc", "blf"):
        files = can_log_files(tmp_path, fmt)
        assert len(files) > 1, f"{fmt} did not rotate"
        back = read_can_log(tmp_path, fmt)
        assert [bytes(m.data) for m in back] == [f[2] for f in frames]
        assert [m.is_rx for m in back] == [f[3] for f in frames]


def test_blf_timestamps_are_wall_clock(tmp_path):
    log = RunLog(tmp_path)
    t = time.monotonic()
    log.on_tx("bus0", can.Message(arbitration_id=0x141, data=b"\xa4"), t, "command", "s", 1)
    log.close()
    (msg,) = read_can_log(tmp_path, "blf")
    assert msg.timestamp == pytest.approx(t + log.wall_offset, abs=1e-3)
    header = json.loads((tmp_path / RUN_HEADER).read_text())
    assert header["wall_minus_monotonic"] == pytest.approx(log.wall_offset)


def test_full_queue_drops_and_counts_without_blocking(tmp_path):
    log = RunLog(tmp_path, queue_size=5, autostart=False)
    msg = can.Message(arbitration_id=0x141, data=b"\xa4\x00")
    t = time.monotonic()
    for i in range(12):
        log.on_tx("bus0", msg, t + i, "command", "s1", i)
    assert log.dropped["can"] == 7
    log.close({"scheduler": {"ok": True}})
    metrics = json.loads((tmp_path / METRICS_FILE).read_text())
    assert metrics["runlog"]["dropped"] == {"can": 7}
    assert metrics["runlog"]["dropped_total"] == 7
    assert metrics["scheduler"] == {"ok": True}
    assert len(read_can_log(tmp_path, "blf")) == 5


def test_trace_latency_and_rejections_files(tmp_path):
    log = RunLog(tmp_path)
    t0 = time.monotonic()
    cmd = can.Message(arbitration_id=0x141, data=b"\xa4" + bytes(7))
    reply = can.Message(arbitration_id=0x241, data=b"\xa4" + bytes(7))
    log.mavlink_received("s1", t0)
    log.on_setpoint("s1", 7, 10.0, "do_set_servo", t0 + 0.001)
    log.on_tx("bus0", cmd, t0 + 0.003, "command", "s1", 7)
    log.on_rx("bus0", reply, t0 + 0.006, "s1", _state(9.5))
    log.telemetry_sent("s1", t0 + 0.010)
    log.on_lost("bus0", "s1", t0 + 0.2)
    log.on_reject("bus0", "bad_end_marker", b"\xaa\xc8\x01\x02", t0 + 0.3)
    log.close()

    with (tmp_path / "trace.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert [r["event"] for r in rows] == ["setpoint", "state", "lost"]
    assert float(rows[1]["position_deg"]) == pytest.approx(9.5)
    assert float(rows[1]["setpoint_deg"]) == pytest.approx(10.0)

    with (tmp_path / "latency.csv").open() as handle:
        (row,) = list(csv.DictReader(handle))
    assert row["outcome"] == "complete"
    assert float(row["accept_s"]) == pytest.approx(0.001, abs=1e-6)
    assert float(row["tx_s"]) == pytest.approx(0.002, abs=1e-6)
    assert float(row["round_trip_s"]) == pytest.approx(0.003, abs=1e-6)
    assert float(row["publish_s"]) == pytest.approx(0.004, abs=1e-6)

    line = (tmp_path / "rejections.log").read_text().strip()
    assert "bad_end_marker" in line and line.endswith("aa c8 01 02")


def test_tlog_reads_back_with_pymavlink(tmp_path):
    log = RunLog(tmp_path)
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=140)
    t0 = time.monotonic()
    sent = []
    for i in range(5):
        msg = mav.named_value_float_encode(i, b"s1_pos", float(i))
        raw = msg.pack(mav)
        sent.append(float(i))
        (log.mavlink_out if i % 2 else log.mavlink_in)(raw, t0 + i * 0.1)
    log.close()
    conn = mavutil.mavlink_connection(str(tmp_path / "mavlink.tlog"), dialect="ardupilotmega")
    values, stamps = [], []
    for _ in range(20):  # bounded
        msg = conn.recv_match(type="NAMED_VALUE_FLOAT")
        if msg is None:
            break
        values.append(msg.value)
        stamps.append(msg._timestamp)
    assert values == sent
    assert stamps[0] == pytest.approx(t0 + log.wall_offset, abs=1e-3)
    assert stamps[-1] - stamps[0] == pytest.approx(0.4, abs=1e-3)


def test_new_run_dir_never_reuses_a_directory(tmp_path):
    now = time.time()
    first = new_run_dir(tmp_path, now)
    second = new_run_dir(tmp_path, now)
    assert first != second and first.is_dir() and second.is_dir()


class _Tee:
    """Forwards to the RunLog and remembers, per direction, what the scheduler reported."""

    def __init__(self, log: RunLog) -> None:
        self.log = log
        self.frames: dict[bool, list[tuple[int, bytes]]] = {False: [], True: []}

    def on_setpoint(self, *args):
        self.log.on_setpoint(*args)

    def on_tx(self, bus, msg, t, kind, servo, seq):
        self.frames[False].append((msg.arbitration_id, bytes(msg.data)))
        self.log.on_tx(bus, msg, t, kind, servo, seq)

    def on_rx(self, bus, msg, t, servo, state):
        self.frames[True].append((msg.arbitration_id, bytes(msg.data)))
        self.log.on_rx(bus, msg, t, servo, state)

    def on_lost(self, *args):
        self.log.on_lost(*args)

    def on_reject(self, *args):
        self.log.on_reject(*args)


def test_short_scheduler_run_on_a_virtual_bus_reads_back_frame_for_frame(tmp_path):
    import uuid

    from mavservo.scheduling.runner import Scheduler, ServoSpec, TimingConfig
    from mavservo.servos import RmdX
    from mavservo.sim.servo import SimServo
    from mavservo.sim.virtual import VirtualServoBus

    channel = f"runlog-{uuid.uuid4().hex}"
    timing = TimingConfig(command_period_s=0.02, telemetry_period_s=0.03, reply_timeout_s=0.05)
    log = RunLog(tmp_path, buses={"bus0": {"bitrate": timing.bitrate}})
    tee = _Tee(log)
    with VirtualServoBus([SimServo("rmd-x", 1), SimServo("rmd-x", 2)], channel=channel):
        bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        try:
            scheduler = Scheduler(
                bus,
                [ServoSpec("s1", RmdX(1)), ServoSpec("s2", RmdX(2))],
                timing,
                observer=tee,
                name="bus0",
            )
            with scheduler:
                for i in range(3):
                    scheduler.set_setpoint("s1", 5.0 * i, "test")
                    scheduler.set_setpoint("s2", -5.0 * i, "test")
                    time.sleep(0.1)
                for _ in range(100):  # bounded wait for replies from both servos
                    if len({r[0] for r in tee.frames[True]}) >= 2:
                        break
                    time.sleep(0.02)
        finally:
            bus.shutdown()
    log.close(scheduler.metrics())
    assert tee.frames[False] and tee.frames[True]
    for fmt in ("asc", "blf"):
        back = read_can_log(tmp_path, fmt)
        for rx in (False, True):
            logged = [(m.arbitration_id, bytes(m.data)) for m in back if m.is_rx == rx]
            assert logged == tee.frames[rx], (fmt, rx)
    metrics = json.loads((tmp_path / METRICS_FILE).read_text())
    assert metrics["runlog"]["dropped_total"] == 0
    assert metrics["latency"]["counts"]["commands"] == 6
    assert set(metrics["servos"]) == {"s1", "s2"}
