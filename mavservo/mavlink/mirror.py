"""Mirror the autopilot's own servo outputs onto the CAN servos.

Two streams carry them: SERVO_OUTPUT_RAW (ArduPilot and PX4; PWM us, 16 channels per message in
MAVLink 2, ``port`` selecting the block) and ACTUATOR_OUTPUT_STATUS (PX4; up to 32 values and an
``active`` field). ``active`` is read as the sender fills it
(:mod:`~mavservo.mavlink.autopilot_flavour`): common.xml declares it a bitmask, PX4 puts the
number of outputs there (``msg.active = act.noutputs``, streams/ACTUATOR_OUTPUT_STATUS.hpp), so
from a PX4 outputs 1..active are valid; read as a mask, PX4's 16 selected output 5 alone
(measured against PX4 SITL: output 1 missed 247 of 247 changes).

Port semantics chosen here: channel = port * ``servo_output_port_width`` + i (1-based i); the
width is 16 by default because ArduPilot puts servo 17..32 in port 1, while the spec's older text
says a port is a set of 8 outputs (set the width to 8 for such senders).
A PWM of 0 means "no pulse" (ArduPilot reports disabled outputs that way) and is never mirrored.
PX4 fills ACTUATOR_OUTPUT_STATUS with raw output values (PWM us for PWM outputs), so values are
converted to normalized [-1, 1] around 1500 us by default; a sender that already sends normalized
values is configured with ``actuator_output_status_units: normalized``.

Only changed values go to the backend (the scheduler re-sends the last setpoint by itself); a value
that was held off by an explicit command, or forgotten after failsafe, is applied again at the next
sample. Pure: no I/O, time comes in as an argument.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Callable
from typing import Any

from mavservo.mavlink.arbitration import CommandHold
from mavservo.mavlink.backend import ActuatorBackend
from mavservo.mavlink.settings import MavlinkSettings

log = logging.getLogger(__name__)

SERVO_OUTPUT_RAW_CHANNELS = 16
#: ACTUATOR_OUTPUT_STATUS.actuator has 32 slots (common.xml, message 375).
ACTUATOR_SLOTS = 32
PWM_CENTRE_US = 1500.0
PWM_HALF_RANGE_US = 500.0


class Mirror:
    """Turns autopilot output streams into backend setpoints for the channels we map."""

    def __init__(
        self,
        backend: ActuatorBackend,
        settings: MavlinkSettings,
        hold: CommandHold,
        active_is_count: Callable[[], bool] = lambda: False,
    ):
        self._backend = backend
        self._settings = settings
        self._hold = hold
        #: whether the autopilot in force fills ACTUATOR_OUTPUT_STATUS.active with a count (PX4)
        self._active_is_count = active_is_count
        self._last_servo: dict[int, float] = {}
        self._last_actuator: dict[int, float] = {}
        self.counters: Counter[str] = Counter()

    def reset(self) -> None:
        """Forget what was applied, so the next sample drives every mapped channel again."""
        self._last_servo.clear()
        self._last_actuator.clear()

    def handle(self, msg: Any, now: float) -> None:
        """Feed one message that came from the watched autopilot."""
        kind = msg.get_type()
        if kind == "SERVO_OUTPUT_RAW" and self._settings.mirror_servo_output_raw:
            self._servo_output_raw(msg, now)
        elif kind == "ACTUATOR_OUTPUT_STATUS" and self._settings.mirror_actuator_output_status:
            self._actuator_output_status(msg, now)

    def _servo_output_raw(self, msg: Any, now: float) -> None:
        mapped = self._backend.mapped_servo_channels()
        base = int(msg.port) * self._settings.servo_output_port_width
        for i in range(1, SERVO_OUTPUT_RAW_CHANNELS + 1):
            channel = base + i
            if channel not in mapped:
                continue
            pwm = float(getattr(msg, f"servo{i}_raw", 0) or 0)
            if pwm == 0:
                self.counters["zero_pwm_ignored"] += 1
                continue
            self._apply_servo(channel, pwm, now)

    def _apply_servo(self, channel: int, pwm: float, now: float) -> None:
        if not self._hold.mirror_allowed(("servo", channel), now):
            self._last_servo.pop(channel, None)
            self.counters["held_by_command"] += 1
            return
        if self._last_servo.get(channel) == pwm:
            return
        result = self._backend.apply_servo_output(channel, pwm, "servo_output_raw", now)
        self.counters["applied" if result.ok else f"refused_{result.outcome.name.lower()}"] += 1
        if result.ok:
            self._last_servo[channel] = pwm
        else:
            log.debug("mirror: servo %d %.0f us refused: %s", channel, pwm, result.reason)

    def _actuator_output_status(self, msg: Any, now: float) -> None:
        mapped = self._backend.mapped_actuator_indices()
        valid = self._valid_slots(int(msg.active))
        for slot, raw in enumerate(msg.actuator):
            index = slot + 1
            if index not in mapped or not valid(slot):
                continue
            value = self._normalize(float(raw))
            if value is None:
                self.counters["invalid_actuator_value"] += 1
                continue
            if not self._hold.mirror_allowed(("actuator", index), now):
                self._last_actuator.pop(index, None)
                self.counters["held_by_command"] += 1
                continue
            if self._last_actuator.get(index) == value:
                continue
            result = self._backend.apply_actuator(index, value, "actuator_output_status", now)
            self.counters["applied" if result.ok else f"refused_{result.outcome.name.lower()}"] += 1
            if result.ok:
                self._last_actuator[index] = value

    def _valid_slots(self, active: int) -> Callable[[int], bool]:
        """Which 0-based slots ``active`` declares valid: the first ``active`` ones from a PX4
        (a count; more than the 32 slots is garbage and counted), the set bits otherwise."""
        if self._active_is_count():
            if active > ACTUATOR_SLOTS:
                self.counters["active_count_out_of_range"] += 1
                return lambda slot: False
            return lambda slot: slot < active
        return lambda slot: bool((active >> slot) & 1)

    def _normalize(self, raw: float) -> float | None:
        """Convert a stream value to [-1, 1]; None for 'unused' (0 PWM) or non-finite values."""
        if not math.isfinite(raw):
            return None
        if self._settings.actuator_output_status_units == "pwm":
            if raw == 0:
                return None
            raw = (raw - PWM_CENTRE_US) / PWM_HALF_RANGE_US
        return max(-1.0, min(1.0, raw))
