"""What ``mavservo run`` records and says, over the real CLI (issue 17, items 7, 8 and 11).

One run of the built-in simulation from a config without ``logging:`` serves the first tests:
both CAN log formats are written by default, and the run summary, ``metrics.json`` and the
report give each figure under one name with one value. The failed-start tests point the
bridge at a port that does not exist and at ``/dev/null``.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest
import yaml

from mavservo.app.console import FRAME_COLUMNS, TIMING_COLUMNS
from mavservo.config import default_config_path
from mavservo.config.schema import LoggingConfig
from mavservo.records.runlog import METRICS_FILE, RUN_HEADER, read_can_log
from tests.app.test_run_cli import REPO, run_mavservo

RUN_SECONDS = "4"


def without_logging_section(text: str) -> str:
    """The packaged sim.yaml without its ``logging:`` block (the file's last section)."""
    head, found, _ = text.partition("\nlogging:")
    assert found, "sim.yaml has no logging section to drop"
    return head + "\n"


@pytest.fixture(scope="module")
def default_run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """One ``mavservo run`` and ``mavservo report`` on a config that says nothing of logging."""
    base = tmp_path_factory.mktemp("records-cli")
    config = base / "no-logging.yaml"
    config.write_text(without_logging_section(default_config_path().read_text()))
    runs = base / "runs"
    proc = run_mavservo(
        "run", "--config", str(config), "--duration", RUN_SECONDS, "--quiet", "--log-dir", str(runs)
    )
    assert proc.returncode == 0, proc.stderr
    [run_dir] = list(runs.iterdir())
    reported = run_mavservo("report", str(run_dir))
    assert reported.returncode == 0, reported.stderr
    return {
        "summary": proc.stdout,
        "dir": run_dir,
        "metrics": json.loads((run_dir / METRICS_FILE).read_text()),
        "report": (run_dir / "report" / "report.md").read_text(),
    }


# -- item 7: one default, everywhere ---------------------------------------------------------


def test_a_config_without_logging_writes_asc_and_blf_with_every_frame(default_run) -> None:
    run_dir = default_run["dir"]
    asc, blf = read_can_log(run_dir, "asc"), read_can_log(run_dir, "blf")
    assert len(blf) > 100
    assert len(asc) == len(blf)  # the same frames, both directions
    assert {m.is_rx for m in blf} == {True, False}
    header = json.loads((run_dir / RUN_HEADER).read_text())
    assert header["can_formats"] == ["asc", "blf"]


@pytest.mark.parametrize(
    "path", sorted((REPO / "config").glob("*.yaml")) + [default_config_path()], ids=str
)
def test_every_shipped_config_writes_the_default_formats(path: Path) -> None:
    """The README promises ``.asc`` and ``.blf``; gimbal.yaml and ardupilot-sitl.yaml wrote
    only ASC, a config without ``logging:`` too."""
    assert LoggingConfig().can_formats == ["asc", "blf"]
    # the logging section alone: the hardware examples' signing key files are not shipped
    section = yaml.safe_load(path.read_text()).get("logging") or {}
    assert LoggingConfig.model_validate(section).can_formats == ["asc", "blf"], path.name


# -- item 8: one name and one value per figure -----------------------------------------------


def _ms(value: float | None) -> str:
    return "-" if value is None else f"{value * 1000:.2f}"


def test_summary_metrics_and_report_agree_on_every_servo_figure(default_run) -> None:
    summary, report = default_run["summary"], default_run["report"]
    servos = default_run["metrics"]["servos"]
    heads = [h for h, _, _ in FRAME_COLUMNS] + [h for h, _, _, _ in TIMING_COLUMNS]
    header_line = next(line for line in summary.splitlines() if line.strip().startswith("servo"))
    assert header_line.split()[1:] == " ".join(heads).split()
    assert (
        "| servo | "
        + " | ".join(
            [h for h, _, _ in FRAME_COLUMNS] + [f"{h} [ms]" for h, _, _, _ in TIMING_COLUMNS]
        )
        + " |"
        in report
    )
    for name, data in servos.items():
        frames = data["frames"]
        counts = [str(frames[key]) for _, _, key in FRAME_COLUMNS]
        timing = [_ms(data[group][key]) for _, _, group, key in TIMING_COLUMNS]
        row = re.search(rf"^\s+{name}\s+(.*)$", summary, re.M)
        assert row, name
        assert row.group(1).split() == counts + timing, name
        report_cells = [v.replace("n/a", "-") for v in counts + timing]
        assert f"| {name} | " + " | ".join(report_cells) + " |" in report, name
        # the definitions behind the names hold: what was not pushed answered a frame sent
        # (every profile here answers a frame with at most one reply)
        assert frames["received"] - frames["pushed"] <= frames["sent"], name
        assert frames["timed_out"] == frames["lost"] + frames["late"]
    # the gimbal's CubeMars servos push: recv far above sent, and the summary says why
    pushers = [n for n, d in servos.items() if d["frames"]["pushed"]]
    assert pushers and all(
        servos[n]["frames"]["received"] > servos[n]["frames"]["sent"] for n in pushers
    )
    assert "pushed = sent unasked by a push-style servo" in summary


def test_summary_metrics_and_report_agree_on_the_bus_load(default_run) -> None:
    summary, report = default_run["summary"], default_run["report"]
    for name, bus in default_run["metrics"]["buses"].items():
        load = bus["load"]
        mean, peak, planned = (f"{100 * load[k]:.2f}" for k in ("mean", "peak", "planned"))
        assert f"bus {name}: load R mean {mean} %, peak {peak} % " in summary
        assert f"planned {planned} % (configured rates)" in summary
        assert f"| {name} | {mean} | {peak} | {planned} |" in report
        assert load["mean"] <= load["peak"]


def test_report_stages_are_the_metrics_stages(default_run) -> None:
    stages = default_run["metrics"]["latency"]["stages"]
    for stage, stats in stages.items():
        values = " / ".join(_ms(stats[k]) for k in ("mean", "p50", "p95", "p99"))
        assert re.search(
            rf"\| Stage {stage}: .* \(mean / p50 / p95 / p99\) \[ms\] \| {values} ",
            default_run["report"],
        ), stage


def test_every_summary_name_is_defined_in_docs_logs() -> None:
    docs = (REPO / "docs" / "logs.md").read_text()
    for head, _, key in FRAME_COLUMNS:
        assert f"`{head}`" in docs and f"`servos.<s>.frames.{key}`" in docs, head
    for head, _, group, key in TIMING_COLUMNS:
        assert f"`{head}`" in docs and f"`servos.<s>.{group}.{key}`" in docs, head
    for key in ("mean", "peak", "planned"):
        assert f"`buses.<b>.load.{key}`" in docs, key


# -- item 11: a failed start leaves a reason, not an empty run --------------------------------


@pytest.mark.parametrize("port", ["/dev/ttyUSB9", "/dev/null"])
def test_a_failed_start_keeps_only_why_and_report_says_so(tmp_path: Path, port: str) -> None:
    config = tmp_path / "hw.yaml"
    config.write_text(
        "mavlink: {url: 'udpin:127.0.0.1:0'}\n"
        "can: {buses: [{name: bus0, interface: aa55, channel: /dev/ttyUSB0}]}\n"
        "servos: [{name: a, profile: rmd-x, can_id: 1}]\n"
    )
    runs = tmp_path / "runs"
    proc = run_mavservo(
        "run", "--config", str(config), "--port", port, "--duration", "1", "--log-dir", str(runs)
    )
    assert proc.returncode == 1 and "cannot start" in proc.stderr
    [run_dir] = list(runs.iterdir())
    assert [p.name for p in run_dir.iterdir()] == [RUN_HEADER]
    header = json.loads((run_dir / RUN_HEADER).read_text())
    assert port in header["start_failed"]
    reported = run_mavservo("report", str(run_dir))
    assert reported.returncode == 2
    assert "never started" in reported.stderr and port in reported.stderr
    assert "Traceback" not in reported.stderr
    assert not (run_dir / "report").exists()
