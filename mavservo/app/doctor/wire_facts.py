"""Frames the doctor reads without any servo profile: ODrive's heartbeat and DroneCAN's
NodeStatus, the two "I am here" messages of their families (both pushed by every node on its
own, so they are heard while listening only).

Written from the vendors' documents, not from the profiles:

* ODrive CANSimple (ODrive docs, "CAN Protocol", v0.6): 11-bit id ``node_id << 5 | cmd_id``;
  ``Heartbeat`` is cmd 0x01, little-endian ``Axis_Error`` u32, ``Axis_State`` u8,
  ``Procedure_Result`` u8, ``Trajectory_Done_Flag`` u8, sent every ``heartbeat_msg_rate_ms``
  (100 ms by default). The error bits are ``ODrive.Error`` and the states ``ODrive.AxisState``
  of the same document's API reference (the DBC ODrive publishes carries the same value tables;
  tests/app/test_doctor.py checks this table against it).
* DroneCAN (DSDL ``uavcan.protocol.NodeStatus``, data type id 341): a single-frame message
  transfer; 29-bit id ``priority << 24 | dtid << 8 | source node`` (service bit 7 clear);
  payload ``uptime_sec`` u32 LE, then ``health`` u2, ``mode`` u3, ``sub_mode`` u3 in one byte
  (most significant bits first), ``vendor_specific_status_code`` u16; the tail byte last.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import can

ODRIVE_GET_VERSION = 0x00
ODRIVE_HEARTBEAT = 0x01

#: ODrive.AxisState (ODrive API reference, v0.6).
ODRIVE_AXIS_STATES = {
    0: "UNDEFINED",
    1: "IDLE",
    2: "STARTUP_SEQUENCE",
    3: "FULL_CALIBRATION_SEQUENCE",
    4: "MOTOR_CALIBRATION",
    6: "ENCODER_INDEX_SEARCH",
    7: "ENCODER_OFFSET_CALIBRATION",
    8: "CLOSED_LOOP_CONTROL",
    9: "LOCKIN_SPIN",
    10: "ENCODER_DIR_FIND",
    11: "HOMING",
    12: "ENCODER_HALL_POLARITY_CALIBRATION",
    13: "ENCODER_HALL_PHASE_CALIBRATION",
}

#: ODrive.Error bits (ODrive API reference, v0.6).
ODRIVE_ERRORS = {
    0x00000001: "INITIALIZING",
    0x00000002: "SYSTEM_LEVEL",
    0x00000004: "TIMING_ERROR",
    0x00000008: "MISSING_ESTIMATE",
    0x00000010: "BAD_CONFIG",
    0x00000020: "DRV_FAULT",
    0x00000040: "MISSING_INPUT",
    0x00000100: "DC_BUS_OVER_VOLTAGE",
    0x00000200: "DC_BUS_UNDER_VOLTAGE",
    0x00000400: "DC_BUS_OVER_CURRENT",
    0x00000800: "DC_BUS_OVER_REGEN_CURRENT",
    0x00001000: "CURRENT_LIMIT_VIOLATION",
    0x00002000: "MOTOR_OVER_TEMP",
    0x00004000: "INVERTER_OVER_TEMP",
    0x00008000: "VELOCITY_LIMIT_VIOLATION",
    0x00010000: "POSITION_LIMIT_VIOLATION",
    0x01000000: "WATCHDOG_TIMER_EXPIRED",
    0x02000000: "ESTOP_REQUESTED",
    0x04000000: "SPINOUT_DETECTED",
    0x08000000: "BRAKE_RESISTOR_DISARMED",
    0x10000000: "THERMISTOR_DISCONNECTED",
    0x40000000: "CALIBRATION_ERROR",
}

CLOSED_LOOP_CONTROL = 8
IDLE = 1


@dataclass(frozen=True)
class ODriveHeartbeat:
    node_id: int
    axis_error: int
    axis_state: int

    @property
    def state_name(self) -> str:
        return ODRIVE_AXIS_STATES.get(self.axis_state, f"state {self.axis_state}")

    @property
    def error_names(self) -> list[str]:
        names = [name for bit, name in ODRIVE_ERRORS.items() if self.axis_error & bit]
        unknown = self.axis_error & ~sum(ODRIVE_ERRORS)
        return names + ([f"0x{unknown:08X}"] if unknown else [])


def odrive_heartbeat(msg: can.Message) -> ODriveHeartbeat | None:
    """``msg`` as an ODrive heartbeat, or None when it cannot be one."""
    if msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame:
        return None
    if msg.arbitration_id & 0x1F != ODRIVE_HEARTBEAT or len(msg.data) < 5:
        return None
    axis_error, axis_state = struct.unpack_from("<IB", bytes(msg.data))
    if axis_state not in ODRIVE_AXIS_STATES:
        return None
    return ODriveHeartbeat(msg.arbitration_id >> 5, axis_error, axis_state)


ACTUATOR_STATUS_DTID = 1011


def actuator_status(msg: can.Message) -> tuple[int, int] | None:
    """``(node id, actuator id)`` of the first frame of a DroneCAN
    ``uavcan.equipment.actuator.Status`` (DSDL 1011: ``actuator_id`` u8 first; 8 bytes of
    payload, so a two-frame transfer whose first frame starts with the 2-byte transfer CRC)."""
    arbitration_id = msg.arbitration_id
    if not msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame or arbitration_id & 0x80:
        return None
    if (arbitration_id >> 8) & 0xFFFF != ACTUATOR_STATUS_DTID:
        return None
    data = bytes(msg.data)
    if len(data) < 2 or not data[-1] & 0x80:  # not the start of a transfer
        return None
    single = bool(data[-1] & 0x40)
    at = 0 if single else 2
    if len(data) - 1 <= at or arbitration_id & 0x7F == 0:
        return None
    return arbitration_id & 0x7F, data[at]


def odrive_version_request(node_id: int) -> can.Message:
    """``Get_Version`` (cmd 0x00) asked with a remote frame: a read (ODrive CAN protocol,
    message table; the answer's layout is the DBC's ``Get_Version``)."""
    return can.Message(
        arbitration_id=node_id << 5 | ODRIVE_GET_VERSION,
        is_remote_frame=True,
        dlc=8,
        is_extended_id=False,
    )


def odrive_version(msg: can.Message) -> tuple[int, str] | None:
    """``(node id, "hardware 3.6-56, firmware 0.6.10")`` from a ``Get_Version`` answer."""
    if msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame or len(msg.data) != 8:
        return None
    if msg.arbitration_id & 0x1F != ODRIVE_GET_VERSION:
        return None
    _, hw_major, hw_minor, variant, fw_major, fw_minor, fw_rev, unreleased = bytes(msg.data)
    firmware = f"{fw_major}.{fw_minor}.{fw_rev}" + (" (unreleased)" if unreleased else "")
    return msg.arbitration_id >> 5, f"hardware {hw_major}.{hw_minor}-{variant}, firmware {firmware}"


def robstride_device_id(msg: can.Message) -> tuple[int, str] | None:
    """``(motor id, "MCU id 0x...")`` from a Robstride private-protocol answer to "get device
    id" (RS0x manual, communication type 0: id ``0 << 24 | motor_id << 8 | 0xFE``, the 64-bit
    MCU unique id in the data)."""
    arbitration_id = msg.arbitration_id
    if not msg.is_extended_id or msg.is_remote_frame or len(msg.data) != 8:
        return None
    if arbitration_id >> 24 != 0 or arbitration_id & 0xFF != 0xFE:
        return None
    return (arbitration_id >> 8) & 0xFF, f"MCU id 0x{bytes(msg.data).hex()}"


DAMIAO_REGISTER_ID = 0x7FF
DAMIAO_READ = 0x33
DAMIAO_CTRL_MODE = 10
#: CTRL_MODE values (Damiao DM-J manual, register table: rid 10).
DAMIAO_MODES = {1: "mit", 2: "position-velocity", 3: "velocity", 4: "force-position"}


def damiao_mode_request(can_id: int) -> can.Message:
    """A read of the CTRL_MODE register on 0x7FF: ``[id lo, id hi, 0x33, 10, 0, 0, 0, 0]``
    (Damiao DM-J manual, "register read"; a read changes nothing)."""
    data = bytes([can_id & 0xFF, can_id >> 8, DAMIAO_READ, DAMIAO_CTRL_MODE, 0, 0, 0, 0])
    return can.Message(arbitration_id=DAMIAO_REGISTER_ID, data=data, is_extended_id=False)


def damiao_mode(msg: can.Message) -> tuple[int, str] | None:
    """``(motor id, mode name)`` from the answer to that read (on the master id, the same
    four-byte head, the value u32 LE after it)."""
    data = bytes(msg.data)
    if msg.is_extended_id or msg.is_remote_frame or len(data) != 8:
        return None
    if data[2] != DAMIAO_READ or data[3] != DAMIAO_CTRL_MODE:
        return None
    value = struct.unpack_from("<I", data, 4)[0]
    return data[0] | data[1] << 8, DAMIAO_MODES.get(value, f"mode {value}")


NODE_STATUS_DTID = 341
HEALTH = ("OK", "WARNING", "ERROR", "CRITICAL")
MODES = {
    0: "OPERATIONAL",
    1: "INITIALIZATION",
    2: "MAINTENANCE",
    3: "SOFTWARE_UPDATE",
    7: "OFFLINE",
}


@dataclass(frozen=True)
class NodeStatus:
    node_id: int
    uptime_s: int
    health: str
    mode: str


def node_status(msg: can.Message) -> NodeStatus | None:
    """``msg`` as a single-frame DroneCAN NodeStatus, or None."""
    arbitration_id = msg.arbitration_id
    if not msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame:
        return None
    if arbitration_id & 0x80 or (arbitration_id >> 8) & 0xFFFF != NODE_STATUS_DTID:
        return None
    data = bytes(msg.data)
    if len(data) != 8 or data[-1] & 0xC0 != 0xC0:  # start and end of transfer: one frame
        return None
    node_id = arbitration_id & 0x7F
    if node_id == 0:
        return None
    uptime, packed = struct.unpack_from("<IB", data)
    mode = (packed >> 3) & 0x7
    return NodeStatus(node_id, uptime, HEALTH[packed >> 6], MODES.get(mode, f"mode {mode}"))


#: MyActuator "Servo Motor Control Protocol" V4.2 (2024.05): requests on ``0x140 + id``,
#: replies on ``0x240 + id``, 8 data bytes (1.1.2); 2.29 "System Software Version Date Read"
#: (0xB2: the reply's bytes 4..7, little-endian, are the date as the decimal YYYYMMDD) and 2.32
#: "Motor Model Reading" (0xB5: bytes 1..7 are the model in ASCII, e.g. ``X8S2V10``). Both
#: send the command byte and seven zeros and change nothing. Cross-checked against
#: 2b-t/myactuator_rmd (``command_type.hpp``: the same bytes; its version-date response also
#: wants bytes 1..3 zero).
RMDX_REQUEST_BASE, RMDX_REPLY_BASE = 0x140, 0x240
RMDX_READ_VERSION_DATE, RMDX_READ_MODEL = 0xB2, 0xB5


def rmdx_identity_requests(can_id: int) -> list[can.Message]:
    """The model and software-date reads of an RMD-X (V4.2, 2.32 and 2.29)."""
    return [
        can.Message(
            arbitration_id=RMDX_REQUEST_BASE + can_id,
            data=bytes([command, 0, 0, 0, 0, 0, 0, 0]),
            is_extended_id=False,
        )
        for command in (RMDX_READ_MODEL, RMDX_READ_VERSION_DATE)
    ]


def rmdx_identity(msg: can.Message) -> tuple[int, str] | None:
    """``(motor id, "model X8S2V10")`` or ``(motor id, "software 2022-02-06")`` from an
    RMD-X's answer to a model or version-date read; None for any other frame, and for an
    answer whose text is not printable ASCII or whose date is not a date (a hostile or
    garbled frame prints nothing)."""
    if msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame or len(msg.data) != 8:
        return None
    can_id = msg.arbitration_id - RMDX_REPLY_BASE
    if not 1 <= can_id <= 32:
        return None
    data = bytes(msg.data)
    if data[0] == RMDX_READ_MODEL:
        text = data[1:].rstrip(b"\x00 ")
        if not text or not all(0x21 <= c < 0x7F for c in text):
            return None
        return can_id, f"model {text.decode('ascii')}"
    if data[0] == RMDX_READ_VERSION_DATE and data[1:4] == bytes(3):
        date = int.from_bytes(data[4:8], "little")
        year, month, day = date // 10000, date // 100 % 100, date % 100
        if not (2000 <= year <= 2099 and 1 <= month <= 12 and 1 <= day <= 31):
            return None
        return can_id, f"software {year:04d}-{month:02d}-{day:02d}"
    return None
