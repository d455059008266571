"""``mavservo run``: load a config, run the bridge, show a live status, print a summary.

Exit status: 0 after a clean run (duration elapsed, SIGINT or SIGTERM); 2 for a bad config or bad
arguments (nothing was touched); 1 when start-up fails for another reason (a port that cannot be
opened...). An expected start-up failure (a :class:`~mavservo.errors.MavservoError` such as a
busy port or a missing adapter, an ``OSError``, a python-can interface that cannot open) is one
clear line; anything else is a bug and prints its traceback too, so it can be reported.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
import time
import traceback
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import can

from mavservo.app.console import StatusDisplay, format_summary
from mavservo.config import (
    ConfigError,
    OverrideError,
    apply_overrides,
    default_config_path,
    load_config,
)
from mavservo.errors import MavservoError

log = logging.getLogger("mavservo")

#: Loggers whose recoveries are logged at info level next to their warnings.
RECOVERY_LOGGERS = ("mavservo.scheduling.runner", "mavservo.transport.resilient_bus")

#: Start-up failures a user can cause or fix (config, busy or missing devices): one line each.
EXPECTED_STARTUP_ERRORS = (MavservoError, OSError, can.CanInitializationError)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mavservo run",
        description="Run the MAVLink <-> CAN servo bridge (default: the built-in simulation).",
    )
    parser.add_argument("--config", "-c", help="YAML config (default: the built-in sim.yaml)")
    parser.add_argument("--duration", type=float, help="stop after this many seconds")
    parser.add_argument("--log-dir", help="base directory for run logs (default: logging.dir)")
    parser.add_argument("--no-log", action="store_true", help="write no run log")
    parser.add_argument("--mavlink", help="override mavlink.url (pymavlink connection string)")
    parser.add_argument("--port", help="override the first CAN bus's channel (serial device)")
    parser.add_argument("--quiet", "-q", action="store_true", help="no live status, summary only")
    parser.add_argument("--verbose", "-v", action="store_true", help="debug logging")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.WARNING,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
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
    try:
        config = apply_overrides(load_config(path), args.mavlink, args.port)
    except ConfigError as exc:
        print(f"mavservo: invalid configuration\n{exc}", file=sys.stderr)
        return 2
    except OverrideError as exc:  # names the option: "--mavlink udpin:...:bad: port 'bad' ..."
        print(f"mavservo: {exc}", file=sys.stderr)
        return 2
    except (OSError, ValueError) as exc:
        print(f"mavservo: cannot use {path}: {exc}", file=sys.stderr)
        return 2

    from mavservo.app.bridge import Bridge, settle_heap

    display = StatusDisplay(enabled=not args.quiet)
    bridge = Bridge(
        config,
        config_path=path,
        log_dir=False if args.no_log else args.log_dir,
        status=display.event,
    )
    stop = threading.Event()

    def on_signal(signum: int, _frame: Any) -> None:
        stop.set()

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            bridge.start()
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
        with display:
            while not stop.is_set():
                if deadline is not None and time.monotonic() >= deadline:
                    break
                display.update(bridge.status_rows())
                stop.wait(0.2)
        summary = bridge.stop()
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    print(format_summary(summary))
    return 0
