"""What a run measured and wrote down: the paper's figures (L, sigma_L, reception intervals, R),
per-stage command latency and the run log directory."""

from __future__ import annotations

from typing import TYPE_CHECKING

from mavservo.faces import lazy_face

# The face: what the other layers use from this package (``tests/test_package_faces.py``), each
# name imported from its module on first use (:func:`mavservo.faces.lazy_face`); the modules'
# other names are the package's own business.
if TYPE_CHECKING:
    from .latency import STAGE_DESCRIPTIONS, STAGES, summarize
    from .metrics import LoadMeter, SchedulerMetrics, percentile, round_trip_figures, write_json
    from .runlog import (
        LATENCY_FILE,
        METRICS_FILE,
        REJECTIONS_FILE,
        RUN_HEADER,
        TRACE_FILE,
        RunLog,
        can_log_files,
        new_run_dir,
        read_can_log,
    )

__all__ = [
    "LoadMeter",
    "RunLog",
    "STAGES",
    "STAGE_DESCRIPTIONS",
    "SchedulerMetrics",
    "new_run_dir",
    "percentile",
    "round_trip_figures",
    "summarize",
    "write_json",
    "RUN_HEADER",
    "TRACE_FILE",
    "LATENCY_FILE",
    "METRICS_FILE",
    "REJECTIONS_FILE",
    "can_log_files",
    "read_can_log",
]
__getattr__ = lazy_face(
    __name__,
    {
        "LoadMeter": "metrics",
        "RunLog": "runlog",
        "STAGES": "latency",
        "STAGE_DESCRIPTIONS": "latency",
        "SchedulerMetrics": "metrics",
        "new_run_dir": "runlog",
        "percentile": "metrics",
        "round_trip_figures": "metrics",
        "summarize": "latency",
        "write_json": "metrics",
        "RUN_HEADER": "runlog",
        "TRACE_FILE": "runlog",
        "LATENCY_FILE": "runlog",
        "METRICS_FILE": "runlog",
        "REJECTIONS_FILE": "runlog",
        "can_log_files": "runlog",
        "read_can_log": "runlog",
    },
)
