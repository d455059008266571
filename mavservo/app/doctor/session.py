"""The doctor's work on one bus: listen, find the bitrate, probe, scan.

What it saw is kept in :class:`.findings.BusFindings`; each received frame is read into them by
:class:`.frame_reader.FrameReader`; before a probe goes out, :class:`.occupants.Occupants` says
whether another device would take it as its own. This module keeps the steps and their timing.

Safe by default: it listens first, listen-only where the adapter has such a mode (AA-55 silent
mode, LAWICEL ``L``, PCAN passive), at the configured bitrate and then at each standard one
until valid traffic is heard; it sends only the profiles' telemetry polls (queries that change
nothing) and the identity reads of :mod:`.families`, and refuses, in :class:`SafeSender`, any
frame a profile would send to start, release or move its motor. ``--allow-enable`` adds the
families' enable frames (each followed by the frame that undoes it), for the motors that answer
nothing else (CubeMars and Robstride in MIT mode).
"""

from __future__ import annotations

import contextlib
import functools
import logging
import time
from collections import defaultdict
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import can

from mavservo.config import BusConfig, ServoConfig
from mavservo.servos import (
    get_node_info_request,
    get_profile,
    release_frames_of,
)
from mavservo.transport import (
    BITRATE_SET_OUTSIDE,
    STANDARD_BITRATES,
    BusRequest,
    OpenedBus,
    has_listen_only,
)

from .families import facts
from .findings import BusFindings
from .frame_reader import FrameReader
from .node_info import ANSWER_WAIT_S, MAX_NODES_ASKED, TOOL_NODE_ID
from .occupants import Occupants
from .recognise import (
    Candidate,
    Recogniser,
    family_variants,
    make_candidate,
    options_key,
)

log = logging.getLogger(__name__)

#: How long the replies to one batch of probes are waited for (a servo answers within ~1 ms;
#: a USB adapter's latency and a loaded host add a few more).
REPLY_WAIT_S = 0.05
#: Sends of a disable frame before a motor is reported left enabled, each after a wait in
#: which a refusing adapter is reopened (the bus wrapper's backoff starts at 0.1 s).
DISABLE_TRIES = 5
DISABLE_RETRY_WAIT_S = 0.25
#: Probes sent before their replies are collected (a scan's batch): at 1 Mbit/s 16 requests
#: and their replies take ~4 ms of bus time, well inside the wait.
BATCH = 16


class UnsafeFrameError(RuntimeError):
    """A frame that would start, release or move a motor, without ``--allow-enable``."""


class SafeSender:
    """Sends the doctor's frames, refusing every frame a profile uses to start, release or
    move a motor (compared whole) unless ``allow_enable``; records all it sends."""

    def __init__(
        self,
        bus: can.BusABC,
        record: Callable[[can.Message, bool], None],
        forbidden: set[tuple[int, bool, bytes]],
    ) -> None:
        self.bus = bus
        self.record = record
        self.forbidden = forbidden
        self.sent = 0

    def send(self, msg: can.Message, *, enabling: bool = False) -> bool:
        if not enabling and _signature(msg) in self.forbidden:
            raise UnsafeFrameError(f"refused: {msg} would start, release or move a motor")
        try:
            self.bus.send(msg, timeout=0.1)
        except can.CanError as exc:
            log.debug("send failed: %s", exc)
            return False
        self.sent += 1
        self.record(msg, False)
        return True


def _signature(msg: can.Message) -> tuple[int, bool, bytes]:
    return (msg.arbitration_id, msg.is_extended_id, bytes(msg.data))


def forbidden_frames(candidates: Iterable[Candidate]) -> set[tuple[int, bool, bytes]]:
    """Every candidate's start-up, release and shutdown frames and a position command (asked
    of a fresh profile: asking may change a profile's state, e.g. a released CubeMars stops
    polling)."""
    out: set[tuple[int, bool, bytes]] = set()
    for candidate in candidates:
        fresh = make_candidate(candidate.profile, candidate.can_id, candidate.raw_options)
        if fresh is None:
            continue
        profile = fresh.instance
        frames: list[can.Message] = []
        releases = functools.partial(release_frames_of, profile)
        for source in (profile.startup_frames, releases, profile.shutdown_frames):
            with contextlib.suppress(Exception):  # a profile that cannot say forbids nothing
                frames += source()
        with contextlib.suppress(Exception):
            frames.append(profile.position_command(0.0))
        out.update(_signature(f) for f in frames)
    return out


class BusDoctor:
    """Diagnoses one bus of a config (see module): owns the bus's findings, the frame reader
    that fills them and the safe sender of each step."""

    def __init__(
        self,
        bus: BusConfig,
        servos: Sequence[ServoConfig],
        open_request: Callable[[BusRequest], OpenedBus],
        record: Callable[[can.Message, bool, int], None],
        *,
        listen_s: float = 1.5,
        allow_enable: bool = False,
        try_bitrates: bool = True,
        node_id: int = TOOL_NODE_ID,
    ) -> None:
        self.bus = bus
        self.servos = list(servos)
        self._open = open_request
        self._record = record
        self.listen_s = listen_s
        self.allow_enable = allow_enable
        self.try_bitrates = try_bitrates
        self.node_id = node_id
        self.findings = BusFindings(bus, has_listen_only(bus.interface))
        if bus.interface in BITRATE_SET_OUTSIDE:
            self.try_bitrates = False  # the link's bitrate is not ours to change
        configured: dict[str, list[Mapping[str, Any]]] = defaultdict(list)
        for servo in self.servos:
            configured[servo.profile].append(servo.options)
            for sibling in facts(servo.profile).siblings:
                configured.setdefault(sibling, [])
        self._families = dict(configured)
        self.recogniser = Recogniser(self._families)
        configured_keys = {(s.profile, s.can_id, options_key(s.options)) for s in self.servos}
        self.reader = FrameReader(self.findings, self.recogniser, configured_keys, node_id)
        self._forbidden = forbidden_frames(self.recogniser.candidates)

    # -- the steps -----------------------------------------------------------------------------

    def run(self, scan: Iterable[tuple[str, Iterable[int]]] = ()) -> BusFindings:
        rates = [self.bus.bitrate] + [r for r in STANDARD_BITRATES if r != self.bus.bitrate]
        if not self.try_bitrates:
            rates = rates[:1]
        for bitrate in rates:
            if self._listen(bitrate):
                self.findings.working_bitrate = bitrate
                break
            if bitrate == self.bus.bitrate and bitrate in self.findings.unsupported:
                # no device, busy, no permission: trying other bitrates would say it 8 times
                self.findings.open_error = self.findings.unsupported.pop(bitrate)
                return self.findings
        if self.findings.working_bitrate is None:
            # nothing pushes on this bus: ask the configured servos, at each rate in turn
            for bitrate in rates:
                if self._probe_servos(bitrate) and self._answered_at(bitrate):
                    self.findings.working_bitrate = bitrate
                    break
        else:
            self._probe_servos(self.findings.working_bitrate)
        bitrate = self.findings.working_bitrate or self.bus.bitrate
        self._scan_for_the_silent(bitrate)
        for profile, ids in scan:
            self.scan(profile, ids, bitrate)
        return self.findings

    def _answered_at(self, bitrate: int) -> bool:
        return any(s.bitrate == bitrate for s in self.findings.sightings.values())

    def _request(self, bitrate: int, listen_only: bool) -> BusRequest:
        options: dict[str, Any] = dict(self.bus.options)
        if self.bus.interface == "aa55":
            options = {
                "serial_baud": self.bus.serial_baud,
                "protocol": self.bus.protocol,
                **options,
            }
        return BusRequest(
            self.bus.name, self.bus.interface, self.bus.channel, bitrate, options, listen_only
        )

    def _opened(self, bitrate: int, listen_only: bool) -> OpenedBus | None:
        try:
            return self._open(self._request(bitrate, listen_only))
        except (can.CanError, ValueError, OSError) as exc:
            self.findings.unsupported[bitrate] = str(exc)
            return None

    def _listen(self, bitrate: int) -> bool:
        """Listen ``listen_s`` at ``bitrate``: True when valid frames were heard."""
        opened = self._opened(bitrate, listen_only=True)
        if opened is None:
            return False
        try:
            valid = self._collect(opened.bus, bitrate, self.listen_s, "heard")
        finally:
            opened.close()
        self.findings.listened[bitrate] = valid
        return valid > 0

    def _collect(
        self,
        bus: can.BusABC,
        bitrate: int,
        seconds: float,
        how: str,
        asked: set[tuple[str, int]] | None = None,
    ) -> int:
        """Receive for ``seconds``; each frame recorded and read. Valid frames counted.
        ``asked``: the motors just sent a request; only they can have ``answered`` it (a
        frame of another, or of a foreign flood that fits some family, was only heard)."""
        valid = 0
        deadline = time.monotonic() + seconds
        for _ in range(200_000):  # bounded: a saturated 1 Mbit/s bus is ~8,000 frames/s
            left = deadline - time.monotonic()
            if left <= 0:
                break
            msg = bus.recv(min(left, 0.05))
            if msg is None:
                continue
            self._record(msg, True, bitrate)
            if msg.is_error_frame:
                self.findings.error_frames[bitrate] = self.findings.error_frames.get(bitrate, 0) + 1
                continue
            valid += 1
            self.reader.read(msg, bitrate, how, asked)
        return valid

    def _probe_servos(self, bitrate: int) -> bool:
        """Ask every configured servo (and its other modes at its id) what the profiles
        allow; False when the adapter would not open at ``bitrate``."""
        probes: list[Candidate] = []
        for servo in self.servos:
            for profile in (servo.profile, *facts(servo.profile).siblings):
                configured = [servo.options] if profile == servo.profile else []
                for options in family_variants(profile, configured):
                    candidate = make_candidate(profile, servo.can_id, options)
                    if candidate is not None:
                        probes.append(candidate)
        opened = self._opened(bitrate, listen_only=False)
        if opened is None:
            return False
        self.findings.probed_bitrates.append(bitrate)
        configured_ids = {(s.profile, s.can_id) for s in self.servos}
        try:
            # a sibling's identity reads are not sent to a servo configured as another family
            # (LK-Tech's document was not checked for MyActuator's 0xB2/0xB5)
            self._probe(
                opened,
                probes,
                bitrate,
                identity=lambda c: True if (c.profile, c.can_id) in configured_ids else None,
            )
            self._ask_node_info(opened, bitrate)
        finally:
            opened.close()
        return True

    def _ask_node_info(self, opened: OpenedBus, bitrate: int) -> None:
        """GetNodeInfo to each DroneCAN node heard by its NodeStatus and not yet asked (a
        request changes nothing on a node: the specification's GetNodeInfo), from the
        doctor's own node id; not at all when a node on the bus has that id."""
        heard = sorted(set(self.findings.node_statuses) - self.findings.node_info_asked)
        if not heard:
            return
        if self.node_id in self.findings.node_statuses:
            self.findings.node_info_skipped = (
                f"GetNodeInfo not asked: node id {self.node_id}, the doctor's, is taken on this "
                "bus (pass --node-id with a free one)"
            )
            return
        sender = SafeSender(
            opened.bus, lambda msg, rx: self._record(msg, rx, bitrate), self._forbidden
        )
        occupants = Occupants(self.servos, self.findings)
        for node in heard[:MAX_NODES_ASKED]:
            frames = get_node_info_request(node, self.node_id, transfer_id=0)
            owner = occupants.owner("dronecan", frames)
            if owner is not None:
                self.findings.spared[owner] += 1
                continue
            self.findings.node_info_asked.add(node)
            for frame in frames:
                sender.send(frame)
        self._collect(opened.bus, bitrate, ANSWER_WAIT_S, "heard", set())
        self.findings.sent += sender.sent

    def _probe(
        self,
        opened: OpenedBus,
        probes: Sequence[Candidate],
        bitrate: int,
        *,
        identity: Callable[[Candidate], bool | None] = lambda candidate: True,
    ) -> None:
        """Send ``probes`` their safe requests (``identity(candidate)``: whether its identity
        reads go too, see :func:`safe_requests`) in batches, and read the answers."""
        forbidden = self._forbidden | forbidden_frames(probes)
        sender = SafeSender(opened.bus, lambda msg, rx: self._record(msg, rx, bitrate), forbidden)
        frames: list[can.Message] = []
        askers: dict[tuple[int, bool, bytes], set[tuple[str, int]]] = {}
        occupants = Occupants(self.servos, self.findings)
        for candidate in probes:  # two modes often share a read (the same frame): sent once
            for msg in safe_requests(candidate, forbidden, identity=identity(candidate)):
                owner = occupants.owner(candidate.profile, [msg])
                if owner is not None:
                    self.findings.spared[owner] += 1
                    continue
                signature = _signature(msg)
                if signature not in askers:
                    askers[signature] = set()
                    frames.append(msg)
                askers[signature].add((candidate.profile, candidate.can_id))
        for start in range(0, len(frames), BATCH):
            asked: set[tuple[str, int]] = set()
            for msg in frames[start : start + BATCH]:
                sender.send(msg)
                asked |= askers[_signature(msg)]
            self._collect(opened.bus, bitrate, REPLY_WAIT_S, "answered", asked)
        if self.allow_enable:
            self._enable_probes(sender, opened, probes, bitrate)
        self.findings.sent += sender.sent

    def _enable_probes(
        self, sender: SafeSender, opened: OpenedBus, probes: Sequence[Candidate], bitrate: int
    ) -> None:
        """``--allow-enable``: the silent ones that answer only when enabled, enabled once
        and disabled again at once."""
        found = {(s.profile, s.can_id) for s in self.findings.sightings.values()}
        occupants = Occupants(self.servos, self.findings)
        for candidate in probes:
            enable = facts(candidate.profile).enable
            if enable is None or (candidate.profile, candidate.can_id) in found:
                continue
            on, off = enable(candidate.can_id, candidate.raw_options)
            owner = next((o for m in on if (o := occupants.owner(candidate.profile, [m]))), None)
            if owner is not None:
                self.findings.spared[owner] += len(on)
                continue
            asked = {(candidate.profile, candidate.can_id)}
            try:
                for msg in on:
                    sender.send(msg, enabling=True)
                    self.findings.enable_sent += 1
                self._collect(opened.bus, bitrate, REPLY_WAIT_S, "answered", asked)
            finally:  # Ctrl-C while it listens still disables it
                self._disable(sender, opened, bitrate, candidate, off)
            self._collect(opened.bus, bitrate, REPLY_WAIT_S / 2, "answered", asked)

    def _disable(
        self,
        sender: SafeSender,
        opened: OpenedBus,
        bitrate: int,
        candidate: Candidate,
        off: Sequence[can.Message],
    ) -> None:
        """Send the frames that undo an enable: a motor left in motor mode after the doctor
        is gone is the one thing ``--allow-enable`` must never cause. Each is tried again
        after a wait in which a refusing adapter is reopened (from the receive path)."""
        for msg in off:
            for _ in range(DISABLE_TRIES):
                if sender.send(msg, enabling=True):
                    break
                self._collect(opened.bus, bitrate, DISABLE_RETRY_WAIT_S, "heard")
            else:
                self.findings.left_enabled.append(f"{candidate.profile} {candidate.can_id}")

    def _silent(self) -> list[ServoConfig]:
        found = {(s.profile, s.can_id) for s in self.findings.sightings.values()}
        return [s for s in self.servos if (s.profile, s.can_id) not in found]

    def _scan_for_the_silent(self, bitrate: int) -> None:
        """A configured servo that said nothing: its family's whole id range (a motor that
        answers on another id is the commonest wiring mistake after the bitrate)."""
        families = sorted({s.profile for s in self._silent()})
        for profile in families:
            cls = get_profile(profile)
            self.scan(profile, range(cls.min_id, cls.max_id + 1), bitrate)

    def scan(self, profile: str, ids: Iterable[int], bitrate: int) -> None:
        """Probe ``profile`` at every id of ``ids`` (its modes too), safe requests only."""
        configured = [s.options for s in self.servos if s.profile == profile]
        probes = [
            c
            for options in family_variants(profile, configured)
            for can_id in ids
            if (c := make_candidate(profile, can_id, options)) is not None
        ]
        forbidden = self._forbidden | forbidden_frames(probes)
        if not any(safe_requests(c, forbidden) for c in probes):
            return  # a family that answers nothing safe (MIT mode): listening said all
        opened = self._opened(bitrate, listen_only=False)
        if opened is None:
            return
        started = time.monotonic()
        try:
            # the polls find a motor (a family no poll reaches, Robstride, is found by its
            # identity read); only the ids that answered are asked who they are: an RMD-X's
            # two identity reads on every id would triple a scan's time
            self._probe(opened, probes, bitrate, identity=lambda candidate: None)
            answered = {
                (s.can_id, options_key(s.options))
                for s in self.findings.sightings.values()
                if s.profile == profile and s.how == "answered"
            }
            found = [c for c in probes if (c.can_id, options_key(c.raw_options)) in answered]
            if found and any(facts(profile).identity(c.can_id, c.raw_options) for c in found):
                self._probe(opened, found, bitrate)
        finally:
            opened.close()
        self.findings.scan_s = (self.findings.scan_s or 0.0) + time.monotonic() - started
        self.findings.scanned += len(probes)


def safe_requests(
    candidate: Candidate,
    forbidden: set[tuple[int, bool, bytes]],
    *,
    identity: bool | None = True,
) -> list[can.Message]:
    """The telemetry polls of the profile (queries, ``ServoProfile.telemetry_requests``) and
    the family's identity reads (``identity``: True always, None only when no poll is safe),
    less any frame that starts, releases or moves a motor: a family whose poll is its enable
    (CubeMars MIT mode polls with enter-motor-mode) is not polled."""
    try:
        polls = list(candidate.instance.telemetry_requests())
    except Exception:  # noqa: BLE001 - a profile that cannot poll is not polled
        polls = []
    frames = [f for f in polls if _signature(f) not in forbidden]
    if identity or (identity is None and not frames):
        reads = facts(candidate.profile).identity(candidate.can_id, candidate.raw_options)
        frames += [f for f in reads if _signature(f) not in forbidden]
    return frames
