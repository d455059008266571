"""The run log and the counters of a bus whose servos share packed DroneCAN transfers.

Eight DroneCAN servos' commands go out in one ArrayCommand transfer of five frames: five frames
on the wire, eight commands applied. Every command must get its write mark (the latency's
``tx`` stage ends there and its ``round_trip`` starts there), the CAN log must hold each frame
once, and the counters must say frames and commands apart (docs/logs.md, "Every figure, once").
A real scheduler on a python-can virtual bus and a real run log; loops bounded in count and
time, no timing thresholds.
"""

from __future__ import annotations

import csv
import json
import time
from pathlib import Path

import can

from mavservo.records.runlog import LATENCY_FILE, METRICS_FILE, RunLog, read_can_log
from mavservo.scheduling.runner import Scheduler
from mavservo.scheduling.schedule_core import ServoSpec, TimingConfig
from mavservo.servos.dronecan.node import frames_for_commands
from mavservo.servos.dronecan.profile import DroneCanServo

SERVOS = 8


def _wait(condition, timeout_s: float = 5.0) -> bool:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.01)
    return bool(condition())


def test_every_command_of_a_packed_transfer_is_written_once_its_frames_are(
    tmp_path: Path,
) -> None:
    names = [f"s{i}" for i in range(SERVOS)]
    specs = [
        ServoSpec(name, DroneCanServo(11 + i, actuator_id=1 + i), telemetry_hz=0)
        for i, name in enumerate(names)
    ]
    runlog = RunLog(tmp_path, formats=("asc",), tlog=False)
    channel = f"dronecan-records-{id(tmp_path)}"
    with can.Bus(interface="virtual", channel=channel) as bus:
        scheduler = Scheduler(
            bus,
            specs,
            TimingConfig(command_period_s=0.05, refresh_interval_s=10.0, bitrate=1_000_000),
            observer=runlog,
            name="bus0",
        )
        for i, name in enumerate(names):  # before the start: all in the first slot
            assert scheduler.set_setpoint(name, float(i), "test").accepted
        scheduler.start()
        try:
            assert _wait(
                lambda: all(scheduler.metrics_store.servos[n].commands_sent >= 1 for n in names)
            )
        finally:
            scheduler.stop()
        metrics = scheduler.metrics()
    runlog.close({"buses": {"bus0": metrics}})

    rows = list(csv.DictReader((tmp_path / LATENCY_FILE).open()))
    assert sorted(row["servo"] for row in rows) == names
    # every command's write is marked (before the fix only as many as the transfer had frames)
    assert all(row["t_written"] for row in rows), rows
    assert all(row["tx_s"] for row in rows)
    # all eight at the transfer's last frame: one write time for the slot
    assert len({row["t_written"] for row in rows}) == 1

    # eight commands applied, one each; five frames on the wire, each once in the CAN log
    servos = metrics["servos"]
    assert [servos[n]["frames"]["commands"] for n in names] == [1] * SERVOS
    sent = [m for m in read_can_log(tmp_path, "asc") if not m.is_rx]
    command_frames = [m for m in sent if (m.arbitration_id >> 8) & 0xFFFF == 1010]
    assert len(command_frames) == frames_for_commands(SERVOS) == 5
    assert metrics["frames_written"] == len(sent)  # node frames (NodeStatus) included
    assert sum(servos[n]["frames"]["sent"] for n in names) == SERVOS
    saved = json.loads((tmp_path / METRICS_FILE).read_text())
    assert saved["buses"]["bus0"]["frames_written"] == metrics["frames_written"]


def test_the_bridges_fan_out_passes_writes_on_to_observers_that_take_them() -> None:
    """The bridge's fan-out gives ``on_written`` to the run log and skips observers written
    before the hook existed (it is optional)."""
    from mavservo.app.bridge import _FanOut
    from mavservo.records.latency import LatencyTracer

    class Old:  # an observer without the hook
        pass

    tracer = LatencyTracer()
    tracer.on_setpoint("s1", 3, 1.0, "test", 1.0)
    _FanOut(Old(), tracer).on_written("bus0", 1.5, "command", "s1", 3)  # type: ignore[arg-type]
    tracer.close_open()
    assert tracer.summary()["stages"]["tx"]["n"] == 1


def test_a_two_frame_status_is_one_state_in_the_trace_and_ends_the_round_trip_at_its_end(
    tmp_path: Path,
) -> None:
    """A Status transfer is two frames: the CAN log has both, ``trace.csv`` one state (as
    ``metrics.json``'s state intervals count one), and the latency's round trip ends at the
    last frame, when the report is whole (before, the first frame made a state row of the old
    values and ended the round trip early)."""
    import math

    import dronecan
    from dronecan.transport import Transfer

    runlog = RunLog(tmp_path, formats=("asc",), tlog=False)
    status = dronecan.uavcan.equipment.actuator.Status(
        actuator_id=1, position=0.5, force=math.nan, speed=0.0, power_rating_pct=0
    )
    transfer = Transfer(transfer_id=0, source_node_id=11, payload=status)
    frames = [
        can.Message(arbitration_id=f.message_id, is_extended_id=True, data=bytes(f.bytes))
        for f in transfer.to_frames()
    ]
    assert len(frames) == 2
    with can.Bus(interface="virtual", channel=f"dronecan-status-{id(tmp_path)}") as bus:
        scheduler = Scheduler(
            bus,
            [ServoSpec("s0", DroneCanServo(11, actuator_id=1), telemetry_hz=0)],
            observer=runlog,
            name="bus0",
        )
        runlog.on_setpoint("s0", 1, 10.0, "test", 1.0)
        runlog.on_written("bus0", 1.1, "command", "s0", 1)
        scheduler.handle_frame(frames[0], 1.2)
        scheduler.handle_frame(frames[1], 1.3)
        runlog.telemetry_sent("s0", 1.4)
        metrics = scheduler.metrics()
    runlog.close()
    assert metrics["servos"]["s0"]["frames"]["received"] == 1
    rows = list(csv.DictReader((tmp_path / "trace.csv").open()))
    states = [row for row in rows if row["event"] == "state"]
    assert len(states) == 1 and float(states[0]["position_deg"]) > 28
    (trace,) = list(csv.DictReader((tmp_path / LATENCY_FILE).open()))
    assert float(trace["t_decoded"]) == 1.3
    assert len([m for m in read_can_log(tmp_path, "asc") if m.is_rx]) == 2
