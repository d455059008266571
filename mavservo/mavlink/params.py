"""The MAVLink parameter protocol on the bridge's components, and quick "no" to other services.

Ground stations ask every component they see for its parameters (QGroundControl, Mission Planner,
MAVProxy's ``param`` module) and, in MAVProxy's case, first try MAVLink FTP for the packed list.
A component that stays silent makes them wait and print time-outs; one that answers lets an
integrator trim a control surface from the field. This module is the protocol, without I/O: it
takes received messages and the passing of time and returns PARAM_VALUE / PARAM_ERROR /
FILE_TRANSFER_PROTOCOL / MISSION_ACK messages to send from a component. What a value means,
whether it is valid and how it takes effect belong to a :class:`ParameterOwner`.

Rules (https://mavlink.io/en/services/parameter.html):

* PARAM_REQUEST_LIST: every parameter of the component as PARAM_VALUE with its index and the
  count; the core paces answers per requester within the link budget (mavlink/answers.py), so
  a list does not arrive as one burst on a radio, and goes to the requester only.
* PARAM_REQUEST_READ: by name when ``param_index`` is -1, else by index; an unknown one gets
  PARAM_ERROR (MAV_PARAM_ERROR_DOES_NOT_EXIST).
* PARAM_SET: a PARAM_VALUE with the value now in force. A refused set gets PARAM_ERROR (345,
  common.xml; MAV_PARAM_ERROR) with the reason's code first: VALUE_OUT_OF_RANGE when the
  config's rules refuse the value, PERMISSION_DENIED when the sender may not write,
  TYPE_UNSUPPORTED for a ``param_type`` that cannot carry a value, DOES_NOT_EXIST for an unknown
  name; then, for a name that exists, the old PARAM_VALUE for clients that predate PARAM_ERROR
  (plus a STATUSTEXT with the owner's reason and a counter). Why the order: MAVSDK's parameter
  client ends a set at the first PARAM_ERROR naming it (``process_param_error``, mapping the
  codes to ValueOutOfRange, PermissionDenied, ...), but takes a PARAM_VALUE with another value
  as a stale one and sends the set again (mavlink_parameter_client.cpp, ``WorkItemSet``); with
  only the old PARAM_VALUE it retried and reported a time-out (issue 38).
* Values travel as MAV_PARAM_TYPE_REAL32; every parameter of the bridge is a float (integral
  ones such as ``SRV1_REV`` are whole-number floats), so no ground station has to know whether
  integers are byte-wise or C-cast encoded.

Security: on a link with signing, only signed frames may read or set parameters (a link that
``accept_unsigned`` lets unsigned frames in for the rest); ``allowed_sources`` is applied by the
caller before a message reaches here. Refusals are counted, never answered: answering an
unsigned reader would leak the tuning to anyone on the radio.
"""

from __future__ import annotations

import logging
import math
import struct
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, Protocol

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.mavlink.commands import Outgoing, RateLimitedLog
from mavservo.mavlink.origin import from_pinned, requester_of
from mavservo.mavlink.pacing import PerSender, RefusalDigest

log = logging.getLogger(__name__)


#: PARAM_SETs one sender may make per second (and in a burst): a ground station sets a value
#: at a time, a flood of 200/s used to cost 400 fsyncs a second (issue 32, finding 2).
SETS_PER_S = 10.0
SET_BURST = 30
#: At most one log line per kind of set outcome per this many seconds.
SET_LOG_INTERVAL_S = 1.0

PARAM_TYPES = ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET")
SERVICE_TYPES = (*PARAM_TYPES, "FILE_TRANSFER_PROTOCOL", "MISSION_REQUEST_LIST")

# MAVLink FTP (https://mavlink.io/en/services/ftp.html): the NAK answer and its error code.
FTP_OPCODE_NAK = 129
FTP_ERROR_UNKNOWN_COMMAND = 7
FTP_HEADER_BYTES = 12


@dataclass(frozen=True)
class WritePolicy:
    """Who may set parameters: a verified sender (a signed frame, or a source listed in
    ``allowed_sources``), or anyone when ``open`` (``mavlink.parameter_writers: anyone``).

    Why: one unauthenticated PARAM_SET reconfigured the aircraft (issue 32, finding 1); reading
    stays open (a ground station lists parameters before it signs anything)."""

    allowed_sources: frozenset[tuple[int, int]] = frozenset()
    open: bool = False

    def permits(self, signed: bool, sender: tuple[int, int], pinned: bool = True) -> bool:
        """``pinned``: the frame came from the address or connection the sender's identity
        is pinned to (:mod:`.origin`); on an unsigned link a listed source is one only there
        (issue 40: a stranger claiming 255/190 from another address set SRV1_TRIM)."""
        return self.open or signed or (pinned and sender in self.allowed_sources)

    def describe(self, signing: bool) -> str:
        """One line for ``mavservo check``: who may write parameters with this config."""
        if self.open:
            return "parameters: anyone on the link may set them (mavlink.parameter_writers: anyone)"
        who = []
        if signing:
            who.append("signed senders (mavlink.signing)")
        if self.allowed_sources:
            who.append(f"allowed_sources {_listed(self.allowed_sources)}")
        if not who:
            return (
                "parameters: read-only (no signing, no allowed_sources; nobody may set them; "
                "add allowed_sources or set mavlink.parameter_writers: anyone to open them)"
            )
        return "parameters: may be set by " + " and ".join(who) + "; read by anyone"

    def signing_advice(self, signing: bool) -> list[str]:
        """For ``mavservo check``: a line recommending signing when the link takes writes
        without it (commands always move servos; parameters when ``open`` or listed sources
        may set them), else none. Why: without signing an id is a claim; pinning a privileged
        id to the address it was first heard from (issue 40) is no authentication."""
        if signing:
            return []
        commands = (
            f"commands from allowed_sources {_listed(self.allowed_sources)}"
            if self.allowed_sources
            else "commands from anyone"
        )
        writes = [commands]
        if self.open:
            writes.append("parameter sets from anyone")
        elif self.allowed_sources:
            writes.append("parameter sets from the allowed sources")
        return [
            "recommended: mavlink.signing. Without it this link takes "
            + " and ".join(writes)
            + " on their word: a source id is a claim, held to the address it was first "
            "heard from, which is no authentication (docs/engineering/security.md)"
        ]


def _listed(sources: frozenset[tuple[int, int]]) -> str:
    return ", ".join(f"{s}/{c}" for s, c in sorted(sources))


@dataclass(frozen=True)
class SetResult:
    """What a PARAM_SET did: the value in force afterwards, and why a refused one was refused."""

    accepted: bool
    value: float
    reason: str = ""


class ParameterOwner(Protocol):
    """The one owner of the bridge's parameters, as the protocol sees it: names, values and
    changes. The protocol hands it a request it has checked for the wire (a name the component
    serves, a value decoded from its ``param_type``, a sender allowed to write, within the
    sender's rate); what the value means, whether the config's rules take it and how it takes
    effect are the owner's (``mavservo.control.LiveParameters``)."""

    def names(self, component_id: int) -> list[str]:
        """The parameters ``component_id`` serves, in index order (empty: none)."""
        ...

    def value(self, name: str) -> float:
        """The value in force now."""
        ...

    def set(self, name: str, value: float, sender: tuple[int, int]) -> SetResult:
        """Validate and apply a new value (or refuse it, saying why)."""
        ...


class ParameterServer:
    """PARAM_* and "not supported" answers for the components ``owner`` serves.

    ``announce(text)`` queues a STATUSTEXT (a refused PARAM_SET says why there, where the user
    looks); ``signing`` says whether the link signs (then unsigned frames are refused here).
    """

    def __init__(
        self,
        owner: ParameterOwner,
        component_ids: Iterable[int],
        *,
        signing: bool,
        announce: Callable[[str], None],
        writers: WritePolicy | None = None,
    ) -> None:
        self.owner = owner
        self.writers = writers if writers is not None else WritePolicy(open=True)
        self.component_ids = tuple(component_ids)
        self.signing = signing
        self._announce = announce
        self.counters: Counter[str] = Counter()
        self._set_rate = PerSender(SETS_PER_S, SET_BURST)
        self._log = RateLimitedLog(SET_LOG_INTERVAL_S)
        self._refusals = RefusalDigest()
        self._now: float | None = None

    # ------------------------------------------------------------------ input

    def handle(
        self, msg: Any, system_id: int, sender: tuple[int, int], now: float | None = None
    ) -> list[Outgoing]:
        """A PARAM_*, FTP or mission request; replies for each component it is addressed to.

        ``now`` (the core's clock) paces each sender's sets and refusal texts; None (unit
        tests of the protocol alone) paces nothing."""
        self._now = now
        kind = msg.get_type()
        targets = self._addressed(msg, system_id)
        if not targets:
            return []
        if kind in PARAM_TYPES and self.signing and not getattr(msg, "_signed", False):
            self.counters["unsigned_refused"] += 1
            return []
        if len(targets) > 1 and kind == "PARAM_REQUEST_LIST":
            targets = [cid for cid in targets if self.owner.names(cid)]
        elif len(targets) > 1:  # a broadcast: one answer, from the component that owns it
            owner = self._owner(kind, msg, targets)
            if owner is None:
                self.counters["broadcast_unowned"] += 1
                return []
            targets = [owner]
        out: list[Outgoing] = []
        for component_id in targets:
            out.extend(self._handle_for(kind, msg, component_id, sender))
        return out

    def _owner(self, kind: str, msg: Any, targets: list[int]) -> int | None:
        """The one component that answers a broadcast (target component 0), or None.

        Why: a broadcast READ drew a value from 140 and a PARAM_ERROR from 154, a broadcast
        gimbal PARAM_SET was applied twice, a broadcast FTP request two NAKs (issue 32,
        finding 3). A name is owned by the most specific component serving it (a gimbal's own
        ``GMBn_*`` by the gimbal, the rest by the servo component); a name nobody serves gets
        no answer; lists are per component by the protocol (a ground station enumerates
        components that way); everything else is answered by the first (servo) component."""
        if kind in ("PARAM_SET", "PARAM_REQUEST_READ") and (
            kind == "PARAM_SET" or int(msg.param_index) < 0
        ):
            name = _param_id(msg.param_id)
            serving = [cid for cid in targets if name in self.owner.names(cid)]
            return serving[-1] if serving else None
        return targets[0]

    def _addressed(self, msg: Any, system_id: int) -> list[int]:
        """Our components ``msg`` targets: one, or all of them for component 0."""
        if getattr(msg, "target_system", 0) not in (0, system_id):
            return []
        target = getattr(msg, "target_component", 0)
        if target == 0:
            return list(self.component_ids)
        return [target] if target in self.component_ids else []

    def _handle_for(
        self, kind: str, msg: Any, component_id: int, sender: tuple[int, int]
    ) -> list[Outgoing]:
        if kind == "PARAM_REQUEST_LIST":
            return self._request_list(component_id)
        if kind == "PARAM_REQUEST_READ":
            return self._request_read(msg, component_id, sender)
        if kind == "PARAM_SET":
            signed = bool(getattr(msg, "_signed", False))
            if not self.writers.permits(signed, sender, from_pinned(msg)):
                return self._not_permitted(msg, component_id, sender)
            return self._set(msg, component_id, sender)
        if kind == "FILE_TRANSFER_PROTOCOL":
            return self._ftp_nak(msg, component_id)
        if kind == "MISSION_REQUEST_LIST":
            self.counters["mission_unsupported"] += 1
            ack = mavlink2.MAVLink_mission_ack_message(
                sender[0],
                sender[1],
                mavlink2.MAV_MISSION_UNSUPPORTED,
                getattr(msg, "mission_type", 0),
            )
            return [(component_id, ack)]
        return []

    def _request_list(self, component_id: int) -> list[Outgoing]:
        """Every value of the component, in index order: the caller paces them (answers go
        through :class:`~mavservo.mavlink.answers.AnswerQueue`, per requester, in budget)."""
        names = self.owner.names(component_id)
        self.counters["list_requests"] += 1
        return [(component_id, self._value(names, index)) for index in range(len(names))]

    def _request_read(self, msg: Any, component_id: int, sender: tuple[int, int]) -> list[Outgoing]:
        names = self.owner.names(component_id)
        self.counters["read_requests"] += 1
        index = int(msg.param_index)
        name = _param_id(msg.param_id)
        if index >= 0:
            if index >= len(names):
                return [self._error(component_id, sender, name, index, "DOES_NOT_EXIST")]
            return [(component_id, self._value(names, index))]
        if name not in names:
            return [self._error(component_id, sender, name, -1, "DOES_NOT_EXIST")]
        return [(component_id, self._value(names, names.index(name)))]

    def _set(self, msg: Any, component_id: int, sender: tuple[int, int]) -> list[Outgoing]:
        names = self.owner.names(component_id)
        name = _param_id(msg.param_id)
        if name not in names:
            self.counters["set_unknown"] += 1
            return [self._error(component_id, sender, name, -1, "DOES_NOT_EXIST")]
        # per identity and origin: a flood claiming the station's ids from another address
        # spends its own bucket, not the station's (issue 40: 0 of 10 sets applied)
        if self._now is not None and not self._set_rate.allow(requester_of(msg), self._now):
            self.counters["set_rate_limited"] += 1
            self._refused(
                sender,
                f"{name}: more than {SETS_PER_S:g} sets/s from {sender[0]}/{sender[1]}, ignored",
            )
            return []
        value = decode_param_value(float(msg.param_value), int(msg.param_type))
        if value is None:
            self.counters["set_bad_type"] += 1
            self._refused(sender, f"{name}: param_type {int(msg.param_type)} not supported")
            return self._refusal(component_id, sender, names, name, "TYPE_UNSUPPORTED")
        result = self.owner.set(name, value, sender)
        if result.accepted:
            self.counters["set_accepted"] += 1
            self._log_set(
                "accepted", "parameter %s set to %g by %d/%d", name, result.value, *sender
            )
            return [(component_id, self._value(names, names.index(name)))]
        self.counters["set_refused"] += 1
        self._log_set(
            "refused",
            "parameter %s = %s from %d/%d refused: %s",
            name,
            value,
            *sender,
            result.reason,
        )
        self._refused(
            sender, f"{name} {value:g} refused: {result.reason.removeprefix(name + ': ')}"
        )
        return self._refusal(component_id, sender, names, name, "VALUE_OUT_OF_RANGE")

    def _refusal(
        self, component_id: int, sender: tuple[int, int], names: list[str], name: str, error: str
    ) -> list[Outgoing]:
        """PARAM_ERROR with ``error``, then the value still in force (for older clients)."""
        out = [self._error(component_id, sender, name, -1, error)]
        if name in names:
            out.append((component_id, self._value(names, names.index(name))))
        return out

    def _log_set(self, kind: str, line: str, *args: Any) -> None:
        """One log line per kind (accepted, refused) a second at most; the rest counted."""
        quiet = self._log.quiet_since_last(kind, 0.0 if self._now is None else self._now)
        if self._now is not None and quiet is None:
            return
        log.warning(line + (f" ({quiet} more since the last line)" if quiet else ""), *args)

    def _refused(self, sender: tuple[int, int], text: str) -> None:
        """A refusal for the ground station: the first of a sender's second at once, the
        repeats collapsed into one text with their count (:meth:`periodic`)."""
        if self._now is None:
            self._announce(text)
            return
        said = self._refusals.note(sender, text, self._now)
        if said is not None:
            self._announce(said)

    def _not_permitted(
        self, msg: Any, component_id: int, sender: tuple[int, int]
    ) -> list[Outgoing]:
        """A PARAM_SET from a sender not allowed to write: PARAM_ERROR PERMISSION_DENIED (the
        ground station says why instead of timing out) and the value in force, counted;
        nothing changes."""
        self.counters["set_not_permitted"] += 1
        name = _param_id(msg.param_id)
        names = self.owner.names(component_id)
        return self._refusal(component_id, sender, names, name, "PERMISSION_DENIED")

    def _ftp_nak(self, msg: Any, component_id: int) -> list[Outgoing]:
        """Every FTP request is answered NAK "unknown command" at once (MAVProxy then falls back
        to PARAM_REQUEST_LIST instead of waiting for its FTP time-out)."""
        self.counters["ftp_refused"] += 1
        request = bytes(msg.payload)
        if len(request) < FTP_HEADER_BYTES:
            return []
        sequence = int.from_bytes(request[0:2], "little")
        session, opcode = request[2], request[3]
        header = (
            ((sequence + 1) & 0xFFFF).to_bytes(2, "little")
            + bytes([session, FTP_OPCODE_NAK, 1, opcode, 0, 0])
            + bytes(4)
        )
        payload = list(header + bytes([FTP_ERROR_UNKNOWN_COMMAND]))
        payload += [0] * (251 - len(payload))
        reply = mavlink2.MAVLink_file_transfer_protocol_message(
            msg.target_network, msg.get_srcSystem(), msg.get_srcComponent(), payload
        )
        return [(component_id, reply)]

    # ------------------------------------------------------------------ time

    def periodic(self, now: float | None = None) -> list[Outgoing]:
        """At ``now``, the summaries of refusals collapsed in the last second (as STATUSTEXT
        through ``announce``); nothing to send itself."""
        if now is not None:
            for text in self._refusals.due(now, "parameter refusals"):
                self._announce(text)
        return []

    # ------------------------------------------------------------------ messages

    def _value(self, names: list[str], index: int) -> Any:
        value = self.owner.value(names[index])
        return mavlink2.MAVLink_param_value_message(
            names[index].encode("ascii"),
            value if math.isfinite(value) else 0.0,
            mavlink2.MAV_PARAM_TYPE_REAL32,
            len(names),
            index,
        )

    def _error(
        self, component_id: int, sender: tuple[int, int], name: str, index: int, error: str
    ) -> Outgoing:
        self.counters[f"error_{error.lower()}"] += 1
        code = _PARAM_ERRORS[error]
        message = mavlink2.MAVLink_param_error_message(
            sender[0], sender[1], name.encode("ascii", "replace")[:16], index, code
        )
        return (component_id, message)


#: MAV_PARAM_ERROR (common.xml, tests/data/mavlink_xml/common.xml line 2917 ff.): pymavlink
#: 2.4.50's bundled dialect stops at READ_ONLY (5); the later codes are the XML's values.
_PARAM_ERRORS = {
    "DOES_NOT_EXIST": 1,
    "VALUE_OUT_OF_RANGE": 2,
    "PERMISSION_DENIED": 3,
    "COMPONENT_NOT_FOUND": 4,
    "READ_ONLY": 5,
    "TYPE_UNSUPPORTED": 6,
    "TYPE_MISMATCH": 7,
    "READ_FAIL": 8,
}

_INTEGER_TYPES = {
    mavlink2.MAV_PARAM_TYPE_UINT8: "<B",
    mavlink2.MAV_PARAM_TYPE_INT8: "<b",
    mavlink2.MAV_PARAM_TYPE_UINT16: "<H",
    mavlink2.MAV_PARAM_TYPE_INT16: "<h",
    mavlink2.MAV_PARAM_TYPE_UINT32: "<I",
    mavlink2.MAV_PARAM_TYPE_INT32: "<i",
}


def decode_param_value(value: float, param_type: int) -> float | None:
    """The number a PARAM_SET carries, by its ``param_type``; None for a type not supported.

    REAL32 is the value. An integer type is either C-cast (ArduPilot, MAVProxy: the float is
    the integer, e.g. 1.0) or byte-wise (the MAVLink parameter protocol, QGroundControl: the
    integer's bytes in the float's, e.g. 1.4e-45 for 1): a whole number is taken as C-cast
    (no byte-wise integer below 2**23 is a whole float), anything else is read byte-wise.
    Why: the type was ignored, so a byte-wise 1 arrived as 1.4e-45 (issue 32, finding 6).
    64-bit types cannot travel in a float32 and are refused.
    """
    if param_type == mavlink2.MAV_PARAM_TYPE_REAL32:
        return value
    layout = _INTEGER_TYPES.get(param_type)
    if layout is None:
        return None
    if math.isfinite(value) and value == int(value):
        return value
    raw = struct.pack("<f", value)
    size = struct.calcsize(layout)
    return float(struct.unpack(layout, raw[:size])[0])


def _param_id(raw: Any) -> str:
    """PARAM_* ``param_id``: up to 16 characters, NUL-padded when shorter."""
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", "replace")
    return str(raw).split("\x00", 1)[0][:16]
