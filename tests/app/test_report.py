"""report: runs on a recorded run directory and produces every figure and the summary."""

from __future__ import annotations

import json
import random
import shutil
import time
from collections.abc import Sequence
from pathlib import Path
from types import SimpleNamespace

import can
import pytest

from mavservo.app import report
from mavservo.records.metrics import LoadMeter
from mavservo.records.runlog import RunLog, read_can_log
from mavservo.scheduling.busload import message_bits

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _record_run(
    directory: Path, seconds: float = 3.0, seed: int = 7, names: Sequence[str] = ("left", "right")
) -> RunLog:
    """A recorded run as the bridge would write it: step setpoints, jittery replies, one
    RMD-X servo per name (CAN ids 1, 2, ...)."""
    rng = random.Random(seed)
    ids = {name: index + 1 for index, name in enumerate(names)}
    log = RunLog(
        directory,
        buses={"bus0": {"bitrate": 1_000_000, "max_load": 0.35}},
        servos={name: {"profile": "rmd-x", "can_id": can_id} for name, can_id in ids.items()},
    )
    t0 = time.monotonic()
    position = dict.fromkeys(names, 0.0)
    seq = 0
    t = t0
    while t < t0 + seconds:
        for servo, can_id in ids.items():
            target = 20.0 if int(t - t0) % 2 else -20.0
            seq += 1
            log.mavlink_received(servo, t)
            log.on_setpoint(servo, seq, target, "servo_output_raw", t + 0.0002)
            cmd = can.Message(
                arbitration_id=0x140 + can_id,
                is_extended_id=False,
                data=b"\xa4\x00\x68\x01" + bytes(4),
            )
            written = t + 0.0004 + rng.uniform(0, 0.0005)
            log.on_tx("bus0", cmd, written, "command", servo, seq)
            position[servo] += (target - position[servo]) * 0.3
            reply = can.Message(
                arbitration_id=0x240 + can_id, is_extended_id=False, data=b"\xa4\x1e" + bytes(6)
            )
            decoded = written + 0.002 + rng.uniform(0, 0.002)
            state = SimpleNamespace(
                position_deg=position[servo],
                velocity_dps=50.0,
                current_a=0.4,
                temperature_c=35.0,
                faults=None,
            )
            log.on_rx("bus0", reply, decoded, servo, state)
            log.telemetry_sent(servo, decoded + rng.uniform(0, 0.05))
        t += 0.05 + rng.uniform(-0.003, 0.003)
    log.on_lost("bus0", "left", t)
    log.on_reject("bus0", "bad_end_marker", b"\xaa\xc8\x00", t)
    log.close(
        {
            "bus0": {
                "servos": {
                    "left": {
                        "latency_s": {"n": 3, "mean": 0.001, "sigma": 0.0002, "p99": 0.0015},
                        "frames": {"sent": 10, "received": 9, "timed_out": 1, "lost": 1},
                    }
                }
            }
        }
    )
    return log


@pytest.fixture(scope="module")
def recorded_run(tmp_path_factory) -> Path:
    directory = tmp_path_factory.mktemp("run")
    _record_run(directory)
    return directory


def test_report_writes_every_figure_and_lists_it(recorded_run, tmp_path):
    copied = tmp_path / "copied-run"  # works from the files alone, wherever they are
    shutil.copytree(recorded_run, copied)
    assert report.main([str(copied)]) == 0
    out = copied / "report"
    markdown = (out / report.REPORT_FILE).read_text()
    for name in report.FIGURES.values():
        data = (out / name).read_bytes()
        assert data.startswith(PNG_MAGIC) and len(data) > 5000, name
        assert f"]({name})" in markdown
    frames = read_can_log(copied, "blf")
    tx = sum(1 for m in frames if not m.is_rx)
    assert f"| CAN frames TX / RX | {tx} / {len(frames) - tx} |" in markdown
    assert "| Decoder rejections | 1 |" in markdown
    # the run summary's columns, under its names: sent recv pushed offline lost late rej, L, state
    header = "| servo | sent | recv | pushed | offline | lost | late | rej | L mean [ms] |"
    assert header in markdown
    assert "| left | 10 | 9 | 0 | 0 | 1 | 0 | 0 | 1.00 | 0.20 | 1.50 | n/a |" in markdown
    assert "| Commands traced (complete / superseded / timed_out / open) |" in markdown


def test_summary_latency_matches_the_latency_log(recorded_run):
    run = report.load_run(recorded_run)
    samples = report.stage_samples(run.latency_rows)["round_trip"]
    assert samples and all(0.002 <= s <= 0.0041 for s in samples)
    rows = dict(report.summary_rows(run, report.bus_load_series(run.frames, run.start_wall)))
    (key,) = (k for k in rows if k.startswith("Stage round_trip:"))
    assert "(mean / p50 / p95 / p99) [ms]" in key
    mean_ms = float(rows[key].split(" / ")[0])
    assert mean_ms == pytest.approx(1e3 * sum(samples) / len(samples), abs=0.01)


def test_bus_load_series_is_the_schedulers_load_meter(recorded_run):
    """The report's load curve is LoadMeter's measure (the window ending at each frame), so
    its peak is the summary's ``load.peak``, not a lower fixed-bin figure (6.58 against 6.8)."""
    run = report.load_run(recorded_run)
    series = report.bus_load_series(run.frames, run.start_wall, {0: 1_000_000})
    assert set(series) == {0}
    meter = LoadMeter(1_000_000, window_s=report.LOAD_WINDOW_S)
    for msg in sorted(run.frames, key=lambda m: m.timestamp):
        meter.add(msg.timestamp, message_bits(msg))
    _, loads = series[0]
    assert len(loads) == len(run.frames)
    assert max(loads) == pytest.approx(meter.peak, rel=1e-9)


def test_report_on_an_empty_run_still_draws_every_figure(tmp_path):
    RunLog(tmp_path).close()
    out = tmp_path / "out"
    assert report.main([str(tmp_path), "--out", str(out)]) == 0
    assert all((out / name).stat().st_size > 0 for name in report.FIGURES.values())


def test_not_a_run_directory_is_a_clear_error(tmp_path, capsys):
    (tmp_path / "notes.txt").write_text("hello")
    assert report.main([str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "not a mavservo run directory" in err
    assert report.main([str(tmp_path / "missing")]) == 2


def test_report_lists_what_went_wrong_during_the_run(recorded_run, tmp_path):
    """Adapter outages, failsafes and failed sends, as the bridge's summary recorded them."""
    copied = tmp_path / "eventful-run"
    shutil.copytree(recorded_run, copied)
    metrics_path = copied / "metrics.json"
    metrics = json.loads(metrics_path.read_text())
    metrics["events"] = ["bus0: CAN adapter lost (gone); reconnecting", "bus0: CAN adapter back"]
    metrics["buses"] = {"bus0": {"send_failures": {"total": 298, "outages": 1}}}
    metrics_path.write_text(json.dumps(metrics))
    assert report.main([str(copied)]) == 0
    markdown = (copied / "report" / report.REPORT_FILE).read_text()
    events = markdown.split("## Events", 1)[1].split("## Figures", 1)[0]
    assert "- bus0: CAN adapter lost (gone); reconnecting" in events
    assert "- bus0: CAN adapter back" in events
    assert "- bus bus0: 298 failed sends in 1 outage(s)" in events


# -- figures stay readable with many servos (issue 17, item 13) ------------------------------


@pytest.fixture(scope="module", params=[1, 4, 9], ids=lambda n: f"{n}-servos")
def run_of(request, tmp_path_factory) -> tuple[int, report.Run]:
    count = request.param
    directory = tmp_path_factory.mktemp(f"run{count}")
    _record_run(directory, seconds=1.0, names=[f"servo{i}" for i in range(count)])
    return count, report.load_run(directory)


def _legend_texts(legend) -> list[str]:
    return [text.get_text() for text in legend.get_texts()]


def test_fig3_has_one_legend_entry_per_servo_and_no_gap(run_of, tmp_path):
    """9 servos made 18 entries (commanded and measured each) in a legend beside the first
    panel, which left a gap under it; now a servo is a colour and the styles say the rest."""
    count, run = run_of
    fig = report.plot_response(run, tmp_path / "fig3.png")
    (legend,) = fig.legends
    assert _legend_texts(legend) == [f"servo{i}" for i in range(count)] + [
        "commanded",
        "measured",
    ]
    axes = [ax for ax in fig.axes if ax.get_visible()]
    assert len(axes) == 3 and all(ax.get_legend() is None for ax in axes)
    heights = [ax.get_position().height for ax in axes]
    assert max(heights) - min(heights) < 0.02 * max(heights)  # equal panels: no gap
    colours = {line.get_color() for line in axes[0].get_lines()}
    assert len(colours) == count  # every servo its own colour (ten or more too)


@pytest.mark.parametrize("plot", [report.plot_interval_histogram, report.plot_interval_sequence])
def test_interval_figures_give_each_servo_its_own_panel(run_of, tmp_path, plot):
    """Fig. 5 drew 9 overlapping scatter series in one axes; now one panel per servo."""
    count, run = run_of
    fig = plot(run, tmp_path / "fig.png")
    panels = [ax for ax in fig.axes if ax.get_visible()]
    assert len(panels) == count
    for index, ax in enumerate(panels):
        assert ax.get_legend() is None
        assert ax.get_title().startswith(f"servo{index}: state p50 ")
    assert not fig.legends


def test_every_latency_stage_is_visible(run_of, tmp_path):
    """Stacked on a linear axis the 0.2 ms accept stage vanished under 50 ms stages."""
    _, run = run_of
    fig = report.plot_latency_stages(run, tmp_path / "latency.png")
    stages_ax = fig.axes[0]
    assert stages_ax.get_xscale() == "log"
    labels = [tick.get_text().split("\n")[0] for tick in stages_ax.get_yticklabels()]
    assert labels == list(report.STAGES)
    assert len(fig.axes[1].get_legend().get_texts()) == 3  # p50, p95, p99


def test_bus_load_legend_is_bounded_by_the_buses(run_of, tmp_path):
    _, run = run_of
    series = report.bus_load_series(run.frames, run.start_wall, report.channel_bitrates(run.header))
    fig = report.plot_bus_load(run, tmp_path / "load.png", series)
    texts = _legend_texts(fig.axes[0].get_legend())
    assert texts[0].startswith("bus0: peak ") and len(texts) <= 3 * len(series)
