"""``mavservo run``: load a config, run the bridge, show a live status, print a summary.

Exit status: 0 after a clean run (duration elapsed, SIGINT, SIGTERM or SIGHUP); 2 for a bad
config or bad arguments, the verdict ``mavservo check`` prints (:func:`startup_config`; nothing
was touched); 1 when start-up fails for another reason (a port that cannot be opened: said with
the bus or link it is, its FILE:LINE and the usual causes). An expected start-up failure (a
:class:`~mavservo.errors.MavservoError` such as a busy port or a missing adapter, an
``OSError``, a python-can interface that cannot open) is one clear line; anything else is a bug
and prints its traceback too, so it can be reported.
"""

from __future__ import annotations

import argparse
import logging
import math
import signal
import sys
import threading
import time
import traceback
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import can

from mavservo.app.console import ConsoleFormatter, HeartbeatNotices, StatusDisplay, format_summary
from mavservo.app.startup_errors import DeviceOpenError, failure_lines
from mavservo.config import (
    ConfigError,
    OverrideError,
    Preflight,
    default_config_path,
    preflight,
)
from mavservo.errors import MavservoError
from mavservo.threads import set_from_signal_handler

log = logging.getLogger("mavservo")

#: Loggers whose recoveries are logged at info level next to their warnings.
RECOVERY_LOGGERS = ("mavservo.scheduling.runner", "mavservo.transport.resilient_bus")

#: Start-up failures a user can cause or fix (config, busy or missing devices): one line each.
EXPECTED_STARTUP_ERRORS = (MavservoError, OSError, can.CanInitializationError)


def stop_signals() -> list[signal.Signals]:
    """SIGINT, SIGTERM and SIGHUP end a run cleanly (failsafe sent, logs closed): by default a
    hangup (the terminal or ssh session closed) killed the bridge without either. A SIGHUP
    ignored at start (``nohup mavservo run``) stays ignored."""
    signals = [signal.SIGINT, signal.SIGTERM]
    hangup = getattr(signal, "SIGHUP", None)
    if hangup is not None and signal.getsignal(hangup) is not signal.SIG_IGN:
        signals.append(hangup)
    return signals


def positive_seconds(text: str) -> float:
    """``--duration``: a finite number of seconds above 0 (``-1``, ``0``, ``nan`` are refused
    with a reason rather than ending the run at once or never)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(
            f"{text!r}: must be a number of seconds above 0 (leave --duration out to run until "
            "Ctrl-C or SIGTERM)"
        )
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mavservo run",
        description="Run the MAVLink <-> CAN servo bridge (default: the built-in simulation).",
    )
    parser.add_argument(
        "config_file",
        nargs="?",
        metavar="CONFIG",
        help="YAML config, as `mavservo check CONFIG` takes it (same as --config)",
    )
    parser.add_argument("--config", "-c", help="YAML config (default: the built-in sim.yaml)")
    parser.add_argument(
        "--duration", type=positive_seconds, help="stop after this many seconds (> 0)"
    )
    parser.add_argument("--log-dir", help="base directory for run logs (default: logging.dir)")
    parser.add_argument("--no-log", action="store_true", help="write no run log")
    parser.add_argument("--mavlink", help="override mavlink.url (pymavlink connection string)")
    parser.add_argument("--port", help="override the first CAN bus's channel (serial device)")
    parser.add_argument("--quiet", "-q", action="store_true", help="no live status, summary only")
    parser.add_argument("--verbose", "-v", action="store_true", help="debug logging")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.config_file is not None:
        if args.config is not None and args.config != args.config_file:
            parser.error(f"two configs given: {args.config_file} and --config {args.config}")
        args.config = args.config_file
    to_stderr = logging.StreamHandler()  # stderr, as before; the format is the console's one
    to_stderr.setFormatter(ConsoleFormatter())
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.WARNING, handlers=[to_stderr]
    )
    if not args.verbose:
        # Their warnings say a servo or a bus went away; the matching "back online" and "sends
        # work again" lines are info, and the journal must show those too.
        for name in RECOVERY_LOGGERS:
            logging.getLogger(name).setLevel(logging.INFO)
    path = Path(args.config) if args.config else default_config_path()
    from mavservo.servos import load_errors

    for error in load_errors():  # a broken plug-in is named; the other profiles still work
        print(f"mavservo: warning: {error.describe()}", file=sys.stderr)
    checked = startup_config(path, args.mavlink, args.port)
    if isinstance(checked, int):
        return checked
    loaded, config = checked.loaded, checked.config

    from mavservo.app.bridge import Bridge, settle_heap

    display = StatusDisplay(enabled=not args.quiet)
    bridge = Bridge(
        config,
        config_path=path,
        log_dir=False if args.no_log else args.log_dir,
        status=display.event,
        parameter_base=loaded.base,
        overlay=loaded.overlay,
        # the built-in default lives inside the installed package: tuning it is for this run
        persist_parameters=args.config is not None,
    )
    stop = threading.Event()
    received: list[str] = []

    def on_signal(signum: int, _frame: Any) -> None:
        received.append(signal.Signals(signum).name)
        set_from_signal_handler(stop)  # never stop.set() here: see the helper

    previous = {s: signal.signal(s, on_signal) for s in stop_signals()}
    try:
        try:
            bridge.start()
        except DeviceOpenError as exc:  # which bus or link, its line, the usual causes
            print(
                f"mavservo: cannot start: {failure_lines(exc, checked.place)[0]}", file=sys.stderr
            )
            print("\n".join(failure_lines(exc)[1:]), file=sys.stderr)
            log.debug("start-up failure", exc_info=True)
            return 1
        except EXPECTED_STARTUP_ERRORS as exc:
            print(f"mavservo: cannot start: {exc}", file=sys.stderr)
            log.debug("start-up failure", exc_info=True)
            return 1
        except Exception as exc:  # noqa: BLE001 - a bug: its cause and where, for the report
            kind = type(exc).__name__
            print(f"mavservo: cannot start: unexpected {kind}: {exc}", file=sys.stderr)
            traceback.print_exc(file=sys.stderr)
            return 1
        settle_heap()
        display.started(path, bridge)
        deadline = None if args.duration is None else time.monotonic() + args.duration
        heartbeats = HeartbeatNotices(
            started=bridge.started_at or time.monotonic(),
            warn_after_s=config.mavlink.heartbeat_timeout_s,
        )
        with display:
            while not stop.is_set():
                if deadline is not None and time.monotonic() >= deadline:
                    break
                display.update(bridge.status_rows())
                _heartbeat_notice(bridge, heartbeats, display)
                stop.wait(0.2)
        summary = bridge.stop(_stop_reason(received, args.duration))
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    print(format_summary(summary))
    return 0


def startup_config(path: Path, mavlink: str | None, port: str | None) -> Preflight | int:
    """The config a run starts from, or exit status 2 with the reasons printed: the verdict of
    :func:`~mavservo.config.preflight`, the one ``mavservo check`` prints (a config check calls
    valid is one run starts; issue 37). Touches no device."""
    try:
        return preflight(path, mavlink=mavlink, port=port)
    except ConfigError as exc:
        print(f"mavservo: invalid configuration\n{exc}", file=sys.stderr)
    except OverrideError as exc:  # names the option: "--mavlink udpin:...:bad: port 'bad' ..."
        print(f"mavservo: {exc}", file=sys.stderr)
    except (OSError, ValueError) as exc:
        print(f"mavservo: cannot use {path}: {exc}", file=sys.stderr)
    return 2


def _heartbeat_notice(bridge: Any, notices: HeartbeatNotices, display: StatusDisplay) -> None:
    """Show the autopilot's first heartbeat, or warn (rate-limited) while none has come."""
    watched = bridge.autopilot_heartbeat()
    if watched is None:
        return
    source, last_heartbeat = watched
    notice = notices.check(source, last_heartbeat, time.monotonic())
    if notice is not None:
        level, text = notice
        display.event(text, level)


def _stop_reason(signals: list[str], duration: float | None) -> str:
    """Why a clean run ends, for the stop line: the signal, or the elapsed ``--duration``."""
    if signals:
        return {"SIGINT": "Ctrl-C (SIGINT)"}.get(signals[0], signals[0])
    return f"end of --duration {duration:g} s" if duration is not None else "stop requested"
