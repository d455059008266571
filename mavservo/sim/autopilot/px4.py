"""A simulated PX4 on its onboard MAVLink link, beside the simulated ArduPilot (:mod:`.stream`).

What it sends and does is read from PX4's source (PX4-Autopilot main bb59c637, Aug 2026; the
file and line of each fact below), so the bridge's PX4 paths are tested in CI without a PX4
build; the live test against PX4 SITL (tests/sim/test_px4_launcher.py) checks the same facts
against the real thing.

* HEARTBEAT with ``autopilot`` 12 (MAV_AUTOPILOT_PX4), a fixed wing (SIH airframe 10041).
* The onboard link's default streams (``src/modules/mavlink/mavlink_main.cpp``,
  MAVLINK_MODE_ONBOARD, lines 1709-1787): SERVO_OUTPUT_RAW_0 at 10 Hz, ATTITUDE (100 Hz there;
  ``attitude_hz`` here, 50 by default to spare CI), SYS_STATUS 5 Hz, GIMBAL_DEVICE_SET_ATTITUDE
  5 Hz; ACTUATOR_OUTPUT_STATUS is not streamed until a SET_MESSAGE_INTERVAL asks for it, which
  PX4 accepts for any stream it has (``MavlinkReceiver::set_message_interval``). No
  AUTOPILOT_STATE_FOR_GIMBAL_DEVICE: PX4 streams that only in MAVLINK_MODE_GIMBAL.
* ACTUATOR_OUTPUT_STATUS with ``active`` = the number of outputs, not a bitmask
  (``streams/ACTUATOR_OUTPUT_STATUS.hpp`` line 68: ``msg.active = act.noutputs``; 16 outputs in
  SITL) and the outputs in their natural units, PWM us (``msg/ActuatorOutputs.msg``).
* The gimbal manager (``src/modules/gimbal/output_mavlink.cpp``, OutputMavlinkV2::update):
  MAV_CMD_REQUEST_MESSAGE(GIMBAL_DEVICE_INFORMATION) to every component (target 0/0) every
  second until a device answers, at any time after boot (no search window as ArduPilot's);
  GIMBAL_DEVICE_SET_ATTITUDE all the while, to component 0 until the device is found, NaN until
  someone demands an attitude, with YAW_IN_VEHICLE_FRAME, or YAW_LOCK and YAW_IN_EARTH_FRAME for
  an absolute yaw (``_publish_gimbal_device_set_attitude``; :class:`Px4Mount`).
* DO_SET_ACTUATOR is PX4's own: it drives the outputs whose function is "Peripheral via Actuator
  Set n" and is never sent on to another component, so a script's ``do_set_actuator`` shows only
  in the outputs here (``peripheral_outputs``: actuator n -> output channel).
* Its parser knows the common dialect only: a frame of a message it does not know (ArduPilot's
  ESC_TELEMETRY_x_TO_y) is dropped, and PX4 counts it as a sequence gap, "lost", for the sender
  (on a loopback link the gaps are exactly these frames: :attr:`Px4Stream.dropped_unknown`);
  ESC_INFO, ESC_STATUS and COMPONENT_METADATA are common messages it knows
  (:attr:`Px4Stream.received_raw`: pymavlink's dialect cannot decode them).
* A reboot forgets the gimbal device (it is looked for again) and every stream request.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable
from typing import Any

from pymavlink.dialects.v20 import common as common_dialect

from mavservo.config import Action, Event, GimbalTarget, Script, SetActuator
from mavservo.mavlink import mavlink2 as mav
from mavservo.sim.autopilot.autopilot_link import AutopilotLink
from mavservo.sim.autopilot.commanded import Commanded
from mavservo.sim.autopilot.message_rates import MessageRates, interval_of
from mavservo.sim.autopilot.motion_scripts import Profile
from mavservo.sim.autopilot.mount_driver import MountDriver
from mavservo.sim.autopilot.stream import GIMBAL_DEVICE_INFORMATION_ID, AutopilotStream

MAV_AUTOPILOT_PX4 = 12
#: PX4's main mode MANUAL in HEARTBEAT.custom_mode (px4_custom_mode.h: main mode in bits 16-23)
_PX4_MANUAL = 1 << 16
#: PX4 SITL's output count (MixingOutput's 16 channels): what ``active`` carries
PX4_OUTPUTS = 16
#: the onboard link's defaults (mavlink_main.cpp, MAVLINK_MODE_ONBOARD)
PX4_ONBOARD_SERVO_OUTPUT_HZ = 10.0
PX4_ONBOARD_GIMBAL_HZ = 5.0
#: PWM of a peripheral actuator at -1 / +1 (PWM_MAIN_MIN/MAX defaults)
_PWM_MIN, _PWM_MAX = 1000.0, 2000.0
#: message ids PX4's parser knows: the common dialect, with the messages pymavlink's bundled
#: dialect leaves out (ESC_INFO 290, ESC_STATUS 291, COMPONENT_METADATA 397)
PX4_KNOWN_IDS = frozenset(common_dialect.mavlink_map) | {290, 291, 397}


class Px4Link(AutopilotLink):
    """The wire side of the simulated PX4: its HEARTBEAT, and its parser, which drops a frame
    of a message it does not know (:attr:`dropped_unknown`, by message id) before anything
    sees it; :attr:`received_raw` counts the frames it knows that pymavlink's dialect cannot
    decode (ESC_INFO, ESC_STATUS, COMPONENT_METADATA), by message id."""

    def __init__(self, system_id: int = 1, component_id: int = 1, keep: int = 20_000) -> None:
        super().__init__(system_id, component_id, keep)
        self.dropped_unknown: Counter[int] = Counter()
        self.received_raw: Counter[int] = Counter()

    def recv(self) -> Any | None:
        """The next message PX4's parser lets through (None: nothing waiting)."""
        while True:
            msg = super().recv()
            if msg is None or msg.get_type() == "BAD_DATA":
                return msg  # noise or a bad CRC: the stream skips it, as PX4 drops it
            msg_id = _message_id(msg)
            if msg_id not in PX4_KNOWN_IDS:
                self.dropped_unknown[msg_id] += 1
                continue
            if msg.get_type().startswith("UNKNOWN_"):
                self.received_raw[msg_id] += 1
            return msg

    def heartbeat(self, now: float, armed: bool) -> None:
        base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mav.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
        self.send(
            "HEARTBEAT",
            now,
            self._conn.mav.heartbeat_send,
            mav.MAV_TYPE_FIXED_WING,
            MAV_AUTOPILOT_PX4,
            base | (mav.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0),
            _PX4_MANUAL,
            mav.MAV_STATE_STANDBY,
            3,
        )


class Px4Mount(MountDriver):
    """PX4's gimbal manager output (``src/modules/gimbal/output_mavlink.cpp``,
    OutputMavlinkV2): between its requests for a device it publishes GIMBAL_DEVICE_SET_ATTITUDE
    to the device found, component 0 (everyone) until then; with no demand yet its attitude
    is NaN (``_q_setpoint`` starts NaN, output.h), flags ROLL_LOCK, PITCH_LOCK and
    YAW_IN_VEHICLE_FRAME (``_absolute_angle`` {true, true, false}); a demand's flags as
    :func:`px4_flags` says. Any component's GIMBAL_DEVICE_INFORMATION is the device."""

    def __init__(self, *, enabled: bool, target: GimbalTarget | None) -> None:
        super().__init__(0, enabled=enabled, wait_for_device=False, search_s=None)
        self.demanded = target is not None
        if target is not None:
            self.target = target

    @property
    def component(self) -> int:
        """Where the setpoints go: the device found, else 0 (every component)."""
        return 0 if self.device_info is None else int(self.device_info.get_srcComponent())

    @component.setter
    def component(self, _value: int) -> None:
        """PX4 is told no component: it takes the one that answers."""

    @property
    def target(self) -> GimbalTarget:
        return self._target

    @target.setter
    def target(self, target: GimbalTarget) -> None:
        self._target = target
        self.demanded = True

    def heard(self, msg: Any) -> None:
        self.device_info = msg

    def forget(self) -> None:
        """A new boot: no device, no demand."""
        self.device_info = None
        self.demanded = False

    def attitude(self) -> tuple[int, tuple[float, float, float, float], tuple[float, float, float]]:
        if not self.demanded:
            nan = math.nan
            locks = mav.GIMBAL_DEVICE_FLAGS_ROLL_LOCK | mav.GIMBAL_DEVICE_FLAGS_PITCH_LOCK
            return px4_flags(locks), (nan, nan, nan, nan), (nan, nan, nan)
        flags, q, rates = super().attitude()
        return px4_flags(flags), q, rates


class Px4Stream(AutopilotStream):
    """The simulated PX4. Takes :class:`AutopilotStream`'s arguments; its defaults are PX4's."""

    def __init__(
        self,
        url: str,
        profile: Profile | str = "sweep",
        script: Script | Iterable[Event] | None = None,
        *,
        servo_output_rate_hz: float = PX4_ONBOARD_SERVO_OUTPUT_HZ,
        actuator_output_status_hz: float = 0.0,
        attitude_hz: float = 50.0,
        sys_status_hz: float = 5.0,
        gimbal: bool = False,
        gimbal_rate_hz: float = PX4_ONBOARD_GIMBAL_HZ,
        peripheral_outputs: dict[int, int] | None = None,
        initial_gimbal: GimbalTarget | None = None,
        **kwargs: Any,
    ) -> None:
        super().__init__(
            url,
            profile,
            script,
            servo_output_rate_hz=servo_output_rate_hz,
            actuator_output_status_hz=actuator_output_status_hz,
            attitude_hz=attitude_hz,
            sys_status_hz=sys_status_hz,
            gimbal=gimbal,
            gimbal_rate_hz=gimbal_rate_hz,
            gimbal_search_s=None,
            initial_gimbal=initial_gimbal,
            **kwargs,
        )
        heartbeat_interval = self.rates.interval_s("HEARTBEAT")
        self.rates = MessageRates(
            {
                "HEARTBEAT": heartbeat_interval,
                "SYS_STATUS": interval_of(sys_status_hz),
                "ATTITUDE": interval_of(attitude_hz),
                "SERVO_OUTPUT_RAW": interval_of(servo_output_rate_hz),
                # a stream PX4 has but does not send on the onboard link unless asked
                "ACTUATOR_OUTPUT_STATUS": interval_of(actuator_output_status_hz),
                "GIMBAL_DEVICE_SET_ATTITUDE": interval_of(gimbal_rate_hz) if gimbal else None,
            },
            unrequestable=("GIMBAL_DEVICE_SET_ATTITUDE",),
        )
        self._px4_mount = Px4Mount(enabled=gimbal, target=initial_gimbal)
        self.mount = self._px4_mount
        self._px4_link = Px4Link(self.system_id, self.component_id, keep=self.keep)
        self.link = self._px4_link
        self.sent = self.link.sent
        self.sent_log = self.link.sent_log
        #: "Peripheral via Actuator Set n" -> output channel (1-based both)
        self.peripheral_outputs = dict(peripheral_outputs or {1: 5, 2: 6})
        #: each output's last ACTUATOR_OUTPUT_STATUS value (its changes go to ``commanded`` as
        #: kind "actuator_output", key = output number)
        self._last_status: dict[int, float] = {}
        self._reboots_seen = 0

    # ------------------------------------------------------------------ PX4's differences

    def _apply(self, action: Action, now: float) -> None:
        if not isinstance(action, SetActuator):
            super()._apply(action, now)
            return
        # PX4 drives its "Peripheral via Actuator Set n" outputs itself; nothing is sent on
        for index, value in action.actuators().items():
            channel = self.peripheral_outputs.get(index)
            if channel is None:
                continue
            pwm = round(_PWM_MIN + (max(-1.0, min(1.0, value)) + 1.0) / 2 * (_PWM_MAX - _PWM_MIN))
            self.outputs.set_servo(channel, pwm)
            self.commanded.record("actuator", Commanded(now, index, value, "do_set_actuator"))

    def _send_periodic(self, name: str, now: float) -> None:
        if name != "ACTUATOR_OUTPUT_STATUS":
            super()._send_periodic(name, now)
            return
        boot_s = now - self._boot_at + self.boot_offset_s
        frame = self.outputs.frame(self.elapsed(now), now)
        values = [float(pwm) for pwm in frame[:PX4_OUTPUTS]]
        values += [0.0] * (32 - len(values))
        self.link.actuator_output_status(now, int(boot_s * 1e6), values, PX4_OUTPUTS)
        for index, value in enumerate(values[:PX4_OUTPUTS], start=1):
            if self._last_status.get(index) != value:
                self._last_status[index] = value
                self.commanded.record(
                    "actuator_output", Commanded(now, index, value, "actuator_output_status")
                )

    def _gimbal_discovery(self, now: float) -> None:
        boot_s = now - self._boot_at + self.boot_offset_s
        if self.mount.request_due(now, boot_s, self.armed):
            params = (GIMBAL_DEVICE_INFORMATION_ID, 0, 0, 0, 0, 0, 0)
            self.link.command_long(now, (0, 0), mav.MAV_CMD_REQUEST_MESSAGE, params)

    def _reboot_if_asked(self, now: float) -> None:
        super()._reboot_if_asked(now)
        if self.reboots != self._reboots_seen:
            self._reboots_seen = self.reboots
            self._px4_mount.forget()  # a new boot looks for the gimbal again, has no demand

    # ------------------------------------------------------------------ what PX4 received

    @property
    def dropped_unknown(self) -> Counter[int]:
        """Frames PX4 dropped as unknown (it counts each as lost), by message id."""
        return self._px4_link.dropped_unknown

    @property
    def received_raw(self) -> Counter[int]:
        """Frames of ESC_INFO, ESC_STATUS, COMPONENT_METADATA received, by message id."""
        return self._px4_link.received_raw


def px4_flags(flags: int) -> int:
    """GIMBAL_DEVICE_SET_ATTITUDE flags as PX4's OutputMavlinkV2 sets them: YAW_LOCK and
    YAW_IN_EARTH_FRAME for an absolute yaw, YAW_IN_VEHICLE_FRAME otherwise."""
    earth = mav.GIMBAL_DEVICE_FLAGS_YAW_LOCK | mav.GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME
    if flags & earth:
        return (flags | earth) & ~mav.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME
    return flags | mav.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME


def _message_id(msg: Any) -> int:
    """A received message's id; pymavlink names one its dialect lacks ``UNKNOWN_<id>``."""
    name = msg.get_type()
    if name.startswith("UNKNOWN_"):
        return int(name.removeprefix("UNKNOWN_"))
    return int(msg.get_msgId())
