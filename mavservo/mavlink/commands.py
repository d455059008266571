"""MAVLink commands in, COMMAND_ACKs out: DO_SET_SERVO, DO_REPEAT_SERVO, DO_SET_ACTUATOR, and the
message services REQUEST_MESSAGE / SET_MESSAGE_INTERVAL, for every component the bridge hosts.

This module decides who a command is for, whether it is a retry, and what ACK it gets; what the
servo commands mean (their parameters, the running repeats) is ``servo_commands.ServoCommands``'
job, and a gimbal's commands its own (``component.HostedComponent``).

Addressing rules (why: real clients send the same command in different ways, see DESIGN.md):

* addressed to one of our components -> handled there, exactly one ACK from that component;
* broadcast (target component 0) -> acted on only when it concerns channels we map (or a hosted
  gimbal claims it), ACKed from the component that acted; otherwise ignored silently, because the
  autopilot or another component will answer it;
* addressed to the autopilot -> ignored, except DO_SET_SERVO on a mapped channel when
  ``act_on_autopilot_commands`` is set: acted on, not ACKed (the autopilot ACKs it);
* another system id -> ignored.

Senders retry until they see the ACK, with the same content. A retry is ACKed again with the
earlier result and not applied twice (DO_REPEAT_SERVO would otherwise restart). What counts as a
retry is decided per servo the command drives (its servo channel or actuator indices resolved
through the mapping, so a DO_SET_SERVO and a DO_SET_ACTUATOR for one servo share one window;
for anything else, the target component and command): a command is a retry only when it is
identical (same sender, its ids and the origin they came from, message type, target and
parameters) to the LAST command for every servo it drives,
and either comes inside ``retry_window_s`` or carries confirmation > 0. Any other command for
one of those outputs in between, from anyone, ends the window: 1100, 1900, 1100 us on one
channel is three commands, never a retry (the MAVLink spec makes confirmation 0 a first
transmission, and a change back is a change). Mirrored autopilot streams (SERVO_OUTPUT_RAW)
do not end a window, on purpose: a retry is the sender's lost-ACK repeat of what it asked
before the stream's newer value, and applying it would undo that newer value. The table holds
one entry per servo, at most ``MAX_RETRY_ENTRIES``, oldest dropped first, so a lookup costs
the same under a flood of distinct commands as for one command, and the memory is bounded.

Bad input never reaches the backend: everything is validated before the first setpoint goes out.
A handler that raises anyway (a bug, a value nobody foresaw) costs that command a DENIED ACK and
a ``handler_error`` count, never the ACK or the thread. Pure apart from logging: time comes in as
an argument, messages go out as return values.
"""

from __future__ import annotations

import logging
import math
from collections import Counter, OrderedDict
from collections.abc import Callable, Hashable, Mapping
from dataclasses import dataclass, field
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.mavlink.arbitration import CommandHold
from mavservo.mavlink.backend import ActuatorBackend, ApplyResult, Outcome
from mavservo.mavlink.component import HostedComponent
from mavservo.mavlink.origin import Requester, origin_of
from mavservo.mavlink.servo_commands import (
    INT32_MAX,
    MAV_CMD_DO_REPEAT_SERVO,
    MAV_CMD_DO_SET_ACTUATOR,
    MAV_CMD_DO_SET_SERVO,
    ServoCommands,
    actuator_values,
    denied,
    is_int,
)
from mavservo.mavlink.settings import MavlinkSettings

log = logging.getLogger(__name__)

MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_CMD_REQUEST_MESSAGE = 512
MSG_HEARTBEAT = 0
#: COMPONENT_METADATA (common.xml 397), answered by each component that serves metadata
MSG_COMPONENT_METADATA = 397

#: MAVLink 2 message ids are 24-bit: anything larger in REQUEST_MESSAGE / SET_MESSAGE_INTERVAL
#: is not a message id.
MAX_MESSAGE_ID = 2**24 - 1
#: MESSAGE_INTERVAL carries the interval as int32 microseconds: a larger one cannot be reported.
MAX_INTERVAL_US = float(INT32_MAX)
#: Outputs the retry table remembers at most (a flood of distinct targets drops the oldest:
#: the worst that does is apply a very old retry again, never refuse a new command).
MAX_RETRY_ENTRIES = 1024
#: How long an entry is kept for confirmation > 0 retries, in retry windows.
RETRY_HORIZON_WINDOWS = 5
#: At most one warning per kind of refusal per this many seconds (the rest are counted).
REFUSAL_LOG_INTERVAL_S = 1.0

#: (component id, pymavlink message) to send from that component.
Outgoing = tuple[int, Any]


@dataclass(frozen=True)
class Command:
    """COMMAND_LONG and COMMAND_INT in one shape: seven float params (COMMAND_INT x/y as floats)."""

    source: tuple[int, int]
    target_system: int
    target_component: int
    command: int
    params: tuple[float, ...]
    is_int: bool = False
    confirmation: int = 0
    #: where it came from (UDP address, TCP connection; None: a link with one peer), see
    #: :mod:`.origin`
    origin: Hashable = None

    @classmethod
    def from_message(cls, msg: Any) -> Command:
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        if msg.get_type() == "COMMAND_INT":
            params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.x, msg.y, msg.z)
            return cls(
                source,
                msg.target_system,
                msg.target_component,
                msg.command,
                tuple(float(p) for p in params),
                is_int=True,
                origin=origin_of(msg),
            )
        params = (
            msg.param1,
            msg.param2,
            msg.param3,
            msg.param4,
            msg.param5,
            msg.param6,
            msg.param7,
        )
        return cls(
            source,
            msg.target_system,
            msg.target_component,
            msg.command,
            tuple(float(p) for p in params),
            confirmation=int(msg.confirmation),
            origin=origin_of(msg),
        )

    @property
    def requester(self) -> Requester:
        """Who sent it: the claimed ids and the origin they spoke from."""
        return Requester(self.source[0], self.source[1], self.origin)

    def retry_key(self) -> tuple:
        """Identity of a command for retry detection (NaN-safe, ignores confirmation): sender
        (its ids *and* origin), target, command, message type (COMMAND_INT and COMMAND_LONG
        differ) and parameters.

        Why the origin (issue 40): on an unsigned link the ids are a claim. Keyed by ids only, a
        stranger at another address repeating the station's DO_SET_SERVO as 255/190 had its
        copy taken for the station's retry (ACKed with the station's result, nothing applied),
        and the station's own command after a stranger's identical one was a "retry" of it."""
        params = tuple("nan" if math.isnan(p) else p for p in self.params)
        return (self.requester, self.target_component, self.command, self.is_int, params)


class RateLimitedLog:
    """At most one line per kind of problem per ``interval_s``; the rest only counted.

    Why: a flood of bad commands is one problem, and a warning line per command would fill the
    journal (and cost the command loop the time to write it). Kinds come from a fixed
    vocabulary (the refusal reasons), so the table stays small.
    """

    def __init__(self, interval_s: float) -> None:
        self.interval_s = interval_s
        self._last: dict[str, float] = {}
        self._quiet: Counter[str] = Counter()

    def quiet_since_last(self, kind: str, now: float) -> int | None:
        """None: stay quiet (counted); else log now, with this many kept quiet since the last."""
        last = self._last.get(kind)
        if last is not None and 0 <= now - last < self.interval_s:
            self._quiet[kind] += 1
            return None
        self._last[kind] = now
        return self._quiet.pop(kind, 0)


@dataclass
class _Recent:
    """The last command for one or more outputs: what it was, what it got, when last seen."""

    key: tuple
    result: Outcome
    when: float
    ack_component: int | None


class RetryTable:
    """The last command per output, for retry detection in constant time and bounded memory.

    Why per output: a retry window belongs to one output. Whatever else was commanded for it
    since (by anyone) makes an identical repeat a new command, because applying it again is
    what its sender wants. Why an ordered dict: entries are kept in the order they were last
    touched, so the expired ones are at the front (dropped a few per call, never a scan) and so
    are the ones dropped when the table is full.
    """

    def __init__(self, window_s: float, max_entries: int = MAX_RETRY_ENTRIES) -> None:
        self.window_s = window_s
        self.max_entries = max_entries
        self.evicted = 0
        self._by_output: OrderedDict[Hashable, _Recent] = OrderedDict()

    def __len__(self) -> int:
        return len(self._by_output)

    def find(self, cmd: Command, outputs: tuple[Hashable, ...], now: float) -> _Recent | None:
        """The earlier command ``cmd`` retries, or None when ``cmd`` is a new command."""
        self._expire(now)
        entries = [self._by_output.get(output) for output in outputs]
        first = entries[0]
        if first is None or any(entry is not first for entry in entries):
            return None  # never seen, or another command for one of its outputs since
        if first.key != cmd.retry_key() or first.result is Outcome.TEMPORARILY_REJECTED:
            return None  # a different command; "try again later" tried again is fresh
        if cmd.confirmation > 0 or now - first.when <= self.window_s:
            self.touch(first, outputs, now)
            return first
        return None

    def record(self, entry: _Recent, outputs: tuple[Hashable, ...]) -> None:
        """``entry`` is now the last command for every one of ``outputs``."""
        self.touch(entry, outputs, entry.when)

    def touch(self, entry: _Recent, outputs: tuple[Hashable, ...], now: float) -> None:
        entry.when = now
        for output in outputs:
            self._by_output[output] = entry
            self._by_output.move_to_end(output)
        while len(self._by_output) > self.max_entries:
            self._by_output.popitem(last=False)
            self.evicted += 1

    def _expire(self, now: float) -> None:
        # kept a while past the window for confirmation > 0 retries
        horizon = RETRY_HORIZON_WINDOWS * self.window_s
        while self._by_output:
            oldest = next(iter(self._by_output.values()))
            if now - oldest.when <= horizon:
                return
            self._by_output.popitem(last=False)


@dataclass
class CommandHandler:
    """Decides, applies and ACKs commands (the servo commands through :attr:`servo`, a
    :class:`~.servo_commands.ServoCommands`, the gimbals' through their component).

    ``system_id`` is read at every call (it may follow the autopilot).
    ``request_message(msg_id, now)`` returns the servo component's answer to REQUEST_MESSAGE
    (or None when it does not publish it); ``set_interval(msg_id, interval_us)`` returns whether
    the servo component publishes that message (or, a text, why it refuses the rate);
    ``heartbeat(component_id)`` is that component's HEARTBEAT, sent at once when
    REQUEST_MESSAGE asks for message 0 (every hosted component publishes one, so every one
    answers for it)."""

    backend: ActuatorBackend
    settings: MavlinkSettings
    hold: CommandHold
    system_id: Callable[[], int]
    request_message: Callable[[int, float], list[Any] | None]
    #: True: set; False: not published; a text: refused, the reason (DENIED)
    set_interval: Callable[[int, float], bool | str]
    heartbeat: Callable[[int], Any]
    gimbals: Mapping[int, HostedComponent] = field(default_factory=dict)
    #: COMPONENT_METADATA of a hosted component (None: it serves no metadata)
    component_metadata: Callable[[int], Any | None] = lambda _cid: None
    counters: Counter[str] = field(default_factory=Counter)
    servo: ServoCommands = field(init=False)
    _retries: RetryTable = field(init=False)
    _refusal_log: RateLimitedLog = field(init=False)
    _servo_of_output: dict[tuple[str, int], str] | None = None
    _now: float = 0.0

    def __post_init__(self) -> None:
        self.servo = ServoCommands(self.backend, self.settings, self.hold)
        self._retries = RetryTable(self.settings.retry_window_s)
        self._refusal_log = RateLimitedLog(REFUSAL_LOG_INTERVAL_S)

    @property
    def retry_table(self) -> RetryTable:
        """The retry table (read-only use: its size, its evictions)."""
        return self._retries

    # ------------------------------------------------------------------ entry points

    def handle(self, cmd: Command, now: float) -> list[Outgoing]:
        """Process one command; returns the ACK (and any requested message) to send."""
        self._now = now
        if cmd.target_system not in (0, self.system_id()):
            self.counters["ignored_other_system"] += 1
            log.debug(
                "command %d from %s ignored: for system %d, not ours",
                cmd.command,
                cmd.source,
                cmd.target_system,
            )
            return []
        servo_comp = self.settings.servo_component_id
        target = cmd.target_component
        if target == servo_comp or target in self.gimbals or target == 0:
            return self._with_retry_check(cmd, now)
        if (
            target == self.settings.autopilot_component
            and self.settings.act_on_autopilot_commands
            and cmd.command == MAV_CMD_DO_SET_SERVO
        ):
            return self._with_retry_check(cmd, now, ack=False)
        self.counters["ignored_other_component"] += 1
        log.debug(
            "command %d from %s ignored: for component %d, which the bridge does not host",
            cmd.command,
            cmd.source,
            target,
        )
        return []

    def tick(self, now: float) -> None:
        """Advance running DO_REPEAT_SERVO jobs."""
        self.servo.tick(now)

    def repeating_channels(self) -> set[int]:
        return self.servo.repeating_channels()

    def cancel_all(self) -> None:
        """Stop every running repeat (failsafe: nothing moves until fresh commands)."""
        self.servo.cancel_all()

    # ------------------------------------------------------------------ routing

    def _with_retry_check(self, cmd: Command, now: float, ack: bool = True) -> list[Outgoing]:
        outputs = self._outputs(cmd)
        recent = self._retries.find(cmd, outputs, now)
        # a repeated REQUEST_MESSAGE that was answered is answered again, message and all: it
        # applies nothing, and its requester repeats it because the answer was lost (a GCS
        # fetching COMPONENT_METADATA over a lossy radio would otherwise get only ACKs until
        # the window passed); a refused one keeps its refusal like any retry
        answer_again = (
            recent is not None
            and cmd.command == MAV_CMD_REQUEST_MESSAGE
            and recent.result is Outcome.ACCEPTED
        )
        if recent is not None and not answer_again:
            self.counters["retry_not_reapplied"] += 1
            log.info(
                "command %d from %s is a retry: ACK %s again, not applied",
                cmd.command,
                cmd.source,
                recent.result.name,
            )
            if not ack or recent.ack_component is None:
                return []
            return [(recent.ack_component, self._ack(cmd, recent.result))]
        decided = self._guarded_dispatch(cmd, now)
        if decided is None:
            # a broadcast (or autopilot-addressed command) for nothing we map: whoever owns it
            # answers, so no ACK from here
            self.counters["ignored_not_ours"] += 1
            log.debug(
                "command %d from %s to component %d ignored: concerns nothing the bridge maps",
                cmd.command,
                cmd.source,
                cmd.target_component,
            )
            return []
        component, result, extra = decided
        self._count_result(cmd, component, result)
        entry = _Recent(cmd.retry_key(), result.outcome, now, component if ack else None)
        self._retries.record(entry, outputs)
        if self._retries.evicted:  # the table was full: a flood of distinct targets
            self.counters["retry_entries_dropped"] = self._retries.evicted
        if not ack:
            return []
        out: list[Outgoing] = [(component, self._ack(cmd, result.outcome))]
        out.extend((component, m) for m in extra)
        return out

    def _count_result(self, cmd: Command, component: int, result: ApplyResult) -> None:
        self.counters[f"result_{result.outcome.name.lower()}"] += 1
        if result.ok:
            log.info(
                "command %d from %s accepted by component %d", cmd.command, cmd.source, component
            )
            return
        kind = result.reason.split(":")[0] if ":" in result.reason else "backend"
        self.counters[f"reason_{kind}"] += 1
        quiet = self._refusal_log.quiet_since_last(kind, self._now)
        if quiet is None:
            return
        log.warning(
            "command %d from %s -> %s: %s%s",
            cmd.command,
            cmd.source,
            result.outcome.name,
            result.reason,
            f" ({quiet} more refused for {kind} since the last line, counted)" if quiet else "",
        )

    def _outputs(self, cmd: Command) -> tuple[Hashable, ...]:
        """What ``cmd`` drives, for retry detection: the servos its mapped servo channel or
        actuator indices drive (see :meth:`_driven`); for anything else (message services,
        gimbal commands, bad or unmapped targets) its target component and command. Only
        mapped outputs get their own entry, so the keys an attacker can make up are bounded by
        the command ids and the servos."""
        generic: tuple[Hashable, ...] = (("command", cmd.target_component, cmd.command),)
        if cmd.command in (MAV_CMD_DO_SET_SERVO, MAV_CMD_DO_REPEAT_SERVO):
            raw = cmd.params[0]
            if is_int(raw) and int(raw) in self.backend.mapped_servo_channels():
                return (self._driven(("servo", int(raw))),)
            return generic
        if cmd.command == MAV_CMD_DO_SET_ACTUATOR:
            values = actuator_values(cmd.params, cmd.is_int)
            mapped = self.backend.mapped_actuator_indices()
            indices = sorted(i for i in values or () if i in mapped)
            driven = dict.fromkeys(self._driven(("actuator", i)) for i in indices)
            return tuple(driven) or generic
        return generic

    def _driven(self, output: tuple[str, int]) -> Hashable:
        """The retry key of a mapped ``output`` ("servo", channel) / ("actuator", index): the
        servo it drives. Why: one servo may be mapped from a servo channel AND an actuator
        (config/sim.yaml's payload_release: channel 9 and actuator 1); keyed by output,
        DO_SET_SERVO(9, 1100), DO_SET_ACTUATOR(1, +1), DO_SET_SERVO(9, 1100) took the third
        for a retry of the first, ACKed it ACCEPTED and left the servo at +1 (finding A).
        Keyed by servo, any command that drives the servo ends the window of every other."""
        servo = self._servo_by_output().get(output)
        return output if servo is None else ("servo_named", servo)

    def _servo_by_output(self) -> dict[tuple[str, int], str]:
        """Which servo each mapped output drives, from the backend's statuses (the mapping is
        fixed for a run, so it is read once; the config allows one mapping per source and
        servo, so a status names every output of its servo)."""
        if self._servo_of_output is None:
            table: dict[tuple[str, int], str] = {}
            for status in self.backend.servo_statuses():
                if status.servo_channel is not None:
                    table[("servo", status.servo_channel)] = status.name
                if status.actuator_index is not None:
                    table[("actuator", status.actuator_index)] = status.name
            self._servo_of_output = table
        return self._servo_of_output

    def _guarded_dispatch(self, cmd: Command, now: float) -> tuple[int, ApplyResult, list] | None:
        """``_dispatch``, but a handler that raises costs a DENIED ACK, not the ACK.

        Why: the handlers validate what they use, but a gimbal's handler or the backend may
        still meet a value nobody foresaw; the sender must get its one ACK and the link thread
        must go on. Logged with the traceback at most once a second, counted every time."""
        try:
            return self._dispatch(cmd, now)
        except Exception:  # noqa: BLE001 - whatever a handler raises, the sender gets an ACK
            self.counters["handler_error"] += 1
            quiet = self._refusal_log.quiet_since_last("handler_exception", now)
            if quiet is not None:
                log.exception(
                    "command %d from %s: handler failed (%d more since the last line; all "
                    "counted in handler_error)",
                    cmd.command,
                    cmd.source,
                    quiet,
                )
            target = cmd.target_component
            component = target if target in self.gimbals else self.settings.servo_component_id
            return component, denied("handler_error", "the handler raised"), []

    def _dispatch(self, cmd: Command, now: float) -> tuple[int, ApplyResult, list] | None:
        """Returns (acking component, result, messages to send after the ACK) or None."""
        target = cmd.target_component
        broadcast = target == 0
        servo_comp = self.settings.servo_component_id
        if cmd.command == MAV_CMD_REQUEST_MESSAGE and cmd.params[0] == MSG_HEARTBEAT:
            # from the component asked; a broadcast gets one answer, from the servo component
            component = target if target in self.gimbals else servo_comp
            return component, ApplyResult(Outcome.ACCEPTED), [self.heartbeat(component)]
        if cmd.command == MAV_CMD_REQUEST_MESSAGE and cmd.params[0] == MSG_COMPONENT_METADATA:
            # each component serves its own metadata; a broadcast gets the servo component's
            component = target if target in self.gimbals else servo_comp
            metadata = self.component_metadata(component)
            if metadata is not None:
                return component, ApplyResult(Outcome.ACCEPTED), [metadata]
        if target in self.gimbals:
            return self._gimbal_command(self.gimbals[target], cmd, now, broadcast=False)
        decided = self._servo_command(cmd, now, broadcast=broadcast or target != servo_comp)
        if decided is not None:
            result, extra = decided
            return servo_comp, result, extra
        if broadcast:
            for device in self.gimbals.values():
                answer = self._gimbal_command(device, cmd, now, broadcast=True)
                if answer is not None:
                    return answer
        return None

    def _gimbal_command(
        self, device: HostedComponent, cmd: Command, now: float, broadcast: bool
    ) -> tuple[int, ApplyResult, list] | None:
        comp = device.component_id
        if cmd.command == MAV_CMD_REQUEST_MESSAGE and _is_message_id(cmd.params[0]):
            message = device.requested_message(int(cmd.params[0]), now)
            if message is not None:
                return comp, ApplyResult(Outcome.ACCEPTED), [message]
            if broadcast:
                return None
            return comp, ApplyResult(Outcome.UNSUPPORTED, "unsupported:message not published"), []
        infinite = [i + 1 for i, p in enumerate(cmd.params) if math.isinf(p)]
        if infinite:
            # the generic numeric guard: no MAVLink parameter means anything at +-inf (NaN
            # does: "no change"), so the gimbal never sees one; its own values it checks itself.
            # A broadcast the gimbal does not handle is not its to answer, inf or not: the
            # guard ran first and made 154 DENY broadcast NAV_TAKEOFF(inf) (finding B)
            if broadcast and not device.handles_command(cmd.command):
                return None
            return comp, denied("bad_param", f"infinite param(s) {infinite}"), []
        raw = device.handle_command(cmd.command, cmd.params, now, sender=cmd.source)
        if raw is None:
            if broadcast:
                return None
            return comp, ApplyResult(Outcome.UNSUPPORTED, "unsupported:command"), []
        if raw not in _MAV_RESULTS:
            raise ValueError(f"gimbal {comp} answered command {cmd.command} with {raw!r}")
        return comp, ApplyResult(Outcome(int(raw)), "" if raw == 0 else "gimbal:refused"), []

    def _servo_command(
        self, cmd: Command, now: float, broadcast: bool
    ) -> tuple[ApplyResult, list] | None:
        """None = not for us (only possible for broadcast / autopilot-addressed commands)."""
        handler = self.servo.handlers.get(cmd.command)
        if handler is not None:
            result = handler(cmd.params, cmd.is_int, now, broadcast)
            return None if result is None else (result, [])
        if cmd.command == MAV_CMD_REQUEST_MESSAGE:
            return self._request_message(cmd, now, broadcast)
        if cmd.command == MAV_CMD_SET_MESSAGE_INTERVAL:
            return self._set_message_interval(cmd, broadcast)
        if broadcast:
            return None
        return ApplyResult(Outcome.UNSUPPORTED, f"unsupported:command {cmd.command}"), []

    # ------------------------------------------------------------------ message services

    def _request_message(
        self, cmd: Command, now: float, broadcast: bool
    ) -> tuple[ApplyResult, list] | None:
        msg_id = cmd.params[0]
        if not _is_message_id(msg_id):
            return None if broadcast else (denied("bad_param", f"message id {msg_id!r}"), [])
        messages = self.request_message(int(msg_id), now)
        if messages is None:
            if broadcast:
                return None
            return ApplyResult(Outcome.UNSUPPORTED, f"unsupported:message {int(msg_id)}"), []
        return ApplyResult(Outcome.ACCEPTED), list(messages)

    def _set_message_interval(
        self, cmd: Command, broadcast: bool
    ) -> tuple[ApplyResult, list] | None:
        msg_id, interval = cmd.params[0], cmd.params[1]
        if not _is_message_id(msg_id) or not _valid_interval(interval):
            return (
                None if broadcast else (denied("bad_param", f"message interval {interval!r}"), [])
            )
        result = self.set_interval(int(msg_id), interval)
        if isinstance(result, str):
            return None if broadcast else (denied("rate", result), [])
        if not result:
            if broadcast:
                return None
            return ApplyResult(Outcome.UNSUPPORTED, f"unsupported:message {int(msg_id)}"), []
        return ApplyResult(Outcome.ACCEPTED), []

    # ------------------------------------------------------------------ helpers

    @staticmethod
    def _ack(cmd: Command, result: Outcome) -> Any:
        return mavlink2.MAVLink_command_ack_message(
            command=cmd.command,
            result=int(result),
            progress=0,
            result_param2=0,
            target_system=cmd.source[0],
            target_component=cmd.source[1],
        )


_MAV_RESULTS = frozenset(int(o) for o in Outcome)


def _is_message_id(value: float) -> bool:
    return is_int(value) and 0 <= value <= MAX_MESSAGE_ID


def _valid_interval(interval_us: float) -> bool:
    """-1 (stop), 0 (default rate) or a positive interval MESSAGE_INTERVAL can report; any
    other negative value means nothing (review3: -0.5 stopped the stream like -1)."""
    return math.isfinite(interval_us) and (interval_us == -1 or 0 <= interval_us <= MAX_INTERVAL_US)
