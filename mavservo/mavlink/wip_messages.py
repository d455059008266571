"""MAVLink common messages pymavlink's bundled dialects leave out: ESC_INFO, ESC_STATUS,
COMPONENT_METADATA.

Why: pymavlink builds its dialects without the messages common.xml marks work-in-progress, but
QGroundControl builds its ESC view from ESC_INFO (290) and ESC_STATUS (291), and reads a
component's parameter metadata through COMPONENT_METADATA (397). The definitions below follow
``message_definitions/v1.0/common.xml`` of the MAVLink repository (commit f368676 of
component_metadata/, common.xml at de1e078): field names, types and array lengths as listed
there, the wire order (fields sorted by type size, largest first, stable) and the CRC_EXTRA seed
computed from them the way the MAVLink serialization page says ("CRC_EXTRA calculation": the
CRC-16/MCRF4XX of the message name and each field's type, name and array length). The tests
decode what these encode with a dialect pymavlink's own generator builds from that XML.

Each class is a pymavlink :class:`MAVLink_message`, so the bridge's per-connection encoders
send it like any generated message.
"""

from __future__ import annotations

import struct
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from pymavlink.generator.mavcrc import x25crc

#: C type -> struct code (MAVLink is little-endian)
_CODES = {
    "uint64_t": "Q",
    "uint32_t": "I",
    "int32_t": "i",
    "float": "f",
    "uint16_t": "H",
    "int16_t": "h",
    "uint8_t": "B",
    "char": "s",
}
_SIZES = {"Q": 8, "I": 4, "i": 4, "f": 4, "H": 2, "h": 2, "B": 1, "s": 1}


def crc_extra(name: str, wire_fields: list[tuple[str, str, int]]) -> int:
    """CRC_EXTRA of a message: (type, name, array length or 0) in wire order."""
    crc = x25crc()
    crc.accumulate_str(name + " ")
    for ctype, field_name, length in wire_fields:
        crc.accumulate_str(ctype + " ")
        crc.accumulate_str(field_name + " ")
        if length:
            crc.accumulate([length])
    return (crc.crc & 0xFF) ^ (crc.crc >> 8)


def _wire_order(fields: list[tuple[str, str, int]]) -> list[tuple[str, str, int]]:
    return sorted(fields, key=lambda f: -_SIZES[_CODES[f[0]]])  # sorted() is stable


def _struct(wire: list[tuple[str, str, int]]) -> struct.Struct:
    parts = []
    for ctype, _name, length in wire:
        code = _CODES[ctype]
        parts.append(f"{length or 1}{code}" if code == "s" or length else code)
    return struct.Struct("<" + "".join(parts))


class _WipMessage(mavlink2.MAVLink_message):
    """A message defined by its XML field list (declaration order)."""

    id: int
    msgname: str
    fields: list[tuple[str, str, int]]
    fieldnames: list[str]
    wire: list[tuple[str, str, int]]
    unpacker: struct.Struct
    crc_extra: int

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        cls.fieldnames = [name for _t, name, _n in cls.fields]
        cls.wire = _wire_order(cls.fields)
        cls.ordered_fieldnames = [name for _t, name, _n in cls.wire]
        cls.unpacker = _struct(cls.wire)
        cls.crc_extra = crc_extra(cls.msgname, cls.wire)

    def __init__(self, **values: Any) -> None:
        super().__init__(self.id, self.msgname)
        self._fieldnames = self.fieldnames
        self._instance_field = None
        self._instance_offset = -1
        for name in self.fieldnames:
            setattr(self, name, values[name])

    def pack(self, mav: Any, force_mavlink1: bool = False) -> bytes:
        flat: list[Any] = []
        for ctype, name, length in self.wire:
            value = getattr(self, name)
            if ctype == "char":
                flat.append(value.encode("ascii") if isinstance(value, str) else bytes(value))
            elif length:
                flat.extend(value)
            else:
                flat.append(value)
        return bytes(
            self._pack(mav, self.crc_extra, self.unpacker.pack(*flat), force_mavlink1=False)
        )


class EscInfo(_WipMessage):
    """ESC_INFO (290): per-ESC status for four ESCs from ``index`` (0-based), ~1 Hz."""

    id = 290
    msgname = "ESC_INFO"
    fields = [
        ("uint8_t", "index", 0),
        ("uint64_t", "time_usec", 0),
        ("uint16_t", "counter", 0),
        ("uint8_t", "count", 0),
        ("uint8_t", "connection_type", 0),
        ("uint8_t", "info", 0),
        ("uint16_t", "failure_flags", 4),
        ("uint32_t", "error_count", 4),
        ("int16_t", "temperature", 4),
    ]


class EscStatus(_WipMessage):
    """ESC_STATUS (291): rpm, voltage and current of four ESCs from ``index`` (0-based)."""

    id = 291
    msgname = "ESC_STATUS"
    fields = [
        ("uint8_t", "index", 0),
        ("uint64_t", "time_usec", 0),
        ("int32_t", "rpm", 4),
        ("float", "voltage", 4),
        ("float", "current", 4),
    ]


class ComponentMetadata(_WipMessage):
    """COMPONENT_METADATA (397): the URI and CRC32 of the component's general metadata file."""

    id = 397
    msgname = "COMPONENT_METADATA"
    fields = [
        ("uint32_t", "time_boot_ms", 0),
        ("uint32_t", "file_crc", 0),
        ("char", "uri", 100),
    ]


#: ESC_CONNECTION_TYPE_CAN (common.xml): the servos are on a CAN bus.
ESC_CONNECTION_TYPE_CAN = 2
#: ESC_INFO.temperature when the ESC did not supply it.
INT16_MAX = 32767
#: ESC_FAILURE_FLAGS (common.xml): the bits the bridge can tell from a servo's faults.
ESC_FAILURE_NONE = 0
ESC_FAILURE_OVER_CURRENT = 1
ESC_FAILURE_OVER_VOLTAGE = 2
ESC_FAILURE_OVER_TEMPERATURE = 4
ESC_FAILURE_OVER_RPM = 8
ESC_FAILURE_INCONSISTENT_CMD = 16
ESC_FAILURE_MOTOR_STUCK = 32
ESC_FAILURE_GENERIC = 64
