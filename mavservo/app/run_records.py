"""The run's records: the run log a bridge opens from its config, and the MAVLink frames fed to it.

:func:`open_run_log` makes the run directory (``logging.dir`` or the ``--log-dir`` given) and
the :class:`~mavservo.records.RunLog` with the config's formats, limits and the servos and
buses it describes; :func:`tap_mavlink` feeds it every MAVLink frame (the run's .tlog) and
closes each servo's latency trace when its telemetry is sent.

Why a module of its own: what goes into the run directory is decided here, from the config,
once; the bridge only hands the run log to the pieces that record into it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from mavservo.config import Config
from mavservo.mavlink import MavlinkSide
from mavservo.records import RunLog, new_run_dir


def open_run_log(
    config: Config,
    log_dir: str | Path | None | bool,
    *,
    config_path: str | Path | None,
    on_problem: Callable[[str], None],
) -> tuple[Path, RunLog] | None:
    """A new run directory and its run log, or None for ``log_dir=False`` (no records).

    ``log_dir``: base directory (None, True or "": the config's ``logging.dir``).
    ``on_problem``: a full disk and other write failures, said at once."""
    if log_dir is False:
        return None
    cfg = config.logging
    base = Path(log_dir) if isinstance(log_dir, (str, Path)) and log_dir else cfg.dir
    run_dir = new_run_dir(base)
    buses = {
        b.name: {"bitrate": b.bitrate, "max_load": b.max_load, "interface": b.interface}
        for b in config.can.buses
    }
    servos = {
        s.name: {"profile": s.profile, "can_id": s.can_id, "bus": config.bus_of(s).name}
        for s in config.servos
    }
    runlog = RunLog(
        run_dir,
        formats=cfg.can_formats,
        can_frames=cfg.can_frames,
        rotate_bytes=int((cfg.rotate_mb or 1e6) * 1024 * 1024),
        buses=buses,
        servos=servos,
        config_path=config_path,
        tlog=cfg.tlog,
        max_run_bytes=int(cfg.max_run_mb * 1024 * 1024),
        on_problem=on_problem,
    )
    return run_dir, runlog


def tap_mavlink(side: MavlinkSide, runlog: RunLog, servo_names: Sequence[str]) -> None:
    """MAVLink frames into the run's .tlog; telemetry sends close the latency traces."""
    names = list(servo_names)

    def tap(direction: str, raw: bytes, t: float) -> None:
        (runlog.mavlink_in if direction == "in" else runlog.mavlink_out)(raw, t)

    def sent(msg: Any, t: float) -> None:
        # ACTUATOR_OUTPUT_STATUS carries every servo's measured position at once
        if msg.get_type() == "ACTUATOR_OUTPUT_STATUS":
            for name in names:
                runlog.telemetry_sent(name, t)

    side.link.tap = tap
    side.on_sent = sent
