"""``mavservo sim``: run the USB-CAN adapter emulator with simulated servos until signalled.

The first line of standard output is the device path to open (flushed at once), so a script
can do ``path=$(mavservo sim ... | head -1)``. Servos, bitrate and faults come from options or
from the ``simulation`` section of a YAML file (options given explicitly win)::

    simulation:
      bitrate: 1000000          # CAN bitrate until the host's settings frame says otherwise
      protocol: variable        # or fixed
      seed: 0
      status_rate_hz: 50        # push rate of push-style servos (cubemars-ak)
      line_faults: {flip_prob: 0.0, drop_byte_prob: 0.0, burst_prob: 0.0, burst_len: 8,
                    direction: to_host}
      servos:
        - id: 1
          profile: rmd-x        # any registered profile (mavservo check --profiles)
          status_rate_hz: 50    # optional, per servo
          physics: {max_speed_dps: 720, max_accel_dps2: 3600, relax_after_s: 2.0, ...}
          faults: {drop_reply_prob: 0.0, reply_delay_s: 0.0, silent: false,
                   over_current: false, over_temperature: false}

A full ``mavservo run`` config (one with a top-level ``servos:`` list) is accepted too: it is
validated like ``mavservo run`` does, and the adapter carries the servos the config puts on one
of its buses (``--bus``, default the first) with their profiles, CAN ids and telemetry rates,
at the bus's bitrate and protocol, tuned by ``simulation.servos`` where that names them. So a
bridge run against the printed device finds every servo it expects.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from collections.abc import Sequence
from typing import Any

from ..servos import ActuatorOptions, get_profile
from ..threads import set_from_signal_handler
from .adapter import AdapterEmulator, LineFaults
from .servo import Faults, Physics, SimServo, share_nodes

#: Signals that end the emulator cleanly (its pty closed, its ``--link`` removed).
STOP_SIGNALS = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)
)


def _ignored_hangup(signum: int) -> bool:
    """A SIGHUP ignored at start (``nohup mavservo sim``) stays ignored: the user asked for it
    to outlive the terminal."""
    return signum == getattr(signal, "SIGHUP", None) and signal.getsignal(signum) is signal.SIG_IGN


def _ids(text: str) -> list[int]:
    return [int(part, 0) for part in text.split(",") if part.strip()]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mavservo sim",
        description="Emulate an AA-55 USB-CAN adapter with simulated CAN servos on a pty. The "
        "first line on standard output is the device path to open (a symlink to the pty: the "
        "--link path, or one in a temporary directory), so `path=$(mavservo sim ... | head -1)` "
        "works; a summary line goes to standard error. Runs until Ctrl-C, SIGTERM or SIGHUP, "
        "then removes the symlink.",
        epilog="Options given on the command line win over the --config file's settings.",
    )
    parser.add_argument(
        "--config",
        help="a mavservo config (simulates the servos of one of its buses) or a YAML file with "
        "a standalone 'simulation' section",
    )
    parser.add_argument(
        "--bus", default=None, help="with a mavservo config: the bus to simulate (default: first)"
    )
    parser.add_argument(
        "--servos",
        type=int,
        default=None,
        help="number of servos (default 1); servos of a profile with actuator ids (dronecan) get "
        "actuator ids 1..N in --ids order, ArduPilot's numbering (SERVOn -> actuator n); PX4 "
        "numbers from 0: give such servos in a --config file's simulation.servos options",
    )
    parser.add_argument(
        "--ids",
        type=_ids,
        default=None,
        help="servo CAN ids, e.g. 1,2,3 (default 1..--servos; DroneCAN: the node ids)",
    )
    parser.add_argument(
        "--profile",
        default=None,
        help="servo profile (default rmd-x; `mavservo check --profiles` lists them)",
    )
    parser.add_argument(
        "--bitrate",
        type=int,
        default=None,
        help="CAN bitrate in bit/s until the host's settings frame sets one (default 1000000)",
    )
    parser.add_argument(
        "--protocol",
        choices=("variable", "fixed"),
        default=None,
        help="AA-55 frame format on the serial line (default variable)",
    )
    parser.add_argument(
        "--link",
        default=None,
        help="also publish the device as a symlink at this path (removed on exit; default none)",
    )
    parser.add_argument(
        "--seed", type=int, default=None, help="random seed for faults and noise (default 0)"
    )
    parser.add_argument(
        "--status-rate-hz",
        type=float,
        default=None,
        help="push rate of push-style servos (cubemars-ak), in Hz (default 50)",
    )
    parser.add_argument(
        "--relax-after",
        type=float,
        default=None,
        help="seconds without command before a servo goes limp (default: never)",
    )
    faults = parser.add_argument_group("fault injection (all servos; default: none)")
    faults.add_argument(
        "--drop-reply-prob",
        type=float,
        default=None,
        help="probability (0..1) that a servo drops a reply",
    )
    faults.add_argument(
        "--reply-delay", type=float, default=None, help="seconds each reply is delayed"
    )
    faults.add_argument(
        "--silent-ids", type=_ids, default=None, help="CAN ids that never reply, e.g. 2,3"
    )
    faults.add_argument(
        "--over-current-ids", type=_ids, default=None, help="CAN ids reporting over-current"
    )
    faults.add_argument(
        "--over-temperature-ids",
        type=_ids,
        default=None,
        help="CAN ids reporting over-temperature",
    )
    faults.add_argument(
        "--flip-prob",
        type=float,
        default=None,
        help="probability (0..1) per byte on the serial line of a flipped bit",
    )
    faults.add_argument(
        "--drop-byte-prob",
        type=float,
        default=None,
        help="probability (0..1) per byte on the serial line of a lost byte",
    )
    faults.add_argument(
        "--burst-prob",
        type=float,
        default=None,
        help="probability (0..1) per write of a burst of 8 garbage bytes on the serial line",
    )
    faults.add_argument(
        "--line-direction",
        choices=("to_host", "to_adapter", "both"),
        default=None,
        help="which direction of the serial line the line faults hit (default to_host)",
    )
    return parser


def load_simulation_section(path: str, bus: str | None = None) -> dict[str, Any]:
    """The simulation settings of a YAML file, in the standalone shape of the module docstring.

    A full mavservo config (top-level ``servos:``) is handed to :func:`config_section`; any
    other file is read for its ``simulation`` mapping (empty if absent).
    """
    import yaml

    try:
        with open(path, encoding="utf-8") as handle:
            document = yaml.safe_load(handle) or {}
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: invalid YAML: {exc}") from None
    if not isinstance(document, dict):
        raise ValueError(f"{path}: expected a mapping with a 'simulation' or 'servos' section")
    if "servos" in document:
        return config_section(path, bus)
    if bus is not None:
        raise ValueError(f"--bus {bus}: {path} is not a mavservo config (it has no 'servos')")
    section = dict(document.get("simulation") or {})
    servos = section.get("servos")
    if servos is not None and not isinstance(servos, list):
        raise ValueError(f"{path}: 'simulation.servos' must be a list")
    return section


def config_section(path: str, bus: str | None = None) -> dict[str, Any]:
    """The standalone shape for the servos a mavservo config puts on ``bus`` (default: first).

    The config is validated exactly as ``mavservo run`` validates it (a bad file raises
    :class:`~mavservo.config.ConfigError` with its lines), and each servo is simulated as the
    bridge's own simulation does it: its profile, CAN id and ``telemetry_hz`` as the push rate,
    ``simulation.servos[name]`` (or ``default``) for physics and faults, and a start position
    inside its limits.
    """
    from mavservo.config import load_config

    config = load_config(path)
    buses = {b.name: b for b in config.can.buses}
    name = bus if bus is not None else config.can.buses[0].name
    if name not in buses:
        raise ValueError(f"--bus {name}: {path} has no such bus; its buses: {', '.join(buses)}")
    specs = []
    for servo in config.servos:
        if config.bus_of(servo).name != name:
            continue
        physics, faults = config.simulated_settings(servo)
        specs.append(
            {
                "id": servo.can_id,
                "profile": servo.profile,
                "physics": physics,
                "faults": faults,
                "status_rate_hz": servo.telemetry_hz,
                "options": dict(servo.options),
            }
        )
    return {
        "bus": name,
        "bus_count": len(buses),
        "bitrate": buses[name].bitrate,
        "protocol": buses[name].protocol,
        "servos": specs,
    }


def read_section(args: argparse.Namespace) -> dict[str, Any]:
    """The ``--config`` file's simulation settings (empty without one)."""
    if args.bus is not None and not args.config:
        raise ValueError("--bus needs --config FILE (a mavservo config)")
    return load_simulation_section(args.config, args.bus) if args.config else {}


def build_emulator(
    args: argparse.Namespace, section: dict[str, Any] | None = None
) -> AdapterEmulator:
    """Servos and adapter from the YAML section, with command-line options on top."""
    if section is None:
        section = read_section(args)
    seed = args.seed if args.seed is not None else int(section.get("seed", 0))
    rate = args.status_rate_hz or float(section.get("status_rate_hz", 50.0))
    specs: list[dict[str, Any]] = [dict(s) for s in section.get("servos") or []]
    explicit = args.ids is not None or args.servos is not None
    if "bus" in section and not specs and not explicit:
        # A config's bus with no servos: falling back to the default rmd-x:1 would simulate a
        # servo the config never declared, and the bridge would find none of its own.
        raise ValueError(
            f"--bus {section['bus']}: no servo of {args.config} is on bus '{section['bus']}'"
        )
    if explicit or not specs:
        profile = args.profile or "rmd-x"
        ids = args.ids or list(range(1, (args.servos or 1) + 1))
        specs = [{"id": i, "profile": profile} for i in ids]
        if "actuator_id" in get_profile(profile).Options.model_fields:
            # servos addressed by actuator id on a shared broadcast (DroneCAN's ArrayCommand):
            # all on the default id would all follow one command. 1..N in --ids order, the
            # ArduPilot numbering (SERVOn -> actuator n) config/dronecan.yaml uses too
            for number, spec in enumerate(specs, start=1):
                spec["options"] = {"actuator_id": number}
    elif args.profile:
        for spec in specs:
            if spec.get("profile") != args.profile:
                spec.pop("options", None)  # options belong to the profile they were written for
            spec["profile"] = args.profile

    servos = []
    for index, spec in enumerate(specs):
        unknown = set(spec) - {"id", "profile", "physics", "faults", "status_rate_hz", "options"}
        if unknown:
            raise ValueError(f"simulation.servos[{index}]: unknown key(s) {sorted(unknown)}")
        physics = Physics.from_dict(spec.get("physics"))
        faults = Faults.from_dict(spec.get("faults"))
        can_id = int(spec["id"])
        if args.relax_after is not None:
            physics.relax_after_s = args.relax_after
        if args.drop_reply_prob is not None:
            faults.drop_reply_prob = args.drop_reply_prob
        if args.reply_delay is not None:
            faults.reply_delay_s = args.reply_delay
        faults.silent |= can_id in (args.silent_ids or [])
        faults.over_current |= can_id in (args.over_current_ids or [])
        faults.over_temperature |= can_id in (args.over_temperature_ids or [])
        profile = str(spec.get("profile", "rmd-x"))
        options = get_profile(profile).Options.model_validate(spec.get("options") or {})
        servos.append(
            SimServo(
                profile,
                can_id,
                physics,
                faults,
                seed=seed + index,
                status_rate_hz=float(spec.get("status_rate_hz", rate)),
                options=options,
            )
        )

    line = LineFaults.from_dict(section.get("line_faults"))
    for option, field in (
        ("flip_prob", "flip_prob"),
        ("drop_byte_prob", "drop_byte_prob"),
        ("burst_prob", "burst_prob"),
        ("line_direction", "direction"),
    ):
        value = getattr(args, option)
        if value is not None:
            setattr(line, field, value)
    return AdapterEmulator(
        share_nodes(servos),
        bitrate=args.bitrate or int(section.get("bitrate", 1_000_000)),
        protocol=args.protocol or section.get("protocol", "variable"),
        line_faults=line,
        link_path=args.link,
        seed=seed,
    )


def _servo_label(servo: SimServo) -> str:
    """``profile:can_id``, with the actuator id where the profile has one (``dronecan:11/a1``)."""
    actuator = servo.options.actuator_id if isinstance(servo.options, ActuatorOptions) else None
    return f"{servo.profile}:{servo.can_id}" + ("" if actuator is None else f"/a{actuator}")


def main(argv: Sequence[str] | None = None) -> int:
    """Run until SIGINT, SIGTERM or SIGHUP; exit 0 on a clean stop, 2 on a configuration error.

    SIGHUP (the terminal closed, ``ssh`` dropped) stops it like SIGTERM: by default it would
    kill the process without the ``finally`` below, leaving the ``--link`` symlink dangling."""
    parser = build_parser()
    args = parser.parse_args(argv)
    from mavservo.config import ConfigError

    try:
        section = read_section(args)
        emulator = build_emulator(args, section)
    except (OSError, ValueError, KeyError, ConfigError) as error:
        print(f"mavservo sim: {error}", file=sys.stderr)
        return 2
    stop = threading.Event()
    previous = {
        sig: signal.signal(sig, lambda *_: set_from_signal_handler(stop))
        for sig in STOP_SIGNALS
        if not _ignored_hangup(sig)
    }
    emulator.start()
    try:
        print(emulator.path, flush=True)
        servo_list = ", ".join(_servo_label(s) for s in emulator.servos)
        source = ""
        if "bus" in section:
            source = f", bus {section['bus']} of {args.config}"
            if section["bus_count"] > 1:
                source += f" (1 of {section['bus_count']} buses; --bus NAME for another)"
        print(
            f"# {emulator.device} at {emulator.bitrate} bit/s{source}, servos {servo_list}",
            file=sys.stderr,
            flush=True,
        )
        while not stop.wait(0.2):
            if emulator.error is not None:
                print(f"mavservo sim: adapter failed: {emulator.error!r}", file=sys.stderr)
                return 1
    finally:
        emulator.stop()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
