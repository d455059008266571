"""``mavservo check``: validate config files and show what they resolve to.

Prints, for each valid file, where it connects (the MAVLink endpoint and each bus's interface,
saying when a left-out key means the built-in simulation), warnings for settings that will not
do what they say, the servos, the channel mapping with the angles the input's
min/trim/max land on (after reverse, trim and soft limits), the gimbal groups, and the
worst-case bus load per bus. Touches no hardware: the bus load comes from arithmetic only.

Its verdict is :func:`mavservo.config.preflight`'s, the one ``mavservo run`` starts from, so a
config ``check`` calls valid is one ``run`` starts (issue 37): that includes the built-in
simulated autopilot refused on a real bus, and each bus's channel and bitrate against its
interface. Devices that are not on this machine (yet) are warnings, not errors.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Sequence
from typing import TextIO

from mavservo.app.check_links import left_out, link_lines
from mavservo.app.fleet_check import clashes
from mavservo.config import (
    BusLoad,
    Config,
    ConfigError,
    LoadedConfig,
    OverrideError,
    ServoOutputChannel,
    bus_loads,
    bus_nodes,
    current_values,
    default_text,
    endpoint_lines,
    overlay_path,
    preflight,
    servos_on,
    tunnel_plan_lines,
)
from mavservo.config import allowed_values as _allowed
from mavservo.control import ChannelMap, Rejected, describe_limits, servo_limits
from mavservo.mavlink import AUTO_ESC_FIRST, BudgetPlan, WritePolicy, plan_budget
from mavservo.servos import PLUGIN_HINT, load_errors, node_family, profiles, release_frames_of

EXIT_OK = 0
EXIT_INVALID = 2


def _table(headers: list[str], rows: list[list[str]]) -> list[str]:
    widths = [max(len(headers[i]), *(len(row[i]) for row in rows)) for i in range(len(headers))]

    def line(cells: list[str]) -> str:
        padded = (cell.ljust(width) for cell, width in zip(cells, widths, strict=True))
        return "  ".join(padded).rstrip()

    return [line(headers), line(["-" * width for width in widths])] + [line(row) for row in rows]


def _angle_text(channel_map: ChannelMap, value: float) -> str:
    target = channel_map.to_angle(value)
    if isinstance(target, Rejected):
        return "rejected"
    return f"{target.angle_deg:+.1f}" + ("*" if target.clamped else "")


def resolved_mapping(config: Config) -> str:
    """A human-readable description of what a validated config does."""
    lines = ["connections:"]
    lines += ["  " + line for line in endpoint_lines(config)]
    lines += ["", "MAVLink telemetry:"]
    lines += ["  " + line for line in telemetry_lines(config)]
    lines += link_lines(config)  # px4: what each link gets (issue 38 item 5)
    lines += ["", "servos:"]
    lines += [
        "  " + row
        for row in _table(
            ["name", "profile", "id", "bus", "limits deg", "mode", "telemetry", "failsafe"],
            [
                [
                    s.name,
                    s.profile,
                    str(s.can_id),
                    config.bus_of(s).name,
                    f"[{s.limits_deg[0]:g}, {s.limits_deg[1]:g}]",
                    s.command_mode,
                    f"{s.telemetry_hz:g} Hz",
                    s.failsafe.action
                    + (f" {s.failsafe.position_deg:g}" if s.failsafe.action == "position" else "")
                    + f" after {s.failsafe.timeout_s:g} s",
                ]
                for s in config.servos
            ],
        )
    ]
    if config.channels:
        rows = []
        for channel in config.channels:
            channel_map = ChannelMap.from_config(channel, config)
            name = (
                f"servo {channel.channel}"
                if isinstance(channel, ServoOutputChannel)
                else f"actuator {channel.index}"
            )
            unit = " us" if channel_map.kind == "pwm" else ""
            rows.append(
                [
                    name,
                    channel.servo,
                    f"{channel_map.input_min:g}/{channel_map.input_trim:g}/{channel_map.input_max:g}"
                    + unit,
                    " / ".join(
                        _angle_text(channel_map, v)
                        for v in (
                            channel_map.input_min,
                            channel_map.input_trim,
                            channel_map.input_max,
                        )
                    ),
                    "yes" if channel.reverse else "no",
                    f"{channel.max_slew_dps:g} deg/s" if channel.max_slew_dps else "-",
                ]
            )
        lines += ["", "channels (angles for input min / trim / max; * = clamped by limits):"]
        lines += [
            "  " + row
            for row in _table(
                ["input", "servo", "min/trim/max", "angle deg", "reverse", "slew"], rows
            )
        ]
    if config.gimbals:
        lines += ["", "gimbals:"]
        for gimbal in config.gimbals:
            axes = ", ".join(f"{axis}={servo}" for axis, servo in gimbal.axes().items())
            lines.append(f"  {gimbal.name} (component {gimbal.component_id}): {axes}")
    for bus in config.can.buses:
        for profile, servos, node in bus_nodes(bus, servos_on(config, bus)):
            lines += ["", f"bus {bus.name}: the bridge's {profile} node"]
            lines += ["  " + line for line in node.describe([s.name for s in servos])]
    lines += ["", "when the bridge's frames stop (stopped, bus or adapter gone), each servo:"]
    lines += ["  " + line for line in stop_behaviour_lines(config)]
    lines += ["", "health checks (servos[].health; docs/health.md):"]
    for servo in config.servos:  # the thresholds in force, derived or set (issue 33)
        lines += describe_limits(servo.name, servo_limits(config, servo))
    lines += ["", "worst-case bus load R (bits of every frame at the configured rates / bitrate):"]
    lines += ["  " + _load_line(load) for load in bus_loads(config)]
    return "\n".join(lines)


def stop_behaviour_lines(config: Config) -> list[str]:
    """What the servos do by themselves once no frame comes (their family's documented stop
    behaviour, ``ServoProfile.stop_behaviour``), servos that behave alike on one line: the
    failsafe action is what the bridge sends while it runs; this is what follows."""
    groups: dict[str, list[str]] = {}
    for servo in config.servos:
        groups.setdefault(servo.make_profile().stop_behaviour(), []).append(servo.name)
    return [f"{', '.join(names)}: {text}" for text, names in groups.items()]


def profiles_listing() -> str:
    """Every usable profile: name, origin, id range, telemetry shape, whether it can release,
    and each option with its default and allowed values."""
    lines = ["servo profiles:"]
    for name, entry in profiles().items():
        cls = entry.profile
        can_release = "yes" if release_frames_of(cls(cls.min_id)) else "no"
        lines.append(
            f"  {name}  ({entry.origin}; ids {cls.min_id}..{cls.max_id}, {cls.telemetry}, "
            f"failsafe release: {can_release})"
        )
        fields = cls.Options.model_fields
        if not fields:
            lines.append("    options: none")
        for key, field in fields.items():
            about = f" - {field.description}" if field.description else ""
            lines.append(
                f"    {key}: {_allowed(field)}; default {default_text(field.default)}{about}"
            )
        family = node_family(cls)
        if family is not None:  # a family with a node on its bus (DroneCAN)
            lines.append(f"    bus node options (can.buses[].node.{name}):")
            for key, field in family.NodeOptions.model_fields.items():
                about = f" - {field.description}" if field.description else ""
                default = field.get_default(call_default_factory=True)
                lines.append(
                    f"      {key}: {_allowed(field)}; default {default_text(default)}{about}"
                )
    lines += ["", PLUGIN_HINT]
    return "\n".join(lines)


def _load_line(load: BusLoad) -> str:
    verdict = "OVER BUDGET" if load.over_budget else "ok"
    return (
        f"{load.bus}: R = {load.load:.3f} of max {load.max_load:g} "
        f"({_count(load.servo_count, 'servo')}, {load.bitrate} bit/s) {verdict}"
    )


def overlay_lines(loaded: LoadedConfig, path: str) -> list[str]:
    """The values a ground station set (the overlay), against the file's own."""
    file_values = current_values(loaded.base)
    lines = [f"parameters set from a ground station ({overlay_path(path)}, in force):"]
    lines += [
        f"  {name} {value:g} (file: {file_values[name]:g})"
        for name, value in sorted(loaded.overlay.items())
    ]
    lines.append(f"  `mavservo params --clear {path}` returns to the file's values")
    return lines


def telemetry_lines(config: Config) -> list[str]:
    """Who the bridge is on the vehicle, its ESC numbers and names, and the bytes per second it
    sends on each link (what a telemetry radio has to carry)."""
    telemetry = config.mavlink.telemetry
    servos = len(config.servos)
    first = AUTO_ESC_FIRST if telemetry.esc_first_index == "auto" else telemetry.esc_first_index
    last = first + servos - 1
    moves = " (auto: moves above ESC telemetry the autopilot or another bridge sends)"
    esc = f"ESC {first}-{last}" if last <= 32 else f"ESC {first}-32 (servos past ESC 32: none)"
    prefix = telemetry.name_prefix
    gimbals = ", ".join(str(g.component_id) for g in config.gimbals) or "none"
    plan = link_plan(config)
    writers = WritePolicy(
        frozenset((a.system, a.component) for a in config.mavlink.allowed_sources),
        open=config.mavlink.parameter_writers == "anyone",
    )
    return [
        f"components: servos {config.mavlink.servo_component_id}, gimbals {gimbals}",
        writers.describe(signing=config.mavlink.signing is not None),
        *writers.signing_advice(signing=config.mavlink.signing is not None),
        f"servo ESC numbers: {esc}" + (moves if telemetry.esc_first_index == "auto" else ""),
        f"NAMED_VALUE_FLOAT names: {prefix}1_pos .. {prefix}{servos}_flt "
        f"(health bits: {prefix}<n>_hlt)",
        *plan.lines(),
    ]


def link_plan(config: Config) -> BudgetPlan:
    """The autopilot link's periodic load of a config, as the running bridge plans it."""
    return plan_budget(
        config.mavlink.link_budget_bytes_s,
        servos=len(config.servos),
        gimbals=len(config.gimbals),
        health_names=len(config.can.buses) + 6,
        components=1 + len(config.gimbals),
        rates=config.mavlink.telemetry,
        signed=config.mavlink.signing is not None,
        left_out=left_out(config),  # px4: what the configured autopilot would drop
    )


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def build_parser() -> argparse.ArgumentParser:
    return argparse.ArgumentParser(
        prog="mavservo check",
        description=(
            "Validate mavservo config files without touching any hardware. For each valid file, "
            "print where it connects (MAVLink endpoint, CAN interface and channel per bus, or "
            "the built-in simulation), warnings, the servos, the channel mapping (angles at "
            "input min/trim/max) and the worst-case bus load. Errors go to stderr as "
            "FILE:LINE: key: message."
        ),
        epilog="exit status: 0 when every file is valid, 2 otherwise",
    )


def check_main(argv: Sequence[str], out: TextIO | None = None, err: TextIO | None = None) -> int:
    """``mavservo check CONFIG...``: 0 when all files are valid, 2 otherwise. Never raises."""
    out = out if out is not None else sys.stdout
    err = err if err is not None else sys.stderr
    parser = build_parser()
    parser.add_argument("configs", nargs="*", metavar="CONFIG", help="YAML config file(s)")
    parser.add_argument(
        "--one-vehicle",
        action="store_true",
        help="the configs are bridges of one vehicle: a clash between them (component id, "
        "name prefix, mapped channel, ESC numbers, endpoint, adapter) fails the check",
    )
    parser.add_argument(
        "--profiles",
        action="store_true",
        help="list every servo profile (built-in and plug-in), its origin, options and defaults",
    )
    try:
        # argparse prints --help and usage errors to sys.stdout/sys.stderr itself; a caller that
        # passed its own streams (an embedding tool, a test) gets them there like every line.
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            args = parser.parse_args(list(argv))
    except SystemExit as exc:  # --help (0) or a usage error (2), already printed by argparse
        return EXIT_OK if exc.code == 0 else EXIT_INVALID
    if not args.configs and not args.profiles:
        parser.print_usage(err)  # as argparse does for a missing argument
        print("mavservo check: error: give CONFIG file(s), --profiles, or both", file=err)
        return EXIT_INVALID
    for error in load_errors():  # one broken plug-in hides nothing else
        print(f"warning: {error.describe()}", file=err)
    if args.profiles:
        print(profiles_listing(), file=out)
    status = EXIT_OK
    valid: list[tuple[str, Config]] = []
    for path in args.configs:
        try:  # the same verdict `mavservo run` starts from (mavservo.config.preflight)
            checked = preflight(path)
        except (ConfigError, OverrideError) as exc:
            print(str(exc), file=err)
            status = EXIT_INVALID
            continue
        loaded, config, warnings = checked.loaded, checked.config, checked.warnings
        valid.append((path, config))
        print(f"{path}: valid\n", file=out)
        if loaded.overlay:
            print("\n".join(overlay_lines(loaded, path)) + "\n", file=out)
        if warnings:
            print("warnings:", file=out)
            for warning in warnings:
                print("  " + warning.format(path), file=out)
            print(file=out)
        print(resolved_mapping(config), file=out)
        print(file=out)
        print("".join(line + "\n\n" for line in tunnel_plan_lines(config)), end="", file=out)
    if len(valid) > 1:
        # gcs (issue 30): bridges meant for one vehicle must not fight over an identity, and
        # share one radio: their link loads add up
        plans = [link_plan(config) for _path, config in valid]
        print(
            f"together: {len(valid)} bridges put {sum(p.link_bytes_s for p in plans):,.0f} B/s "
            "of periodic telemetry on the autopilot link and the ground station's (each "
            "link_budget_bytes_s is per bridge: split the radio's share between them)",
            file=out,
        )
        found = clashes(valid)
        if found:
            fatal = args.one_vehicle
            print(
                f"{'error' if fatal else 'warning'}: if these {len(valid)} configs run on one "
                "vehicle, they clash:",
                file=err,
            )
            for line in found:
                print("  " + line, file=err)
            if fatal:
                status = EXIT_INVALID
            else:
                print("  (--one-vehicle makes this an error)", file=err)
        else:
            print(
                f"no clash between the {len(valid)} configs: components, name prefixes, "
                "mapped channels, ESC numbers, endpoints and adapters differ",
                file=out,
            )
    return status
