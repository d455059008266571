"""DroneCAN on python-can frames, through the ``dronecan`` package: no hand-written DSDL.

The ``dronecan`` package (PyPI) owns the data types (it parses the DSDL definitions it ships)
and the transfer framing: tail byte, toggle bit, transfer CRC seeded with the data type's
signature. This module only moves between its ``Frame``/``Transfer`` objects and
``can.Message``, and reassembles received transfers with times handed in (the library's own
``TransferManager`` reads the clock, and profiles are pure).

The package parses every DSDL file it ships on import (about 0.6 s), so it is imported lazily,
on the first DroneCAN frame built or decoded: a configuration without DroneCAN servos never
pays for it.

Everything a remote node sends is hostile: a transfer that does not reassemble (a toggle out of
order, a frame without a start, a wrong CRC, a data type the library does not know, a payload
the library cannot unpack) is counted by reason in :class:`Reassembler.errors` and dropped;
nothing raises.
"""

from __future__ import annotations

import binascii
import functools
import importlib
import math
import struct
from collections import Counter
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import can

# uavcan.protocol.NodeStatus constants (uavcan/protocol/341.NodeStatus.uavcan)
HEALTH_OK, HEALTH_WARNING, HEALTH_ERROR, HEALTH_CRITICAL = 0, 1, 2, 3
MODE_OPERATIONAL, MODE_INITIALIZATION, MODE_MAINTENANCE, MODE_SOFTWARE_UPDATE = 0, 1, 2, 3
MODE_OFFLINE = 7
# uavcan.equipment.actuator.Command.command_type (uavcan/equipment/actuator/Command.uavcan)
COMMAND_TYPE_UNITLESS, COMMAND_TYPE_POSITION, COMMAND_TYPE_PWM = 0, 1, 4
# ardupilot.indication.SafetyState.status (ardupilot/indication/20000.SafetyState.uavcan)
SAFETY_ON, SAFETY_OFF = 0, 255
POWER_RATING_UNKNOWN = 127

# data type ids used here (the library's ``default_dtid`` of each; tests check they agree)
DTID_ARRAY_COMMAND = 1010
DTID_ACTUATOR_STATUS = 1011
DTID_NODE_STATUS = 341
DTID_GET_NODE_INFO = 1
DTID_ALLOCATION = 1
DTID_VOLZ_STATUS = 20020
DTID_HIMARK_INFO = 2019
DTID_SAFETY_STATE = 20000

# transfer priorities (libcanard's names): commands high, service answers medium, heartbeat low
PRIORITY_HIGH, PRIORITY_MEDIUM, PRIORITY_LOW = 8, 16, 24

MAX_COMMANDS_PER_TRANSFER = 15
"""``uavcan.equipment.actuator.ArrayCommand``: ``Command[<=15] commands``."""
NODE_STATUS_PERIOD_S = 1.0
"""Every node sends ``uavcan.protocol.NodeStatus`` at 1 Hz."""
OFFLINE_AFTER_S = 3.0
"""A node silent for this long is gone (the specification's ``OFFLINE_TIMEOUT_MS``)."""
MAX_FRAMES_PER_TRANSFER = 64
"""Longer transfers are dropped: nothing this project decodes needs more (bounds memory)."""
_MAX_PENDING = 64


def float16_inside(value: float, low: float, high: float) -> float:
    """The float16 nearest ``value`` that lies within ``[low, high]`` (both finite, positive,
    ``low <= value <= high``, with a float16 between them): a command field is float16 on the
    wire, and the nearest one may lie outside the range (2499 us is carried as 2500: float16
    steps by 2 between 2048 and 4096), which would put a pulse past a channel's limit."""
    (bits,) = struct.unpack("<H", struct.pack("<e", value))
    on_wire = struct.unpack("<e", struct.pack("<H", bits))[0]
    if on_wire > high:
        on_wire = struct.unpack("<e", struct.pack("<H", bits - 1))[0]
    elif on_wire < low:
        on_wire = struct.unpack("<e", struct.pack("<H", bits + 1))[0]
    return float(on_wire)


@functools.cache
def lib() -> ModuleType:
    """The ``dronecan`` package, imported on first use (see module docstring)."""
    # import_module rather than an import statement: the package has no type information, and
    # import_module's result is a ModuleType for mypy as well as at run time
    return importlib.import_module("dronecan")


def message_type(full_name: str) -> Any:
    """The library's message class for a DSDL full name (``uavcan.protocol.NodeStatus``)."""
    node: Any = lib()
    for part in full_name.split("."):
        node = getattr(node, part)
    return node


# ------------------------------------------------------------------------------ CAN identifiers
def is_message_frame(msg: can.Message) -> bool:
    """A (non-anonymous or anonymous) message frame: 29-bit, service bit clear."""
    return bool(msg.is_extended_id) and not msg.is_remote_frame and not msg.arbitration_id & 0x80


def source_node(msg: can.Message) -> int:
    """The sending node's id (0: anonymous)."""
    return int(msg.arbitration_id & 0x7F)


def message_dtid(msg: can.Message) -> int:
    """A message frame's data type id (an anonymous frame carries only its two low bits)."""
    if source_node(msg) == 0:
        return (msg.arbitration_id >> 8) & 0x3
    return (msg.arbitration_id >> 8) & 0xFFFF


def message_id(dtid: int, source: int, priority: int = PRIORITY_HIGH) -> int:
    """The 29-bit id of a message frame (source 1..127)."""
    return (priority & 0x1F) << 24 | (dtid & 0xFFFF) << 8 | (source & 0x7F)


@dataclass(frozen=True)
class ServiceFrameId:
    """The fields of a service frame's id."""

    dtid: int
    request: bool
    destination: int
    source: int


def service_fields(msg: can.Message) -> ServiceFrameId | None:
    """The service fields of ``msg``, None if it is not a service frame."""
    if not msg.is_extended_id or msg.is_remote_frame or not msg.arbitration_id & 0x80:
        return None
    arb = msg.arbitration_id
    return ServiceFrameId((arb >> 16) & 0xFF, bool(arb & 0x8000), (arb >> 8) & 0x7F, arb & 0x7F)


# ------------------------------------------------------------------------------------ encoding
def _to_messages(transfer: Any) -> list[can.Message]:
    return [
        can.Message(arbitration_id=frame.message_id, is_extended_id=True, data=bytes(frame.bytes))
        for frame in transfer.to_frames()
    ]


def encode_message(
    payload: Any, source: int, transfer_id: int, priority: int = PRIORITY_HIGH
) -> list[can.Message]:
    """The frames of one message transfer of ``payload`` (a library message object)."""
    transfer = lib().transport.Transfer(
        transfer_id=transfer_id & 0x1F,
        source_node_id=source,
        payload=payload,
        transfer_priority=priority,
    )
    return _to_messages(transfer)


def encode_anonymous(payload: Any, discriminator: int, transfer_id: int) -> list[can.Message]:
    """An anonymous (source 0) single-frame message: what a node without an id sends."""
    transfer = lib().transport.Transfer(
        transfer_id=transfer_id & 0x1F,
        source_node_id=0,
        payload=payload,
        transfer_priority=PRIORITY_LOW,
        discriminator=discriminator & 0x3FFF,
    )
    return _to_messages(transfer)


def encode_service(
    payload: Any,
    *,
    source: int,
    destination: int,
    transfer_id: int,
    request: bool,
    priority: int = PRIORITY_MEDIUM,
) -> list[can.Message]:
    """The frames of a service request or response (``payload`` in that mode)."""
    transfer = lib().transport.Transfer(
        transfer_id=transfer_id & 0x1F,
        source_node_id=source,
        dest_node_id=destination,
        payload=payload,
        transfer_priority=priority,
        request_not_response=request,
        service_not_message=True,
    )
    return _to_messages(transfer)


def array_command(commands: list[tuple[int, int, float]]) -> Any:
    """``ArrayCommand`` of ``(actuator_id, command_type, value)`` (at most 15)."""
    actuator = lib().uavcan.equipment.actuator
    return actuator.ArrayCommand(
        commands=[
            actuator.Command(actuator_id=a, command_type=t, command_value=v) for a, t, v in commands
        ]
    )


def safety_state(off: bool) -> Any:
    """``ardupilot.indication.SafetyState``: SAFETY_OFF (255) lets an ArduPilot peripheral
    drive its outputs, anything else (SAFETY_ON, 0) keeps them off."""
    state = lib().ardupilot.indication.SafetyState()
    state.status = SAFETY_OFF if off else SAFETY_ON
    return state


def node_status(uptime_s: float, health: int, mode: int, vendor_code: int = 0) -> Any:
    return lib().uavcan.protocol.NodeStatus(
        uptime_sec=max(0, min(0xFFFFFFFF, int(uptime_s))),
        health=health,
        mode=mode,
        sub_mode=0,
        vendor_specific_status_code=vendor_code & 0xFFFF,
    )


def float16(value: float) -> float:
    """``value`` as float16 would carry it (what a receiver decodes), NaN kept."""
    dronecan = lib()
    if math.isnan(value):
        return math.nan
    return float(dronecan.transport.f32_from_f16(dronecan.transport.f16_from_f32(value)))


# ------------------------------------------------------------------------------------ decoding
@dataclass(frozen=True)
class Received:
    """One transfer that reassembled and decoded: the library's payload object and its ids."""

    payload: Any
    dtid: int
    source: int
    transfer_id: int
    service: bool
    request: bool
    destination: int | None
    full_name: str
    priority: int = PRIORITY_MEDIUM


def _error_reason(exc: Exception) -> str:
    text = str(exc)
    for needle, reason in (
        ("CRC", "crc"),
        ("Toggle", "toggle"),
        ("Unrecognised", "unknown_type"),
        ("Transfer ID", "transfer_id"),
        ("transmission", "sequence"),
    ):
        if needle in text:
            return reason
    return "malformed"


class Reassembler:
    """Frames in, whole transfers out, for the frames one party accepts.

    Pure: each frame comes with its receive time; a transfer whose next frame does not come
    within ``timeout_s`` is dropped (counted ``expired``) when the next frame arrives. Errors
    are counted in :attr:`errors` by reason (``crc``, ``toggle``, ``orphan``, ``unknown_type``,
    ``malformed``, ``too_long``, ``expired``, ``empty``); nothing raises.
    """

    def __init__(self, timeout_s: float = 1.0, reuse_payloads: bool = False) -> None:
        self.timeout_s = timeout_s
        self.errors: Counter[str] = Counter()
        self._pending: dict[tuple[int, int], tuple[float, list[bytes]]] = {}
        self._reused: dict[int, tuple[Any, Any] | None] | None = {} if reuse_payloads else None
        """``reuse_payloads``: message types made of primitive fields only are unpacked into
        one payload object per type, kept (see :meth:`_decode_reused`); the caller must be done
        with a payload before it pushes the next frame."""

    def push(self, msg: can.Message, now: float) -> Received | None:
        """Feed one frame; the decoded transfer when it was the last one, else None."""
        data = bytes(msg.data)
        if not msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame:
            return None
        if not data or len(data) > 8:
            self.errors["empty" if not data else "malformed"] += 1
            return None
        self._expire(now)
        tail = data[-1]
        key = (int(msg.arbitration_id), tail & 0x1F)
        start, end, toggle = bool(tail & 0x80), bool(tail & 0x40), tail & 0x20
        if start:
            if key in self._pending:
                self.errors["sequence"] += 1  # a new transfer restarts the unfinished one
            if toggle:
                self.errors["toggle"] += 1
                self._pending.pop(key, None)
                return None
            frames = [data]
        else:
            pending = self._pending.pop(key, None)
            if pending is None:
                self.errors["orphan"] += 1
                return None
            frames = pending[1] + [data]
            expected = 0x20 if len(pending[1]) % 2 else 0
            if toggle != expected:
                self.errors["toggle"] += 1
                return None
        if not end:
            if len(frames) >= MAX_FRAMES_PER_TRANSFER:
                self.errors["too_long"] += 1
                return None
            if len(self._pending) >= _MAX_PENDING:
                oldest = min(self._pending, key=lambda k: self._pending[k][0])
                del self._pending[oldest]
                self.errors["expired"] += 1
            self._pending[key] = (now, frames)
            return None
        return self._decode(int(msg.arbitration_id), frames)

    def _expire(self, now: float) -> None:
        stale = [k for k, (t, _) in self._pending.items() if now - t > self.timeout_s]
        for key in stale:
            del self._pending[key]
            self.errors["expired"] += 1

    def _decode(self, arbitration_id: int, frames: list[bytes]) -> Received | None:
        if self._reused is not None and not arbitration_id & 0x80 and arbitration_id & 0x7F:
            entry = self._reusable((arbitration_id >> 8) & 0xFFFF, self._reused)
            if entry is not None:
                return self._decode_reused(arbitration_id, frames, *entry)
        dronecan = lib()
        transport = dronecan.transport
        transfer = transport.Transfer()
        try:
            transfer.from_frames([transport.Frame(arbitration_id, data) for data in frames])
            full_name = dronecan.get_dronecan_data_type(transfer.payload).full_name
        except Exception as exc:  # a hostile payload may trip anything in a third-party decoder
            self.errors[_error_reason(exc)] += 1
            return None
        return Received(
            payload=transfer.payload,
            dtid=int(transfer.data_type_id),
            source=int(transfer.source_node_id or 0),
            transfer_id=int(transfer.transfer_id),
            service=bool(transfer.service_not_message),
            request=bool(transfer.request_not_response),
            destination=transfer.dest_node_id,
            full_name=str(full_name),
            priority=(arbitration_id >> 24) & 0x1F,
        )

    @staticmethod
    def _reusable(dtid: int, cache: dict[int, tuple[Any, Any] | None]) -> tuple[Any, Any] | None:
        """The package's data type of message ``dtid`` and a payload object to unpack it into,
        when every field of it is a primitive (or void): unpacking then rewrites every field, so
        the object can be reused. None otherwise (arrays, nested types, unknown ids), decided
        once per id from the package's parsed DSDL."""
        if dtid in cache:
            return cache[dtid]
        dronecan = lib()
        dsdl = dronecan.dsdl
        datatype = dronecan.DATATYPES.get((dtid, dsdl.CompoundType.KIND_MESSAGE))
        entry = None
        if datatype is not None and all(
            isinstance(field.type, (dsdl.PrimitiveType, dsdl.VoidType)) for field in datatype.fields
        ):
            kept = datatype()
            # ``_unpack`` is the package's own (private) unpacking: a release without it takes
            # the public path below instead of failing every transfer
            if callable(getattr(kept, "_unpack", None)):
                entry = (datatype, kept)
        if len(cache) < _MAX_PENDING:  # bounded: ids come off the wire
            cache[dtid] = entry
        return entry

    def _decode_reused(
        self, arbitration_id: int, frames: list[bytes], datatype: Any, payload: Any
    ) -> Received | None:
        """What ``Transfer.from_frames`` does for a message (the transfer CRC seeded with the
        type's, then the package's own unpacking), into a kept payload object: building a new
        one is most of the package's cost (every field constructed, float16 ones converted).
        Tail bytes, toggles and transfer ids were checked by :meth:`push`. The CRC is the
        package's CRC-16-CCITT (polynomial 0x1021, not reflected) from ``binascii.crc_hqx``, the
        same function in C (tests check the two agree)."""
        data = b"".join(frame[:-1] for frame in frames)
        try:
            if len(frames) > 1:
                crc = data[0] | data[1] << 8
                data = data[2:]
                if binascii.crc_hqx(data, datatype.base_crc) != crc:
                    self.errors["crc"] += 1
                    return None
            payload._unpack(lib().transport.bits_from_bytes(data), True)
        except Exception as exc:  # a hostile payload may trip anything in a third-party decoder
            self.errors[_error_reason(exc)] += 1
            return None
        return Received(
            payload=payload,
            dtid=int(datatype.default_dtid),
            source=arbitration_id & 0x7F,
            transfer_id=frames[-1][-1] & 0x1F,
            service=False,
            request=False,
            destination=None,
            full_name=str(datatype.full_name),
            priority=(arbitration_id >> 24) & 0x1F,
        )
