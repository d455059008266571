"""ESC_INFO and ESC_STATUS for QGroundControl's ESC view, on the same ESC numbers as
ESC_TELEMETRY_x_TO_y.

Mission Planner reads ESC_TELEMETRY_1_TO_4 .. 29_TO_32 (which :mod:`telemetry` sends);
QGroundControl builds its ESC page from ESC_INFO (290, slow: online bits, failure flags,
temperature) and ESC_STATUS (291, fast: rpm, voltage, current). Both carry four ESCs from
``index`` (0-based), so ESC_INFO/ESC_STATUS with ``index`` 16 describe the same four servos as
ESC_TELEMETRY_17_TO_20 (common.xml, messages 290 and 291, field ``index``: "Index of the first
ESC in this message", increment 4). Field meanings and units follow common.xml: temperature in
cdegC with INT16_MAX for "not supplied", rpm signed, voltage in V, current in A (NaN unknown),
``count`` the number of ESCs in all messages (fields at or above it are to be ignored), and
``info`` one online bit per ESC of the message.

Sans-I/O: statuses in, messages out.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

from mavservo.mavlink.backend import ServoStatus
from mavservo.mavlink.wip_messages import (
    ESC_CONNECTION_TYPE_CAN,
    ESC_FAILURE_GENERIC,
    ESC_FAILURE_MOTOR_STUCK,
    ESC_FAILURE_NONE,
    ESC_FAILURE_OVER_CURRENT,
    ESC_FAILURE_OVER_RPM,
    ESC_FAILURE_OVER_TEMPERATURE,
    ESC_FAILURE_OVER_VOLTAGE,
    INT16_MAX,
    EscInfo,
    EscStatus,
)
from mavservo.servos import Fault

#: ESC_INFO is the slow half: common.xml recommends 1 Hz.
ESC_INFO_HZ = 1.0
INT32_MAX = 2**31 - 1
UINT16_MAX = 65535

#: A servo's faults as ESC_FAILURE_FLAGS bits (anything without its own bit is GENERIC).
_FAILURE_BITS = (
    (Fault.OVER_CURRENT, ESC_FAILURE_OVER_CURRENT),
    (Fault.OVER_VOLTAGE, ESC_FAILURE_OVER_VOLTAGE),
    (Fault.OVER_TEMPERATURE, ESC_FAILURE_OVER_TEMPERATURE),
    (Fault.OVERSPEED, ESC_FAILURE_OVER_RPM),
    (Fault.STALL, ESC_FAILURE_MOTOR_STUCK),
)
_NAMED = Fault.OVER_CURRENT | Fault.OVER_VOLTAGE | Fault.OVER_TEMPERATURE
_NAMED |= Fault.OVERSPEED | Fault.STALL | Fault.NO_REPLY


def failure_flags(faults: Fault) -> int:
    """ESC_FAILURE_FLAGS of a servo's faults (NO_REPLY is the ``info`` bit, not a failure)."""
    flags = ESC_FAILURE_NONE
    for fault, bit in _FAILURE_BITS:
        if fault in faults:
            flags |= bit
    if faults & ~_NAMED:
        flags |= ESC_FAILURE_GENERIC
    return flags


def _slots(
    statuses: Sequence[ServoStatus], group: int, esc_number: Callable[[int], int]
) -> list[ServoStatus | None]:
    by_slot = {esc_number(s.index) - 1 - 4 * group: s for s in statuses}
    return [by_slot.get(slot) for slot in range(4)]


def _count(statuses: Sequence[ServoStatus], esc_number: Callable[[int], int]) -> int:
    return max((esc_number(s.index) for s in statuses), default=0)


def esc_info(
    statuses: Sequence[ServoStatus],
    group: int,
    esc_number: Callable[[int], int],
    *,
    counter: int,
    time_usec: int,
) -> EscInfo:
    """ESC_INFO for ESC numbers ``4 * group + 1`` .. ``+ 4``."""
    info = 0
    flags = [0] * 4
    temperatures = [INT16_MAX] * 4
    for slot, status in enumerate(_slots(statuses, group, esc_number)):
        if status is None or not status.online or status.state is None:
            continue
        info |= 1 << slot
        flags[slot] = failure_flags(status.state.faults)
        temperature = status.state.temperature_c
        if temperature is not None and math.isfinite(temperature):
            temperatures[slot] = int(max(-INT16_MAX, min(INT16_MAX - 1, round(temperature * 100))))
    return EscInfo(
        index=4 * group,
        time_usec=time_usec,
        counter=counter & UINT16_MAX,
        count=min(255, _count(statuses, esc_number)),
        connection_type=ESC_CONNECTION_TYPE_CAN,
        info=info,
        failure_flags=flags,
        error_count=[0] * 4,
        temperature=temperatures,
    )


def esc_status(
    statuses: Sequence[ServoStatus],
    group: int,
    esc_number: Callable[[int], int],
    *,
    time_usec: int,
) -> EscStatus:
    """ESC_STATUS for ESC numbers ``4 * group + 1`` .. ``+ 4`` ("rpm" = velocity in deg/s / 6,
    signed, as ESC_TELEMETRY's unsigned rpm without the sign)."""
    rpm = [0] * 4
    voltage = [math.nan] * 4
    current = [math.nan] * 4
    for slot, status in enumerate(_slots(statuses, group, esc_number)):
        state = status.state if status is not None and status.online else None
        if state is None:
            continue
        if math.isfinite(state.velocity_dps):
            rpm[slot] = int(max(-INT32_MAX, min(INT32_MAX, round(state.velocity_dps / 6.0))))
        if state.voltage_v is not None and math.isfinite(state.voltage_v):
            voltage[slot] = _float32(state.voltage_v)
        if math.isfinite(state.current_a):
            current[slot] = _float32(state.current_a)
    return EscStatus(
        index=4 * group, time_usec=time_usec, rpm=rpm, voltage=voltage, current=current
    )


def _float32(value: float) -> float:
    return max(-3.4e38, min(3.4e38, float(value)))
