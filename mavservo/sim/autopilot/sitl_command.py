"""``python -m mavservo.sim.autopilot stream|replay``: the simulator and the tlog replayer from a
shell.

``main(argv) -> int`` is also what ``mavservo sitl ...`` calls. Ctrl-C ends either command cleanly
with exit status 0 after printing what was sent and received.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import sys
import threading
import time
from pathlib import Path

import yaml

from mavservo.config import Dropout, Event, parse_script, read_key_file
from mavservo.sim.autopilot.motion_scripts import PROFILES, RandomWalkProfile, get_profile
from mavservo.sim.autopilot.px4 import Px4Stream
from mavservo.sim.autopilot.px4_sitl import run_px4
from mavservo.sim.autopilot.replay import BRIDGE_TYPES, TlogError, replay
from mavservo.sim.autopilot.stream import AutopilotStream, gimbal_demo_script
from mavservo.threads import set_from_signal_handler


def _target(text: str) -> tuple[int, int]:
    try:
        system, component = (int(part) for part in text.split("/"))
    except ValueError:
        raise argparse.ArgumentTypeError("expected SYSTEM/COMPONENT, e.g. 1/0") from None
    return system, component


#: ``--keep`` default: at 50 Hz SERVO_OUTPUT_RAW the logs are full after about 20 s.
STREAM_KEEP = 1000


def _positive_keep(text: str) -> int:
    value = int(text)
    if value < 2:
        raise argparse.ArgumentTypeError("must be at least 2")
    return value


def build_parser(prog: str = "sitl") -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=prog,
        description=f"The simulated autopilot ({prog} stream) or the replay of a recorded .tlog "
        f"({prog} replay), sending MAVLink to a bridge.",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser(
        "arduplane",
        help="run a built ArduPlane SITL with SERIAL1 sent to the bridge (never builds or "
        "fetches; 'arduplane --help' for its options)",
        add_help=False,
    )

    sub.add_parser(
        "px4",
        help="run a built PX4 SITL (SIH airframe 10041, headless) for the bridge's onboard "
        "link (never builds or fetches; 'px4 --help' for its options)",
        add_help=False,
    )

    s = sub.add_parser("stream", help="run the simulated ArduPilot (or --autopilot px4) stream")
    s.add_argument(
        "--url",
        default="udpout:127.0.0.1:14551",
        help="pymavlink connection string (default: %(default)s)",
    )
    s.add_argument(
        "--autopilot",
        choices=("ardupilot", "px4"),
        default="ardupilot",
        help="which autopilot to simulate: ArduPlane's port, or PX4's onboard link "
        "(mavservo/sim/autopilot/px4.py; its defaults are PX4's) (default: %(default)s)",
    )
    s.add_argument(
        "--profile",
        default="sweep",
        choices=sorted(PROFILES),
        help="how the servo outputs move: hold (at trim), sweep (repeating control-surface "
        "chirps), staircase or steps (min to max in held steps), random-walk (seeded by "
        "--seed) (default: %(default)s)",
    )
    s.add_argument("--seed", type=int, default=0, help="random-walk seed")
    s.add_argument("--duration", type=float, default=None, help="seconds (default: until Ctrl-C)")
    s.add_argument(
        "--servo-rate",
        type=float,
        default=None,
        help="SERVO_OUTPUT_RAW Hz (default: 20 for ArduPilot, PX4's onboard 10)",
    )
    s.add_argument(
        "--actuator-rate",
        type=float,
        default=0.0,
        help="ACTUATOR_OUTPUT_STATUS Hz, PX4-style normalized outputs (default: off)",
    )
    s.add_argument(
        "--gimbal",
        action="store_true",
        help="act as a gimbal manager (MNT1_TYPE 6) with a demo target sequence",
    )
    s.add_argument(
        "--script",
        type=Path,
        help="YAML list of timed commands, e.g. '- {at: 2.0, do_set_servo: {channel: 9, pwm: "
        "1100}}' (also do_repeat_servo, do_set_actuator, gimbal, dropout; see "
        "simulation.autopilot.script in docs/configuration.md and config/sim.yaml)",
    )
    s.add_argument(
        "--dropout",
        action="append",
        default=[],
        metavar="AT:SECONDS",
        help="go silent at AT s for SECONDS (repeatable); SIGUSR1 also starts one",
    )
    s.add_argument(
        "--dropout-seconds",
        type=float,
        default=3.0,
        help="length of a drop-out started by SIGUSR1 (default: %(default)s)",
    )
    s.add_argument(
        "--command-target",
        type=_target,
        default=(1, 0),
        help="SYSTEM/COMPONENT the mission commands go to (default: 1/0)",
    )
    s.add_argument(
        "--signing-key-file",
        type=Path,
        default=None,
        help="sign everything with this MAVLink 2 key (64 hex characters, the file a signed "
        "mavservo config's key_file names), as an autopilot set up for signing does",
    )
    s.add_argument(
        "--keep",
        type=_positive_keep,
        default=STREAM_KEEP,
        help="records kept per log (commanded values per channel, messages sent and received, "
        "commands, ACKs); a shell run reads none of them, so few keep its memory flat within "
        "a minute instead of filling 20,000 entries for a quarter of an hour "
        "(default: %(default)s)",
    )
    s.add_argument(
        "--repeat-cycle-ms",
        action="store_true",
        help="send DO_REPEAT_SERVO param4 in ms (ArduPilot) instead of s (spec)",
    )

    r = sub.add_parser("replay", help="replay a .tlog into a MAVLink link")
    r.add_argument("file", type=Path, help="the telemetry log (.tlog) to send")
    r.add_argument(
        "--url",
        default="udpout:127.0.0.1:14551",
        help="pymavlink connection string to send it to (default: %(default)s)",
    )
    r.add_argument("--speed", type=float, default=1.0, help="time factor (4 = 4x faster)")
    r.add_argument("--as-fast", action="store_true", help="ignore timestamps, send at once")
    r.add_argument(
        "--types",
        default=None,
        help=f"comma-separated message types, or 'all' (default: {','.join(sorted(BRIDGE_TYPES))})",
    )
    r.add_argument("--start", type=float, default=0.0, help="skip the first seconds of the file")
    r.add_argument("--end", type=float, default=None, help="stop at this file time")
    r.add_argument(
        "--max-duration",
        type=float,
        default=None,
        help="stop after this many seconds of wall-clock time, wherever the file is "
        "(default: play to --end or the end of the file)",
    )
    return parser


def _load_script(path: Path) -> list[Event]:
    """The events of a ``--script`` YAML file; ValueError says which event is wrong and how."""
    items = yaml.safe_load(path.read_text()) or []
    if not isinstance(items, list) or not all(isinstance(item, dict) for item in items):
        raise ValueError("expected a list of events like {at: 2.0, do_set_servo: {...}}")
    return parse_script(items).events


def _run_stream(args: argparse.Namespace) -> int:
    profile = (
        RandomWalkProfile(seed=args.seed)
        if args.profile == "random-walk"
        else get_profile(args.profile)
    )
    events = []
    if args.script is not None:
        try:
            events += _load_script(args.script)
        except (OSError, ValueError, yaml.YAMLError) as exc:
            print(f"sitl: --script {args.script}: {exc}", file=sys.stderr)
            return 2
    for spec in args.dropout:
        at, _, seconds = spec.partition(":")
        try:
            events.append(Event(float(at), Dropout(float(seconds))))
        except ValueError:
            print(f"sitl: bad --dropout {spec!r}, expected AT:SECONDS", file=sys.stderr)
            return 2
    if args.gimbal:
        events += gimbal_demo_script()
    signing_key = None
    if args.signing_key_file is not None:
        try:
            signing_key = read_key_file(args.signing_key_file)
        except ValueError as exc:
            print(f"sitl: --signing-key-file: {exc}", file=sys.stderr)
            return 2
    stream = (Px4Stream if args.autopilot == "px4" else AutopilotStream)(
        args.url,
        profile,
        events,
        **({} if args.servo_rate is None else {"servo_output_rate_hz": args.servo_rate}),
        actuator_output_status_hz=args.actuator_rate,
        gimbal=args.gimbal,
        command_target=args.command_target,
        duration_s=args.duration,
        repeat_servo_cycle="milliseconds" if args.repeat_cycle_ms else "seconds",
        signing_key=signing_key,
        keep=args.keep,
    )
    stream.start()
    if hasattr(signal, "SIGUSR1") and threading.current_thread() is threading.main_thread():
        previous_usr1 = signal.signal(
            signal.SIGUSR1, lambda signum, frame: stream.dropout(args.dropout_seconds)
        )
    else:
        previous_usr1 = None
    print(f"sitl: streaming profile {profile.name!r} to {args.url} (Ctrl-C to stop)", flush=True)
    try:
        while not stream.wait(0.2) and not _STOP.is_set():
            pass
    finally:
        stream.stop()
        if previous_usr1 is not None:
            signal.signal(signal.SIGUSR1, previous_usr1)
    print(f"sitl: sent {dict(stream.sent)}")
    print(f"sitl: received {stream.received.counts()}")
    t0 = stream.t0 or 0.0  # set by start(); drop-outs are only recorded after it
    for start, end in stream.dropouts:
        print(f"sitl: drop-out {start - t0:.1f}..{end - t0:.1f} s")
    for record in stream.commands.commands:
        print(
            f"sitl: command {record.command} {record.params[:3]} attempts={record.attempts} "
            f"result={record.result}"
        )
    return 1 if stream.error else 0


def _run_replay(args: argparse.Namespace) -> int:
    if args.types is None:
        types = BRIDGE_TYPES
    elif args.types == "all":
        types = None
    else:
        types = frozenset(t.strip().upper() for t in args.types.split(",") if t.strip())
    started = time.monotonic()
    pace = "as fast as possible" if args.as_fast else f"at {args.speed:g}x"
    print(f"sitl: replaying {args.file} to {args.url} {pace} (Ctrl-C to stop)", flush=True)
    try:
        result = replay(
            args.file,
            args.url,
            speed=args.speed,
            as_fast=args.as_fast,
            types=types,
            start_s=args.start,
            end_s=args.end,
            max_duration_s=args.max_duration,
            stop=_STOP,
        )
    except (OSError, TlogError) as exc:
        print(f"sitl: {exc}", file=sys.stderr)
        return 2
    if _STOP.is_set():
        print(f"sitl: replay interrupted after {time.monotonic() - started:.1f} s")
    print(f"sitl: replayed {result.sent} messages in {result.duration_s:.2f} s: {result.per_type}")
    return 0


_STOP = threading.Event()


def _request_stop(signum: int, frame: object) -> None:
    set_from_signal_handler(_STOP)  # the main thread may be inside _STOP.wait (a replay)


def _stop_on_signals() -> dict[int, object]:
    """SIGINT and SIGTERM both end a run cleanly (exit 0), even where the shell ignored SIGINT.

    The handler only sets an event that the loops poll, so a signal can never land as an
    exception in the middle of closing the link or printing the summary.
    """
    _STOP.clear()
    previous: dict[int, object] = {}
    if threading.current_thread() is threading.main_thread():
        for signum in (signal.SIGINT, signal.SIGTERM):
            previous[signum] = signal.signal(signum, _request_stop)
    return previous


#: The ArduPlane SITL launcher, shipped with the package (a pip install has no repository paths).
ARDUPLANE_SCRIPT = Path(__file__).with_name("run-arduplane.sh")


def run_arduplane(argv: list[str]) -> int:
    """``mavservo sitl arduplane ...``: the packaged run-arduplane.sh with ``argv`` (its own
    options; ``--help`` lists them). It runs an arduplane binary already built and never
    builds, fetches or runs sim_vehicle.py; replaces this process, so signals reach SITL."""
    bash = shutil.which("bash")
    if bash is None:
        print(
            "mavservo sitl arduplane: needs bash (the launcher is a bash script)", file=sys.stderr
        )
        return 3
    os.execv(bash, [bash, str(ARDUPLANE_SCRIPT), *argv])
    return 0  # not reached: execv replaces the process


def main(argv: list[str] | None = None, prog: str = "sitl") -> int:
    """``prog``: the name in usage texts (``mavservo sitl`` when run through ``mavservo``)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["arduplane"]:
        return run_arduplane(argv[1:])
    if argv[:1] == ["px4"]:
        return run_px4(argv[1:])
    args = build_parser(prog).parse_args(argv)
    previous = _stop_on_signals()
    try:
        return _run_stream(args) if args.command == "stream" else _run_replay(args)
    finally:  # when called in-process (``mavservo sitl``, tests) give the caller its handlers back
        for signum, handler in previous.items():
            signal.signal(signum, handler)  # type: ignore[arg-type]


if __name__ == "__main__":
    sys.exit(main())
