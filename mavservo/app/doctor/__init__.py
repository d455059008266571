"""``mavservo doctor [CONFIG]``: a read-only diagnosis of the buses a config names.

For each bus it listens (listen-only where the adapter can), finds the bitrate with valid
traffic, says who is on the bus, probes each configured servo with requests that change nothing,
scans a family's id range with ``--scan FAMILY``, names the likely cause and fix of every
silent servo, and prints a ``servos:`` block that ``mavservo check`` accepts. Every frame it
sent and heard goes to ``doctor-<time>.asc`` in the config's log directory, so what it did can
be checked afterwards. Buses on ``channel: sim`` are diagnosed on their simulation, with the
mistakes ``simulation:`` injects. See docs/doctor.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import can
import yaml

from mavservo.app.startup_errors import Loc, bus_open_error, failure_lines
from mavservo.config import (
    Config,
    ConfigError,
    YamlDocument,
    bitrate_text,
    default_config_path,
    describe_bus,
    format_path,
    load_located,
    mavlink_settings,
)
from mavservo.mavlink import TunnelLink
from mavservo.servos import UnknownProfileError, get_profile
from mavservo.sim import simulator_factory
from mavservo.transport import (
    BITRATE_SET_OUTSIDE,
    MAVLINK_CAN,
    SIM_CHANNEL,
    BusRequest,
    OpenedBus,
    open_bus,
)

from .findings import BusFindings
from .node_info import TOOL_NODE_ID
from .session import BusDoctor
from .verdict import Verdict, extra_entries, judge

EXIT_OK, EXIT_PROBLEMS, EXIT_INVALID = 0, 1, 2


def _id_range(text: str) -> range:
    low, _, high = text.partition("-")
    try:
        start, end = int(low, 0), int(high or low, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an id range like 1-32") from None
    if not 0 <= start <= end <= 0x1FFFFFFF:
        raise argparse.ArgumentTypeError(f"{text!r}: ids must rise, from 0")
    return range(start, end + 1)


#: The longest listen per bitrate: ten NodeStatus periods, a hundred ODrive heartbeats.
MAX_LISTEN_S = 10.0


def _listen_seconds(text: str) -> float:
    """``--listen``: a finite number of seconds in (0, MAX_LISTEN_S] (NaN made every receive
    deadline unreachable; a huge value, one bitrate for hours)."""
    try:
        seconds = float(text)
    except ValueError:
        seconds = math.nan
    if not 0 < seconds <= MAX_LISTEN_S:  # NaN fails both comparisons
        raise argparse.ArgumentTypeError(f"{text!r}: seconds in (0, {MAX_LISTEN_S:g}]")
    return seconds


def _node_id(text: str) -> int:
    """``--node-id``: a DroneCAN node id, 1..127."""
    try:
        node_id = int(text)
    except ValueError:
        node_id = 0
    if not 1 <= node_id <= 127:
        raise argparse.ArgumentTypeError(f"{text!r}: a DroneCAN node id is 1..127")
    return node_id


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mavservo doctor",
        description="Read-only diagnosis of a config's CAN buses: bitrate, who is on the bus, "
        "why a servo is silent, and a servos: block that works.",
    )
    parser.add_argument("config", nargs="?", help="config file (default: the built-in one)")
    parser.add_argument(
        "--scan",
        action="append",
        default=[],
        metavar="FAMILY",
        help="also probe FAMILY's whole id range (safe requests only); repeatable",
    )
    parser.add_argument("--ids", type=_id_range, help="the id range of --scan, e.g. 1-32")
    parser.add_argument(
        "--allow-enable",
        action="store_true",
        help="may send enable frames (then the matching disable) to motors that answer "
        "nothing else (CubeMars/Robstride in MIT mode); never sent without it",
    )
    parser.add_argument(
        "--listen",
        type=_listen_seconds,
        default=1.5,
        metavar="S",
        help=f"seconds of listening per bitrate (0 < S <= {MAX_LISTEN_S:g})",
    )
    parser.add_argument(
        "--no-bitrate-search",
        action="store_true",
        help="stay at the configured bitrate instead of trying the standard ones",
    )
    parser.add_argument(
        "--node-id",
        type=_node_id,
        default=TOOL_NODE_ID,
        help="the DroneCAN node id the doctor asks GetNodeInfo from (default 127, the id the "
        "DroneCAN specification reserves for tools)",
    )
    parser.add_argument("--log-dir", help="where doctor-<time>.asc goes (default: logging.dir)")
    return parser


class FrameLog:
    """Every frame the doctor sent (TX) and heard (RX), in one ASC file (python-can's writer),
    the channel numbering the config's buses."""

    def __init__(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self._writer = can.ASCWriter(str(path))
        self.frames = 0

    def record(self, channel: int) -> Callable[[can.Message, bool, int], None]:
        def write(msg: can.Message, rx: bool, bitrate: int) -> None:
            copy = can.Message(
                timestamp=time.time(),
                arbitration_id=msg.arbitration_id,
                is_extended_id=msg.is_extended_id,
                is_remote_frame=msg.is_remote_frame,
                is_error_frame=msg.is_error_frame,
                dlc=msg.dlc,
                data=msg.data,
                is_rx=rx,
                channel=channel,
                check=False,
            )
            self._writer.on_message_received(copy)
            self.frames += 1

        return write

    def close(self) -> None:
        self._writer.stop()


def _skipped_ids(asked: range, probed: range) -> str:
    """The ids of ``asked`` left out of ``probed`` (a sub-range), e.g. ``"0, 33-80"``; "" for none.

    Said aloud because ``--ids 1-80`` quietly probing 1..32 reads as "nothing at 33..80"
    (issue 37)."""

    def span(start: int, stop: int) -> str:
        return str(start) if stop - start == 1 else f"{start}-{stop - 1}"

    parts = []
    if asked.start < probed.start:
        parts.append(span(asked.start, probed.start))
    if probed.stop < asked.stop:
        parts.append(span(probed.stop, asked.stop))
    return ", ".join(parts)


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    path = Path(args.config) if args.config else default_config_path()
    try:
        config, _warnings, document = load_located(path)
    except ConfigError as exc:
        print(f"mavservo doctor: invalid configuration\n{exc}", file=sys.stderr)
        return EXIT_INVALID
    if args.ids is not None and not args.scan:
        print("mavservo doctor: --ids goes with --scan FAMILY", file=sys.stderr)
        return EXIT_INVALID
    scans: list[tuple[str, range]] = []
    for family in args.scan:
        try:
            cls = get_profile(family)
        except UnknownProfileError as exc:
            print(f"mavservo doctor: --scan: {exc}", file=sys.stderr)
            return EXIT_INVALID
        family_ids = range(cls.min_id, cls.max_id + 1)
        ids = family_ids
        if args.ids is not None:  # only the family's own ids: 0-0x1FFFFFFF would take hours
            ids = range(max(args.ids.start, cls.min_id), min(args.ids.stop, family_ids.stop))
            if not ids:
                print(
                    f"mavservo doctor: --ids {args.ids.start}-{args.ids.stop - 1}: {family} "
                    f"ids are {cls.min_id}-{cls.max_id}",
                    file=sys.stderr,
                )
                return EXIT_INVALID
            skipped = _skipped_ids(args.ids, ids)
            if skipped:
                print(
                    f"mavservo doctor: --scan {family}: probing ids {ids.start}-{ids.stop - 1} "
                    f"only, {family} ids are {cls.min_id}-{cls.max_id}; skipped {skipped}"
                )
        scans.append((family, ids))
    log_dir = Path(args.log_dir) if args.log_dir else config.logging.dir
    frame_log = FrameLog(log_dir / f"doctor-{time.strftime('%Y%m%d-%H%M%S')}.asc")
    print(f"mavservo doctor: {path}; every frame sent and heard: {frame_log.path}")
    all_ok = True
    try:
        for index, bus in enumerate(config.can.buses):
            findings, verdicts = diagnose_bus(
                config,
                index,
                frame_log,
                listen_s=args.listen,
                allow_enable=args.allow_enable,
                try_bitrates=not args.no_bitrate_search,
                node_id=args.node_id,
                scans=scans,
            )
            all_ok &= print_bus(findings, verdicts, index, _placer(path, document))
            if findings.open_error is None:
                print_yaml(config, bus.name, findings, verdicts)
    finally:
        frame_log.close()
    return EXIT_OK if all_ok else EXIT_PROBLEMS


def diagnose_bus(
    config: Config,
    index: int,
    frame_log: FrameLog,
    *,
    listen_s: float,
    allow_enable: bool,
    try_bitrates: bool,
    scans: Sequence[tuple[str, range]] = (),
    node_id: int = TOOL_NODE_ID,
) -> tuple[BusFindings, list[Verdict]]:
    """Run the doctor on ``config``'s bus ``index`` (its simulation for ``channel: sim``)."""
    bus = config.can.buses[index]
    servos = [s for s in config.servos if config.bus_of(s).name == bus.name]
    simulator = None
    if bus.channel == SIM_CHANNEL:
        simulator = simulator_factory(config)(bus.name, bus.interface, bus.bitrate)
    # mavlink-can: the autopilot's CAN port, reached through a MAVLink link of the doctor's own
    tunnel = TunnelLink(mavlink_settings(config)) if bus.interface == MAVLINK_CAN else None
    if tunnel is not None:
        tunnel.start()

    def open_request(request: BusRequest) -> OpenedBus:
        if simulator is not None:
            request = dataclasses.replace(request, channel=simulator.path)
        if tunnel is None:
            return open_bus(request)
        # everything the port carries (the autopilot's DroneCAN nodes too), no filter at the
        # autopilot: the doctor looks for whoever is there, not only the configured servos
        options = {"keep_extended": True, **request.options, "filter_at_autopilot": False}
        return open_bus(dataclasses.replace(request, options=options), carrier=tunnel.tunnel)

    doctor = BusDoctor(
        bus,
        servos,
        open_request,
        frame_log.record(index),
        listen_s=listen_s,
        allow_enable=allow_enable,
        try_bitrates=try_bitrates,
        node_id=node_id,
    )
    try:
        findings = doctor.run(scans)
    finally:
        if simulator is not None:
            simulator.stop()
        if tunnel is not None:
            tunnel.stop()
    return findings, judge(findings, servos)


def _placer(path: Path, document: YamlDocument) -> Callable[[Loc], str]:
    """``FILE:LINE: key`` of a key of the config, for the lines that name one."""

    def place(loc: Loc) -> str:
        line = document.line_of(loc)[1]
        return f"{path}:{line}: {format_path(loc)}" if line is not None else format_path(loc)

    return place


def print_bus(
    findings: BusFindings,
    verdicts: list[Verdict],
    index: int = 0,
    place: Callable[[Loc], str] | None = None,
) -> bool:
    """The bus's report; True when the bus and all its servos are as configured. ``index``:
    the bus's place in ``can.buses`` (``place`` turns its key into ``FILE:LINE``)."""
    bus = findings.bus
    print(f"\nbus {bus.name}: {describe_bus(bus)}")
    mode = "listen-only" if findings.listen_only else "normal mode (no listen-only on this adapter)"
    for bitrate, frames in findings.listened.items():
        errors = findings.error_frames.get(bitrate, 0)
        print(
            f"  listened {mode} at {bitrate_text(bitrate)}: {frames} valid frames, "
            f"{errors} error frames"
        )
    for bitrate, why in findings.unsupported.items():
        print(f"  {bitrate_text(bitrate)}: the adapter refused it ({why})")
    ok = True
    rate = findings.working_bitrate
    if findings.open_error is not None:  # the lines `mavservo run` prints for it
        for line in failure_lines(bus_open_error(index, bus, findings.open_error), place):
            print(f"  {line}")
        return False
    if rate is None and bus.interface in BITRATE_SET_OUTSIDE:
        ok = False
        link = bus.channel
        print(
            f"  no valid traffic and no answer; a {bus.interface} bus gets its bitrate outside "
            "python-can, so the doctor cannot try others: for SocketCAN try each (`sudo ip link "
            f"set {link} down; sudo ip link set {link} up type can bitrate 500000`) and run it "
            f"again; `ip -details -statistics link show {link}` shows bus-off and error counters"
        )
    elif rate is None:
        ok = False
        print(
            "  no valid traffic and no answer at any bitrate tried: check power, CAN_H/CAN_L, "
            "a 120 ohm terminator at each end, and that the adapter is on this bus"
        )
    elif rate != bus.bitrate:
        ok = False
        print(
            f"  WRONG BITRATE: nothing at the configured {bitrate_text(bus.bitrate)}, valid "
            f"traffic at {bitrate_text(rate)}; fix: `bitrate: {rate}` for bus {bus.name} "
            f"(or set every node to {bitrate_text(bus.bitrate)})"
        )
    else:
        print(f"  bitrate {bitrate_text(rate)}: valid traffic")
    _print_who(findings)
    for verdict in verdicts:
        servo = verdict.servo
        head = f"  {servo.name:<12} {servo.profile} id {servo.can_id}: "
        if verdict.ok:
            print(head + "OK, " + "; ".join(verdict.notes))
        else:
            ok = False
            print(head + verdict.cause)
            if verdict.fix:
                print(f"  {'':<12} fix: {verdict.fix}")
            for note in verdict.notes:
                print(f"  {'':<12} {note}")
    for entry in extra_entries(findings, verdicts):
        _print_unconfigured(findings, entry)
    if findings.scan_s is not None:
        print(
            f"  probed {findings.scanned} ids in {findings.scan_s:.2f} s "
            f"({findings.sent} requests sent, {findings.enable_sent} enable frames)"
        )
    for motor in findings.left_enabled:
        ok = False
        print(
            f"  WARNING: {motor} was enabled (--allow-enable) and the bus refused its disable "
            "frame every time: it may still be in motor mode; power-cycle it or disable it "
            "before touching it"
        )
    for device, count in sorted(findings.spared.items()):
        print(
            f"  not sent: {count} requests whose id is {device}'s (another family's command "
            "there); scan that family with the device unplugged, or on another bus"
        )
    return ok


def _print_unconfigured(findings: BusFindings, entry: dict[str, Any]) -> None:
    """A motor that answered or was heard but no configured servo explains (a scan found it,
    or it talks on its own): how it was seen and who it said it is, so a scan's result reads
    as fully as a configured servo's (before, its identity reads were sent and not shown)."""
    key = (entry["profile"], entry["can_id"])
    answered = any(
        (s.profile, s.can_id) == key and s.how == "answered" for s in findings.sightings.values()
    )
    how = "answered the doctor's requests" if answered else "heard unasked"
    said = [how]
    identity = findings.identities.get(key)
    if identity is not None:
        said.append(identity)
    print(f"  {'(not configured)':<12} {key[0]} id {key[1]}: " + "; ".join(said))


def _print_who(findings: BusFindings) -> None:
    sightings = list(findings.sightings.values())
    if findings.noisy:  # chance matches of a foreign flood: only what answered is named
        sightings = [s for s in sightings if s.how == "answered"]
        print(
            "  most frames here are no family's: motors only heard (not answering a request) "
            "may be chance matches and are not named or listed below"
        )
    heard = sorted(
        {(s.profile, s.can_id, s.how) for s in sightings},
        key=lambda k: (k[0], k[1]),
    )
    if heard:
        print("  on the bus: " + ", ".join(f"{p} {i} ({how})" for p, i, how in heard))
    for node, beat in sorted(findings.heartbeats.items()):
        errors = ", ".join(beat.error_names) or "no errors"
        print(f"  ODrive node {node}: heartbeat, {beat.state_name}, {errors}")
    for node, status in sorted(findings.node_statuses.items()):
        print(
            f"  DroneCAN node {node}: NodeStatus {status.health}, {status.mode}, "
            f"up {status.uptime_s} s; {findings.node_info_said(node)}"
        )
    if findings.unknown_ids:
        ids = ", ".join(
            f"0x{i:X}{'x' if ext else ''} ({n})"
            for (i, ext), n in findings.unknown_ids.most_common(8)
        )
        more = (
            f"; {findings.unknown_overflow} more of other ids" if findings.unknown_overflow else ""
        )
        print(f"  frames no family reads: {ids}{more}")


def print_yaml(
    config: Config, bus_name: str, findings: BusFindings, verdicts: list[Verdict]
) -> None:
    """The corrected ``servos:`` (and ``can:``, when the bitrate was wrong) of this bus."""
    document: dict[str, Any] = {}
    bus = findings.bus
    if findings.working_bitrate is not None and findings.working_bitrate != bus.bitrate:
        buses = [b.model_dump(mode="json", exclude_unset=True) for b in config.can.buses]
        for entry in buses:
            if entry.get("name", "bus0") == bus_name:
                entry["bitrate"] = findings.working_bitrate
        document["can"] = {"buses": buses}
    document["servos"] = [v.entry for v in verdicts] + extra_entries(findings, verdicts)
    print(f"\n# mavservo doctor: what bus {bus_name} needs (paste into your config)")
    print(yaml.safe_dump(document, sort_keys=False, default_flow_style=None).rstrip())
