"""The MAVLink side's decisions, without sockets or threads.

:class:`MavlinkCore` takes received messages and the passing of time, and returns what each hosted
component must send. Everything that touches the network (connection, encoders, signing,
threads) is in :mod:`mavservo.mavlink.link` and :mod:`mavservo.mavlink.side`; keeping the core
pure makes the addressing, arbitration and failsafe rules testable without timing.

System id: with ``system_id: follow`` the bridge takes the system id of the first HEARTBEAT from a
vehicle component numbered like the configured autopilot component (not a GCS), and watches that
autopilot for failsafe; until then it uses the configured autopilot system id. A fixed id is used
as is, and the configured autopilot (system, component) is watched.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Mapping, Sequence, Sized
from typing import Any, TypeVar

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.mavlink.answers import Answer, AnswerQueue
from mavservo.mavlink.arbitration import CommandHold
from mavservo.mavlink.autopilot_flavour import MSG_COMPONENT_METADATA, AutopilotFlavour
from mavservo.mavlink.backend import ActuatorBackend
from mavservo.mavlink.bandwidth import BudgetPlan, LinkBudget, plan_budget
from mavservo.mavlink.commands import (
    REFUSAL_LOG_INTERVAL_S,
    Command,
    CommandHandler,
    Outgoing,
    RateLimitedLog,
)
from mavservo.mavlink.component import (
    MAV_TYPE_GIMBAL,
    MAV_TYPE_SERVO,
    CountingComponent,
    DemandHolder,
    HostedComponent,
)
from mavservo.mavlink.failsafe import (
    LOST_TEXT,
    RECOVERED_TEXT,
    FailsafeEvent,
    HeartbeatWatchdog,
)
from mavservo.mavlink.ftp import UNBUDGETED_BYTES_S, chunk_for_budget
from mavservo.mavlink.gimbal import GimbalDevice
from mavservo.mavlink.gimbal_discovery import GimbalDiscoveryWatch, log_hint
from mavservo.mavlink.link_carriage import LinkCarriage
from mavservo.mavlink.metadata_service import MetadataService
from mavservo.mavlink.mirror import Mirror
from mavservo.mavlink.origin import Requester, describe, from_pinned, origin_of, requester_of
from mavservo.mavlink.params import (
    SERVICE_TYPES,
    ParameterOwner,
    ParameterServer,
    SetResult,
    WritePolicy,
)
from mavservo.mavlink.settings import FOLLOW, MavlinkSettings, TelemetryRates
from mavservo.mavlink.stream_request import StreamRequester, set_message_interval
from mavservo.mavlink.telemetry import (
    ESC_MESSAGES,
    MAV_SEVERITY_CRITICAL,
    MAV_SEVERITY_NOTICE,
    MAV_SEVERITY_WARNING,
    Telemetry,
)

log = logging.getLogger(__name__)

_T = TypeVar("_T")
"""What one part of the tick returns a sequence of (see :meth:`MavlinkCore._guarded`)."""

MAV_TYPE_GCS = 6
MAV_AUTOPILOT_INVALID = 8
MAV_STATE_ACTIVE = 4
MAV_STATE_CRITICAL = 5
HEARTBEAT_PERIOD_S = 1.0
#: At most one STATUSTEXT per this many seconds per identity claimed from a second address.
CLAIM_NOTICE_S = 10.0
#: The part of the link bucket's depth a queued COMMAND_ACK leaves for the bridge's own events
#: (other answers leave half): an ACK is tiny and a client waits for it (issue 38, item 2).
ACK_KEEP_SHARE = 0.25
COMMAND_TYPES = ("COMMAND_LONG", "COMMAND_INT")
PARAM_LIST = "PARAM_REQUEST_LIST"
MIRROR_TYPES = ("SERVO_OUTPUT_RAW", "ACTUATOR_OUTPUT_STATUS")
#: ESC_TELEMETRY_1_TO_4 .. 29_TO_32 by message name -> group (0 = 1_TO_4)
ESC_TELEMETRY_TYPES = {cls.msgname: group for group, cls in enumerate(ESC_MESSAGES)}


class MavlinkCore:
    """Routes messages to the command handler, the mirror, the gimbal devices and the watchdog."""

    def __init__(
        self,
        settings: MavlinkSettings,
        backend: ActuatorBackend,
        gimbals: Sequence[HostedComponent] = (),
        boot_time: float = 0.0,
        parameters: ParameterOwner | None = None,
        metadata_files: Mapping[int, Mapping[str, bytes]] | None = None,
    ) -> None:
        self.settings = settings
        self.backend = backend
        self.gimbals = {g.component_id: g for g in gimbals}
        if settings.servo_component_id in self.gimbals:
            raise ValueError("a gimbal uses the servo component id")
        self.components: dict[int, int] = {settings.servo_component_id: MAV_TYPE_SERVO}
        self.components.update({cid: MAV_TYPE_GIMBAL for cid in self.gimbals})
        following = settings.system_id == FOLLOW
        self._system_id = settings.autopilot_system if following else int(settings.system_id)
        self._system_id_known = not following
        self.watched = (settings.autopilot_system, settings.autopilot_component)
        self.hold = CommandHold(settings.command_hold_s)
        #: ArduPilot or PX4 (px4: issue 39): configured, or from the autopilot's HEARTBEAT
        self.flavour = AutopilotFlavour(settings.autopilot_flavour)
        #: what the autopilot link carries for that autopilot (px4: issue 38 item 5)
        self.carriage = LinkCarriage(settings.autopilot_link, self.flavour)
        self.mirror = Mirror(
            backend, settings, self.hold, lambda: self.flavour.facts.active_is_count
        )
        self.telemetry = Telemetry(backend, settings.telemetry, boot_time)
        self.watchdog = HeartbeatWatchdog(settings.heartbeat_timeout_s)
        self.streams = StreamRequester(settings.stream_request, settings.heartbeat_timeout_s)
        self.streams.set_flavour(self.flavour.facts, boot_time)
        self.commands = CommandHandler(
            backend=backend,
            settings=settings,
            hold=self.hold,
            system_id=lambda: self._system_id,
            request_message=self.telemetry.request,
            set_interval=self._set_interval,
            heartbeat=lambda cid: self._heartbeat_message(self.components[cid]),
            gimbals=self.gimbals,
            component_metadata=self._component_metadata,
        )
        #: a hosted gimbal the autopilot never looks for is said, with the fix (issue 30); not
        #: one that is its own gimbal manager (a ground station drives it directly, issue 38)
        self.discovery = GimbalDiscoveryWatch(
            cid for cid, gimbal in self.gimbals.items() if not _own_manager(gimbal)
        )
        self._now = boot_time
        self._next_heartbeat = {cid: boot_time for cid in self.components}
        self.counters: Counter[str] = Counter()
        self._problem_log = RateLimitedLog(REFUSAL_LOG_INTERVAL_S)
        self._claim_notice = RateLimitedLog(CLAIM_NOTICE_S)
        #: what of the periodic telemetry also goes on the autopilot link (monitors get all)
        self.budget = LinkBudget(self._plan(settings.telemetry))
        self._gimbal_hz = settings.telemetry.gimbal_attitude_status_hz
        #: answers to requests (parameters, FTP, missions), per requester, paced
        self.answers = AnswerQueue()
        #: responses to unverified senders' commands, per sender, in turn: their ACKs in a
        #: lane of their own, served before any answer, then the messages they asked for
        self.acks = AnswerQueue()
        self.responses = AnswerQueue()
        self._ftp_first = False
        #: parameters, and a prompt "not supported" to FTP and mission requests, on every
        #: component (without an owner the components serve no parameters but still answer)
        self.parameters = ParameterServer(
            parameters or _NoParameters(),
            self.components,
            signing=settings.signing is not None,
            announce=lambda text: self.telemetry.announce(MAV_SEVERITY_WARNING, text),
            writers=WritePolicy(
                settings.allowed_sources, open=settings.parameter_writers == "anyone"
            ),
        )
        #: COMPONENT_METADATA and a read-only MAVLink FTP server per component (the metadata
        #: files the app built); its answers take the event share of the link budget
        budget = settings.link_budget_bytes_s
        self.metadata = MetadataService(
            self.components,
            metadata_files or {},
            # with a budget, the budget's answers share paces the replies (the window of the
            # whole budget is only a second bound); 10 % of it (before) let a 239-byte reply
            # out 1.2-7 s after its request, past every client's time-out (issue 38)
            bytes_per_s=UNBUDGETED_BYTES_S if budget is None else budget,
            boot_time=boot_time,
            chunk_bytes=chunk_for_budget(budget),
        )

    @property
    def system_id(self) -> int:
        return self._system_id

    # ------------------------------------------------------------------ input

    def on_message(self, msg: Any, now: float) -> list[Outgoing]:
        """One received message (already signature-checked by the link)."""
        self._now = now
        kind = msg.get_type()
        if kind == "BAD_DATA":
            self.counters["bad_data"] += 1
            return []
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        if source[0] == self._system_id and source[1] in self.components:
            return []  # our own traffic echoed back by a router
        self.counters["received"] += 1
        if self._claimed_elsewhere(msg, source, now):
            return []
        if source == self.watched:
            for text in self.discovery.on_autopilot_message(msg, now):
                log.info("%s", text)
                self.telemetry.announce(MAV_SEVERITY_NOTICE, text)
        if kind in ESC_TELEMETRY_TYPES and source[0] == self._system_id:
            self._heard_esc(kind, source)
        if kind == "HEARTBEAT":
            return self._heartbeat(msg, source, now)
        from_autopilot = source == self.watched
        if from_autopilot:
            restarts = self.streams.autopilot_restarts
            self.streams.on_message(msg, now)
            if self.streams.autopilot_restarts != restarts:  # its boot time went back
                self._forget_gimbal_demands()
            if kind == "COMMAND_ACK" and self._acks_our_request(msg):
                self.streams.on_ack(msg.command, msg.result, now)
                return []
        if from_autopilot and kind in MIRROR_TYPES:
            if self.watchdog.in_failsafe:
                self.counters["mirror_ignored_in_failsafe"] += 1
            else:
                self.mirror.handle(msg, now)
            return []
        if not from_autopilot and not self._source_allowed(source):
            self.counters["rejected_source"] += 1
            self._log_rejected_source(kind, source, now)
            return []
        if kind in COMMAND_TYPES:
            return self.commands.handle(Command.from_message(msg), now)
        if kind == "FILE_TRANSFER_PROTOCOL":
            self._ftp(msg, source, now)
            return []
        if kind in SERVICE_TYPES:
            answers = self.parameters.handle(msg, self._system_id, source, now)
            # a list asked again replaces what is still queued of it (per component)
            tag = ("list", getattr(msg, "target_component", 0)) if kind == PARAM_LIST else None
            self.answers.put(requester_of(msg), answers, now, tag)
            return []
        self._to_gimbals(msg, now)
        return []

    def _ftp(self, msg: Any, source: tuple[int, int], now: float) -> None:
        """A MAVLink FTP request: to the addressed component's server (never a broadcast: one
        request must not make every component answer). On a signed link only signed frames."""
        if self.settings.signing is not None and not getattr(msg, "_signed", False):
            self.counters["ftp_unsigned_refused"] += 1
            return
        if msg.target_system not in (0, self._system_id) or msg.target_component == 0:
            return
        self.metadata.handle(msg, msg.target_component, requester_of(msg), now)

    def answers_due(self, now: float) -> list[Answer]:
        """Answers to requests that may go now: each to its requester only, paced per
        requester, within the link budget (:class:`~mavservo.mavlink.answers.AnswerQueue`).

        Order: the COMMAND_ACKs of queued command responses first (an ACK never waits behind
        answers, its own requested message included: a ground station asking for a message 5
        times a second got 63 of 182 ACKs later than 300 ms when the ACK waited behind the
        requested messages; issue 38), then the other queued responses (the messages asked
        for), then the services' answers (FTP replies and parameter answers, which of the two
        goes first alternates per tick so neither starves the other). While an answer waits
        for the budget, periodic telemetry leaves it the tokens (see
        :meth:`~mavservo.mavlink.bandwidth.LinkBudget.admit_answer`)."""
        self.budget.answers_round()

        def admit(cid: int, msg: Any, awaited: bool = True) -> bool:
            return self.budget.admit_answer(cid, msg, now, awaited=awaited)

        def ftp_due(t: float) -> list[Answer]:
            return self.metadata.due(t, admit)

        def admit_ack(cid: int, msg: Any) -> bool:
            return self.budget.admit_answer(cid, msg, now, keep_share=ACK_KEEP_SHARE)

        acks = self.acks.due(now, admit_ack)
        responses = self.responses.due(now, admit)
        self._ftp_first = not self._ftp_first
        if self._ftp_first:
            ftp = self._guarded("metadata", ftp_due, now)
            services = [*ftp, *self.answers.due(now, admit)]
        else:
            params = self.answers.due(now, admit)
            ftp = self._guarded("metadata", ftp_due, now)
            services = [*params, *ftp]
        return [*acks, *responses, *services]

    def queue_responses(self, source: Requester, out: list[Outgoing], now: float) -> None:
        """Responses to a command from an unverified sender (its ACK, the messages it asked
        for): to that sender only, in turn with the other requesters, not ahead of everyone.

        Why (review3): sent at once to every peer, a stranger's REQUEST_MESSAGE flood (1,000/s
        for COMPONENT_METADATA) filled the held events with its ACKs and answers: 11,654
        events dropped in 7 s, and a ground station got 1 of 30 ACKs of its DO_SET_SERVO (all
        30 applied). Queued per requester, the flood waits for its own turn.

        The ACK goes to its own lane, served first; a request repeated before its answers went
        is answered once: what is still queued for the same command (its ACK) and the same
        requested message type replaces the older copy instead of doubling the queue (issue
        38: QGroundControl and MAVSDK retry a command after their ACK timeout)."""
        self.counters["responses_queued"] += len(out)
        asked: list[Outgoing] = []
        for component_id, msg in out:
            if msg.get_type() == "COMMAND_ACK":  # the same command with the same outcome
                tag = ("ack", component_id, msg.command, msg.result)
                self.acks.put(source, [(component_id, msg)], now, tag)
            else:
                asked.append((component_id, msg))
        if asked:  # the messages one request asked for, replaced as a whole by a repeat
            kinds = tuple(sorted({(cid, msg.get_type()) for cid, msg in asked}))
            self.responses.put(source, asked, now, ("asked", kinds))

    def set_telemetry_rates(self, rates: TelemetryRates, now: float) -> None:
        """New telemetry rates (TEL_*_HZ parameters): in force at once, the budget re-planned."""
        self.telemetry.set_rates(rates, now)
        self._gimbal_hz = rates.gimbal_attitude_status_hz
        self.replan(now)

    def _set_interval(self, msg_id: int, interval_us: float) -> bool | str:
        """SET_MESSAGE_INTERVAL from a peer: the stream's new rate, and the budget re-planned
        (before: planned once at start, so TEL_*_HZ raised took the link from 952 to 21,688
        B/s; issue 32, finding 3); a rate faster than the configured one is refused with the
        reason (a stranger's 1 us starved every other stream: Telemetry.interval_refusal)."""
        refusal = self.telemetry.interval_refusal(msg_id, interval_us)
        if refusal is not None:
            self.counters["interval_refused"] += 1
            return refusal
        before = self.telemetry.rates_hz()
        accepted = self.telemetry.set_interval(msg_id, interval_us, self._now)
        if accepted and self.telemetry.rates_hz() != before:
            # only a change re-plans (issue 40: 250 spoofed ids repeating the configured
            # rates re-planned 167 times a second and the gimbal status fell to 4 Hz)
            self.replan(self._now)
        return accepted

    def replan(self, now: float) -> None:
        """The link budget's plan for the rates in force now (the bucket stays as it is)."""
        hz = self.telemetry.rates_hz()
        rates = TelemetryRates(
            actuator_output_status_hz=hz.get("actuator_output_status_hz", 0.0),
            esc_telemetry_hz=hz.get("esc_telemetry_hz", 0.0),
            named_value_float_hz=hz.get("named_value_float_hz", 0.0),
            gimbal_attitude_status_hz=self._gimbal_hz,
        )
        self.budget.replan(self._plan(rates), now)

    def _plan(self, rates: TelemetryRates) -> BudgetPlan:
        return plan_budget(
            self.settings.link_budget_bytes_s,
            servos=_safe_len(self.backend.servo_statuses),
            gimbals=len(self.gimbals),
            health_names=_safe_len(self.backend.health),
            components=len(self.components),
            rates=rates,
            signed=self.settings.signing is not None,
            manager_status_hz=sum(
                g.settings.manager_status_rate_hz
                for g in self.gimbals.values()
                if isinstance(g, GimbalDevice) and _own_manager(g)
            ),
            left_out=self.carriage.left_out_streams(),
        )

    def _acks_our_request(self, msg: Any) -> bool:
        """An ACK of our own SET_MESSAGE_INTERVAL (sent from the servo component)."""
        return (
            msg.command == mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL
            and msg.target_system in (0, self._system_id)
            and msg.target_component in (0, self.settings.servo_component_id)
        )

    def _log_rejected_source(self, kind: str, source: tuple[int, int], now: float) -> None:
        """One line per ``REFUSAL_LOG_INTERVAL_S`` for the whole kind, not one per message.

        Why: on an unsigned link anyone can spoof a known message from a source not allowed;
        a line per message was a log flood an attacker controlled (500 spoofed commands, 500
        lines). Every one is still counted in ``rejected_source``; the line says how many
        were kept quiet since the last one. One kind for every message type, so cycling
        through message types buys no more lines."""
        quiet = self._problem_log.quiet_since_last("rejected_source", now)
        if quiet is None:
            return
        log.warning(
            "message %s from %s rejected: not in allowed_sources%s",
            kind,
            source,
            f" ({quiet} more rejected since the last line, counted in rejected_source)"
            if quiet
            else " (repeats counted in rejected_source, one line a second at most)",
        )

    def _heard_esc(self, kind: str, source: tuple[int, int]) -> None:
        """Another component of this vehicle publishes ESC telemetry: the autopilot (for its
        motors) or another bridge. The autopilot, and a bridge with a lower component id, keep
        their ESC numbers; this bridge moves (or warns)."""
        group = ESC_TELEMETRY_TYPES[kind]
        yield_to = source == self.watched or source[1] < self.settings.servo_component_id
        self.telemetry.heard_esc(source, group, yield_to=yield_to)

    def _claimed_elsewhere(self, msg: Any, source: tuple[int, int], now: float) -> bool:
        """True for an unsigned frame claiming a privileged identity (the watched autopilot,
        an allowed source) from another address or connection than the one it is pinned to
        (the link tags it, :mod:`.origin`): refused whole, counted (``claims_refused``), said
        in a STATUSTEXT naming that address at most every :data:`CLAIM_NOTICE_S` per identity.

        Why (issue 40): on an unsigned link a stranger claiming 255/190 from another address
        set SRV1_TRIM (2 of 2 applied) and its set flood took the station's set budget; its
        spoofed autopilot HEARTBEATs kept the bridge out of failsafe while the real autopilot
        was cut off. Only signing authenticates; this keeps a claim to the place it was
        first heard from (until that place falls silent: ``link.PIN_REBIND_S``)."""
        if from_pinned(msg) or getattr(msg, "_signed", False):
            return False
        self.counters["claims_refused"] += 1
        name = f"{source[0]}/{source[1]}"
        if self._claim_notice.quiet_since_last(name, now) is not None:
            self.telemetry.announce(
                MAV_SEVERITY_WARNING,
                f"servo bridge: {name} claimed from {describe(origin_of(msg))}, not its "
                "pinned address: refused (unsigned link)",
            )
        return True

    def _source_allowed(self, source: tuple[int, int]) -> bool:
        allowed = self.settings.allowed_sources
        return not allowed or source in allowed

    def _heartbeat(self, msg: Any, source: tuple[int, int], now: float) -> list[Outgoing]:
        if (
            not self._system_id_known
            and source[1] == self.settings.autopilot_component
            and msg.type != MAV_TYPE_GCS
            and msg.autopilot != MAV_AUTOPILOT_INVALID
        ):
            self._system_id = source[0]
            self._system_id_known = True
            self.watched = source
            log.info("following autopilot system id %d", source[0])
        if source == self.watched:
            if self.flavour.on_heartbeat(msg.autopilot):
                self._flavour_changed(now)
            self.streams.on_heartbeat(source, now)
        if source == self.watched and self.watchdog.heartbeat(now) is FailsafeEvent.RECOVERED:
            self.backend.leave_failsafe(now)
            self.mirror.reset()
            self.hold.release_all()
            self.telemetry.announce(MAV_SEVERITY_NOTICE, RECOVERED_TEXT, essential=True)
        self._to_gimbals(msg, now)
        return []

    def _flavour_changed(self, now: float) -> None:
        """The autopilot's flavour is known (or changed): what is asked of it and what the
        link carries follow it (px4: issue 39)."""
        self.streams.set_flavour(self.flavour.facts, now)
        self.replan(now)
        held = self.carriage.held_names()
        if held:
            log.info(
                "not sending %s on the autopilot link: %s drops them (mavlink.autopilot.link: "
                "router if a router or the ground station is at the other end; docs/px4.md)",
                ", ".join(held),
                self.flavour.facts.name,
            )

    def _forget_gimbal_demands(self) -> None:
        """The autopilot was lost or rebooted: each gimbal drops its demand (px4: issue 39;
        :meth:`~mavservo.mavlink.gimbal.GimbalDevice.forget_demand`)."""
        for device in self.gimbals.values():
            if isinstance(device, DemandHolder):
                device.forget_demand()
        self.counters["gimbal_demands_forgotten"] += 1

    def _component_metadata(self, component_id: int) -> Any | None:
        """COMPONENT_METADATA of a component, None (UNSUPPORTED) when the link cannot carry
        it: ArduPilot drops message 397, a ground station behind it would wait in vain."""
        if not self.carriage.carries(MSG_COMPONENT_METADATA):
            self.counters["metadata_not_carried"] += 1
            return None
        return self.metadata.component_metadata(component_id, self._now)

    def link_carries(self, msg: Any) -> bool:
        """Whether ``msg`` goes on the autopilot link (:mod:`.link_carriage`); the monitor
        outputs get it either way."""
        return self.carriage.carries(msg.get_msgId())

    def _to_gimbals(self, msg: Any, now: float) -> None:
        """Deliver a message to each gimbal it is addressed to (or broadcast to)."""
        target_system = getattr(msg, "target_system", 0)
        target_component = getattr(msg, "target_component", 0)
        if target_system not in (0, self._system_id):
            return
        for cid, device in self.gimbals.items():
            if target_component in (0, cid):
                device.handle_message(msg, now)

    # ------------------------------------------------------------------ time

    def tick(self, now: float, read_until: float | None = None) -> list[Outgoing]:
        """Everything due at ``now``: failsafe, repeats, heartbeats, telemetry, gimbal status
        (``read_until``: how far the link has read, for the failsafe: see
        :meth:`~.failsafe.HeartbeatWatchdog.check`)."""
        self._now = now
        out: list[Outgoing] = []
        if self.watchdog.check(now, read_until) is FailsafeEvent.LOST:
            self.counters["failsafe_entered"] += 1
            self.commands.cancel_all()
            self.backend.enter_failsafe("autopilot heartbeat lost", now)
            self._forget_gimbal_demands()
            self.discovery.lost_autopilot()
            self.telemetry.announce(MAV_SEVERITY_CRITICAL, LOST_TEXT, essential=True)
        if not self.watchdog.in_failsafe:
            self._guarded("commands", self.commands.tick, now)
            for gimbal, text in self.discovery.due(now):
                self.counters["gimbal_not_found"] += 1
                log.warning("%s (%s)", text, log_hint(gimbal, self.discovery.flavour or ""))
                self.telemetry.announce(MAV_SEVERITY_WARNING, text)
        for cid, mav_type in self.components.items():
            if now >= self._next_heartbeat[cid]:
                self._next_heartbeat[cid] = max(self._next_heartbeat[cid] + HEARTBEAT_PERIOD_S, now)
                out.append((cid, self._heartbeat_message(mav_type)))
        servo = self.settings.servo_component_id
        out.extend((servo, m) for m in self._guarded("streams", self._stream_requests, now))
        out.extend((servo, m) for m in self._guarded("telemetry", self.telemetry.periodic, now))
        out.extend(self._guarded("parameters", self.parameters.periodic, now))
        for cid, device in self.gimbals.items():
            out.extend((cid, m) for m in self._guarded(f"gimbal {cid}", device.periodic, now))
        return out

    def _stream_requests(self, now: float) -> list[Any]:
        """SET_MESSAGE_INTERVAL commands due now (sent from the servo component)."""
        return [set_message_interval(*request) for request in self.streams.tick(now)]

    def _guarded(
        self, part: str, step: Callable[[float], Sequence[_T] | None], now: float
    ) -> Sequence[_T]:
        """Run one part of the tick; an exception there costs only that part's output.

        The tick thread is the only source of heartbeats: a NaN one servo reported once killed
        it for good while the bridge still looked online. The first failure of each part is
        logged with its traceback, every one is counted (``tick_errors``).
        """
        try:
            result = step(now)
        except Exception:  # noqa: BLE001 - whatever fails, the other parts must go on
            self.counters["tick_errors"] += 1
            key = f"tick_errors {part}"
            if not self.counters[key]:
                log.exception("MAVLink tick: %s failed (logged once, counted in tick_errors)", part)
            self.counters[key] += 1
            return []
        return [] if result is None else result

    def announce(self, severity: int, text: str) -> None:
        """Queue a STATUSTEXT from the servo component (link events from the I/O layer)."""
        self.telemetry.announce(severity, text)

    def _heartbeat_message(self, mav_type: int) -> Any:
        state = MAV_STATE_CRITICAL if self.watchdog.in_failsafe else MAV_STATE_ACTIVE
        return mavlink2.MAVLink_heartbeat_message(mav_type, MAV_AUTOPILOT_INVALID, 0, 0, state, 3)

    def stats(self) -> dict[str, Any]:
        """Counters for the bridge's summary."""
        return {
            "system_id": self._system_id,
            "core": dict(self.counters),
            "commands": dict(self.commands.counters),
            "mirror": dict(self.mirror.counters),
            "mirror_held_by_command": self.hold.mirror_suppressed,
            "telemetry": dict(self.telemetry.counters),
            "parameters": dict(self.parameters.counters),
            "ftp": self.metadata.stats(),
            "answers": dict(self.answers.counters),
            "responses": dict(self.responses.counters),
            "acks": dict(self.acks.counters),
            "failsafe_count": self.watchdog.failsafe_count,
            "failsafe_deferred": self.watchdog.deferred,
            "in_failsafe": self.watchdog.in_failsafe,
            "gimbals": self._gimbal_counters(),
            "stream": self.streams.stats(),
            "gimbal_discovery": self.discovery.stats(),
            "autopilot_flavour": self.flavour.stats(),
        }

    def _gimbal_counters(self) -> dict[str, dict[str, int]]:
        """Each hosted gimbal's counters (``bad_value``, ``denied_control``, ...) by component
        id, so they reach the summary and ``metrics.json`` like the command counters: a flood
        of hostile gimbal values was DENIED and counted, but the count stayed in the device."""
        out: dict[str, dict[str, int]] = {}
        for cid, device in self.gimbals.items():
            if isinstance(device, CountingComponent):
                out[str(cid)] = device.counter_values()
        return out


class _NoParameters:
    """The owner of a bridge built without parameters: every component serves none."""

    def names(self, component_id: int) -> list[str]:
        return []

    def value(self, name: str) -> float:
        raise KeyError(name)

    def set(self, name: str, value: float, sender: tuple[int, int]) -> SetResult:
        raise KeyError(name)


def _own_manager(gimbal: HostedComponent) -> bool:
    """A hosted gimbal that is its own gimbal manager (``act_as_manager``)."""
    return isinstance(gimbal, GimbalDevice) and bool(gimbal.settings.act_as_manager)


def _safe_len(snapshot: Callable[[], Sized]) -> int:
    """How many items a backend snapshot has; 0 when it fails (the tick's guards report a
    failing backend; building the MAVLink side must not fail on it)."""
    try:
        return len(snapshot())
    except Exception:  # noqa: BLE001 - any failure of the backend: plan for nothing
        return 0
