"""The MAVLink side as the bridge uses it: link + core + a tick thread.

``MavlinkSide(settings, backend, gimbals=[...])`` opens the connection, hosts the servo component
and every gimbal component, and runs two threads: the link's receive thread (messages into the
core) and a tick thread (heartbeats, telemetry, failsafe, DO_REPEAT_SERVO steps) every
``TICK_S``. Both enter the core under one lock, so the core needs no locking of its own.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from mavservo.mavlink.answers import Answer
from mavservo.mavlink.backend import ActuatorBackend
from mavservo.mavlink.bandwidth import Admission
from mavservo.mavlink.can_tunnel import CanTunnel
from mavservo.mavlink.commands import Outgoing
from mavservo.mavlink.component import HostedComponent
from mavservo.mavlink.link import MavlinkLink
from mavservo.mavlink.mavlink_core import MavlinkCore
from mavservo.mavlink.origin import Requester, requester_of
from mavservo.mavlink.params import ParameterOwner
from mavservo.mavlink.settings import MavlinkSettings
from mavservo.mavlink.telemetry import MAV_SEVERITY_WARNING
from mavservo.threads import BackgroundLoop

log = logging.getLogger(__name__)

TICK_S = 0.01
#: Events (STATUSTEXT chunks, ACKs) waiting for the link budget at most.
MAX_HELD_EVENTS = 256
#: Where a decided message goes: the link and the monitors, the monitors only (decimated, or
#: waiting for the link), the link only (it waited; the monitors had it when it was made).
_BOTH, _MONITORS, _LINK = "both", "monitors", "link"


class MavlinkSide:
    """Lifecycle owner of the MAVLink half of the bridge: ``start()``, ``stop()``, ``stats()``."""

    def __init__(
        self,
        settings: MavlinkSettings,
        backend: ActuatorBackend,
        gimbals: Sequence[HostedComponent] = (),
        clock: Callable[[], float] = time.monotonic,
        on_event: Callable[[str], None] | None = None,
        parameters: ParameterOwner | None = None,
        metadata_files: Mapping[int, Mapping[str, bytes]] | None = None,
        can_tunnel: CanTunnel | None = None,
    ) -> None:
        self._clock = clock
        #: also told about link loss / recovery (the bridge's console and event list)
        self._on_event = on_event
        # re-entrant: the core calls the backend under this lock, and the backend may announce
        self._lock = threading.RLock()
        #: held from a batch's decision to its last send (taken before ``_lock``, never inside
        #: it): the receive thread and the tick thread each decide under ``_lock`` and used to send
        #: outside it, so one's sends could overtake the other's already decided ones (a held
        #: event released by one thread behind a newer one of the other, a waiting value of a
        #: stream behind its newer one). The core is never blocked by a write: only the other
        #: thread's sends wait, as they waited for the link's own write lock before.
        self._send_order = threading.RLock()
        self.core = MavlinkCore(
            settings,
            backend,
            gimbals,
            boot_time=clock(),
            parameters=parameters,
            metadata_files=metadata_files,  # gcs: COMPONENT_METADATA + FTP (issue 30)
        )
        self.link = MavlinkLink(
            settings.url,
            self._on_message,
            baud=settings.baud,
            signing=settings.signing,
            on_event=self._on_link_event,
            clock=clock,
            monitor_outputs=settings.monitor_outputs,
        )
        for cid in self.core.components:
            self.link.add_component(cid, self.core.system_id)
        allowed = settings.allowed_sources
        self.link.privileged = lambda source: source == self.core.watched or source in allowed
        self._loop = BackgroundLoop(self._tick_loop, name="mavlink-tick")
        self._tick_errors = 0  # failures the core's own guards did not catch
        #: events the link budget could not take yet, in order (sent before newer ones), each
        #: with whether a peer asked for it (a requested message is an event whatever its type)
        #: and, if so, who asked (the answer goes to that origin only)
        self._held: list[tuple[int, Any, bool, Requester | None]] = []
        #: ``on_sent(msg, t)`` after each message went out (latency tracing); must not block.
        self.on_sent: Callable[[Any, float], None] | None = None
        #: CAN frames to and from the autopilot's CAN port (``mavlink-can`` buses), straight
        #: on the link: addressed to the autopilot only, outside the radio's budget
        self._can_tunnel = can_tunnel
        if can_tunnel is not None:
            servo = settings.servo_component_id
            can_tunnel.attach(
                send=lambda msg: self._send_tunnelled(servo, msg),
                autopilot=self._heard_autopilot,
                own=lambda: (self.core.system_id, servo),
            )

    def start(self) -> None:
        self.link.start()
        self._loop.start()

    @property
    def is_running(self) -> bool:
        """True while the tick loop (the only heartbeat source) runs."""
        return self._loop.is_running

    def stop(self) -> None:
        self._loop.stop()
        self.link.stop()

    def __enter__(self) -> MavlinkSide:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def stats(self) -> dict[str, Any]:
        with self._lock:
            stats = {**self.core.stats(), "link": self.link.stats()}
            stats["link_budget"] = {
                "budget_bytes_s": self.core.budget.plan.budget_bytes_s,
                "planned_bytes_s": round(self.core.budget.plan.link_bytes_s, 1),
                "configured_bytes_s": round(self.core.budget.plan.full_bytes_s, 1),
                **self.core.budget.counters,
            }
            if self._tick_errors:
                stats["tick_loop_errors"] = self._tick_errors
            return stats

    # ------------------------------------------------------------------ plumbing

    def _send_tunnelled(self, component_id: int, msg: Any) -> bool:
        """A tunnel's message on the link only; False when the link is not open."""
        if not self.link.is_open:
            return False
        self.link.send(component_id, msg, self.core.system_id, to_monitors=False)
        return True

    def _heard_autopilot(self) -> tuple[int, int] | None:
        """The followed autopilot's (system, component) once its HEARTBEAT was heard."""
        core = self.core
        return core.watched if core.watchdog.last_heartbeat is not None else None

    def _on_message(self, msg: Any, now: float) -> None:
        tunnel = self._can_tunnel
        if tunnel is not None and tunnel.take(msg, now):
            return  # a forwarded CAN frame: the mavlink-can bus's, not the core's
        with self._lock:
            out = self.core.on_message(msg, now)
            source = (msg.get_srcSystem(), msg.get_srcComponent())
            if out and not (self.link.privileged(source) or getattr(msg, "_signed", False)):
                # an unverified sender's responses wait for its turn (a flood cannot push
                # everyone else's ACKs out): to it only, with the next tick
                self.core.queue_responses(requester_of(msg), out, now)
                return
        # a verified sender's responses go at once, but to where it spoke from only: sent to
        # every peer, the station's COMMAND_ACK and the message it asked for reached a
        # stranger claiming its ids from another address too (issue 40 after issue 38's merge)
        self._send(out, requested=True, reply_to=requester_of(msg))

    def announce(self, text: str, severity: int = MAV_SEVERITY_WARNING) -> None:
        """Queue a STATUSTEXT from the servo component (thread-safe, for the other layers)."""
        with self._lock:
            self.core.announce(severity, text)

    def _on_link_event(self, text: str) -> None:
        self.announce(f"servo bridge: {text}")
        if self._on_event is not None:
            self._on_event(text)

    def _tick_loop(self) -> None:
        next_tick = self._clock()
        while not self._loop.stopping:
            now = self._clock()
            try:
                with self._send_order:
                    with self._lock:
                        out = self.core.tick(now, self.link.read_until)
                        answers = self.core.answers_due(now)
                    self._send(out)
                    self._send_answers(answers)
            except Exception:  # noqa: BLE001 - the only heartbeat source must never die
                self._tick_errors += 1
                if self._tick_errors == 1:
                    log.exception("MAVLink tick failed (logged once, counted in tick_errors)")
            next_tick += TICK_S
            delay = next_tick - self._clock()
            if delay < 0:
                next_tick = self._clock()
                delay = 0
            self._loop.wait(delay)

    def _send(
        self, out: list[Outgoing], requested: bool = False, reply_to: Requester | None = None
    ) -> None:
        """Send ``out`` within the link budget: periodic telemetry goes to the monitors at
        once and to the link in its turn (the budget's waiting line: what waited goes first,
        a message the plan decimates goes to the monitors only); an event (STATUSTEXT chunk,
        ACK) the budget cannot take now goes to the monitors at once and waits, in order, for
        the link at a next tick instead of being lost (a long text arrives whole).
        ``requested``: the responses to a peer's message (its ACK, a message it asked for),
        events whatever their type, to ``reply_to`` only (the origin of the request)."""
        with self._send_order:  # sent in the order decided, whichever thread decided first
            with self._lock:  # the budget's bucket and the held events are shared by two threads
                decided = self._decide(out, requested, reply_to)
            system_id = self.core.system_id
            for component_id, msg, where, to in decided:
                self.link.send(
                    component_id,
                    msg,
                    system_id,
                    to_link=where != _MONITORS,
                    to_monitors=where != _LINK,
                    reply_to=to,
                )
                if self.on_sent is not None and where != _LINK:  # when it first left
                    self.on_sent(msg, self._clock())

    def _decide(
        self, out: list[Outgoing], requested: bool, reply_to: Requester | None = None
    ) -> list[tuple[int, Any, str, Requester | None]]:
        """Where each message goes. The held events first (the monitors had them when they
        were held: to the link only), then ``out`` (new: the monitors at once, whatever the
        link takes; before, a held event reached the monitors only when the link took it,
        and one dropped from the full held list never)."""
        budget = self.core.budget
        now = self._clock()
        held, self._held = self._held, []
        pending = [(cid, msg, asked, to, False) for cid, msg, asked, to in held]
        pending += [(cid, msg, requested, reply_to, True) for cid, msg in out]
        decided: list[tuple[int, Any, str, Requester | None]] = [
            (component_id, msg, _LINK, None) for component_id, msg in budget.due(now)
        ]
        for component_id, msg, asked, to, new in pending:
            if new and not self.core.link_carries(msg):  # px4: the autopilot would drop it
                decided.append((component_id, msg, _MONITORS, to))
                continue
            if not (asked or budget.is_event(msg)):
                # periodic: the monitors now, the link now, in its turn (WAITS) or not (SKIPPED)
                goes = budget.offer(component_id, msg, now) is Admission.NOW
                decided.append((component_id, msg, _BOTH if goes else _MONITORS, to))
                continue
            # an event: in order behind one that waits, or waits itself for the budget; an
            # essential one (heartbeat, CRITICAL text) never waits behind others (a heartbeat
            # held behind a burst of texts went 6 s late: a component lost to its peers)
            behind = bool(self._held) and (asked or not budget.essential(msg))
            goes = not behind and budget.offer(component_id, msg, now, requested=asked) is (
                Admission.NOW
            )
            if not goes:
                self._hold(component_id, msg, asked, to)
            if new:
                decided.append((component_id, msg, _BOTH if goes else _MONITORS, to))
            elif goes:
                decided.append((component_id, msg, _LINK, to))
        return decided

    def _hold(
        self, component_id: int, msg: Any, requested: bool, reply_to: Requester | None = None
    ) -> None:
        """Keep an event for the next tick; beyond :data:`MAX_HELD_EVENTS` the oldest one
        that is not essential (the bridge's CRITICAL text, its heartbeat; one a peer asked for
        is an answer) is dropped and counted."""
        self._held.append((component_id, msg, requested, reply_to))
        if len(self._held) > MAX_HELD_EVENTS:
            victim = next(
                (
                    i
                    for i, (_, m, asked, _to) in enumerate(self._held)
                    if asked or not self.core.budget.essential(m)  # one asked for: an answer
                ),
                None,
            )
            if victim is not None:
                del self._held[victim]
                self.core.budget.counters["events_dropped"] += 1

    def _send_answers(self, answers: list[Answer]) -> None:
        """Answers to requests (already admitted by the budget), each to its requester only."""
        system_id = self.core.system_id
        for answer in answers:
            if not self.core.link_carries(answer.msg):  # px4: the autopilot would drop it
                continue
            self.link.send(answer.component_id, answer.msg, system_id, reply_to=answer.to)
