"""What a run measured and wrote down: the paper's figures (L, sigma_L, reception intervals, R),
per-stage command latency and the run log directory."""

from __future__ import annotations

from typing import TYPE_CHECKING

from mavservo.faces import lazy_face

# The face: what the other layers use from this package (``tests/test_package_faces.py``), each
# name imported from its module on first use (:func:`mavservo.faces.lazy_face`); the modules'
# other names are the package's own business.
if TYPE_CHECKING:
    from .can_log import can_log_files, read_can_log
    from .latency import STAGE_DESCRIPTIONS, STAGES, summarize
    from .metrics import LoadMeter, SchedulerMetrics, percentile, round_trip_figures, write_json
    from .repeats import REPEAT_INTERVAL_S, Key, Repeats, Summary, repeated
    from .run_files import LATENCY_FILE, REJECTIONS_FILE, TRACE_FILE
    from .runlog import METRICS_FILE, RUN_HEADER, RunLog, new_run_dir
    from .vocabulary import BACK_ONLINE, GLOSSARY, LATE, LOST, OFFLINE, glossary_text

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
    "REPEAT_INTERVAL_S",
    "Repeats",
    "Summary",
    "repeated",
    "Key",
    "BACK_ONLINE",
    "GLOSSARY",
    "LATE",
    "LOST",
    "OFFLINE",
    "glossary_text",
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
        "TRACE_FILE": "run_files",
        "LATENCY_FILE": "run_files",
        "METRICS_FILE": "runlog",
        "REJECTIONS_FILE": "run_files",
        "can_log_files": "can_log",
        "read_can_log": "can_log",
        "REPEAT_INTERVAL_S": "repeats",
        "Repeats": "repeats",
        "Summary": "repeats",
        "repeated": "repeats",
        "Key": "repeats",
        "BACK_ONLINE": "vocabulary",
        "GLOSSARY": "vocabulary",
        "LATE": "vocabulary",
        "LOST": "vocabulary",
        "OFFLINE": "vocabulary",
        "glossary_text": "vocabulary",
    },
)
