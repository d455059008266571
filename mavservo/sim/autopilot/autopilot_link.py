"""The simulated autopilot's MAVLink connection: what ArduPlane puts in each message it sends.

A part of its own because it is the wire side of the autopilot, with its own state (the
pymavlink connection, what was sent and when) and its own job: encode ArduPlane's messages
(HEARTBEAT, SYS_STATUS, ATTITUDE, SERVO_OUTPUT_RAW, the gimbal streams, COMMAND_LONG,
COMMAND_ACK), count them, and hand back what arrives. The stream decides what is sent and when;
every send goes through :meth:`AutopilotLink.send`, so the counters see them all.
"""

from __future__ import annotations

import math
import select
import time
from collections import Counter, deque
from collections.abc import Callable, Sequence
from typing import Any

from mavservo.mavlink import euler_to_quaternion, open_connection
from mavservo.mavlink import mavlink2 as mav

#: ArduPlane's HEARTBEAT base mode while disarmed (MAV_MODE_FLAG custom, stabilize, manual)
_BASE_MODE = 81
#: SYS_STATUS sensors present, enabled and healthy (a healthy ArduPlane's set)
_SENSORS = 0x0020FC2F
#: the attitude the vehicle reports to its gimbal (yaw -7 degrees)
_VEHICLE_YAW_DEG = -7.0


class AutopilotLink:
    """One pymavlink connection as sysid ``system_id``/compid ``component_id``; counts sends.

    :attr:`sent` counts messages per type, :attr:`sent_log` keeps the last ``keep`` (time,
    type) pairs. Not open until :meth:`open`; a closed link waits by sleeping.
    """

    #: the heading ATTITUDE reports (rad); a simulated autopilot may change it (a restarted
    #: PX4's estimator need not head where the old one did)
    yaw_rad = -0.12

    def __init__(self, system_id: int = 1, component_id: int = 1, keep: int = 20_000) -> None:
        self.system_id = system_id
        self.component_id = component_id
        self.sent: Counter[str] = Counter()
        self.sent_log: deque[tuple[float, str]] = deque(maxlen=keep)
        self._conn: Any = None

    def open(self, url: str, signing_key: bytes | None = None, **connection: Any) -> None:
        self._conn = open_connection(
            url,
            source_system=self.system_id,
            source_component=self.component_id,
            **connection,
        )
        if signing_key is not None:
            # accept the bridge's unsigned replies too: this side only plays the autopilot
            self._conn.setup_signing(
                signing_key, sign_outgoing=True, allow_unsigned_callback=lambda *_: True
            )

    def close(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def recv(self) -> Any | None:
        """The next message already received, without waiting (None: nothing)."""
        return self._conn.recv_match(blocking=False)

    def wait(self, timeout: float) -> None:
        """Wait up to ``timeout`` for input (the socket or serial port), else just sleep."""
        port = getattr(self._conn, "port", None)
        if port is None:  # not a socket or serial connection (closed, or a file)
            time.sleep(timeout)
            return
        try:
            select.select([port], [], [], timeout)
        except (TypeError, ValueError, OSError):
            time.sleep(timeout)

    def send(self, name: str, now: float, send: Callable[..., Any], *args: Any) -> None:
        """Send with ``send(*args)`` and count it as a ``name`` sent at ``now``."""
        send(*args)
        self.sent[name] += 1
        self.sent_log.append((now, name))

    def message(self, now: float, msg: Any) -> None:
        """Send a ready pymavlink message (the CAN forward's CAN_FRAME and ACK), counted."""
        if self._conn is not None:
            self.send(msg.get_type(), now, self._conn.mav.send, msg)

    # -- ArduPlane's messages ------------------------------------------------------------------

    def heartbeat(self, now: float, armed: bool) -> None:
        self.send(
            "HEARTBEAT",
            now,
            self._conn.mav.heartbeat_send,
            mav.MAV_TYPE_FIXED_WING,
            mav.MAV_AUTOPILOT_ARDUPILOTMEGA,
            _BASE_MODE | (mav.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0),
            0,
            mav.MAV_STATE_STANDBY,
            3,
        )

    def sys_status(self, now: float) -> None:
        sensors = _SENSORS
        self.send(
            "SYS_STATUS",
            now,
            self._conn.mav.sys_status_send,
            sensors,
            sensors,
            sensors,
            120,
            12600,
            150,
            95,
            0,
            0,
            0,
            0,
            0,
            0,
        )

    def attitude(self, now: float, boot_s: float) -> None:
        wobble = 0.02 * math.sin(0.5 * boot_s)
        self.send(
            "ATTITUDE",
            now,
            self._conn.mav.attitude_send,
            int(boot_s * 1000) & 0xFFFFFFFF,
            wobble,
            -wobble / 2,
            self.yaw_rad,
            0.0,
            0.0,
            0.0,
        )

    def servo_output_raw(self, now: float, usec: int, frame: Sequence[int]) -> None:
        send = self._conn.mav.servo_output_raw_send
        self.send("SERVO_OUTPUT_RAW", now, send, usec & 0xFFFFFFFF, 0, *frame)

    def actuator_output_status(
        self, now: float, usec: int, values: Sequence[float], active: int
    ) -> None:
        send = self._conn.mav.actuator_output_status_send
        self.send("ACTUATOR_OUTPUT_STATUS", now, send, usec, active, values)

    def gimbal_device_set_attitude(
        self,
        now: float,
        component: int,
        flags: int,
        q: Sequence[float],
        rates: Sequence[float],
    ) -> None:
        send = self._conn.mav.gimbal_device_set_attitude_send
        self.send(
            "GIMBAL_DEVICE_SET_ATTITUDE", now, send, self.system_id, component, flags, q, *rates
        )

    def autopilot_state_for_gimbal_device(self, now: float, usec: int) -> None:
        q = euler_to_quaternion(0.0, 0.0, _VEHICLE_YAW_DEG)
        self.send(
            "AUTOPILOT_STATE_FOR_GIMBAL_DEVICE",
            now,
            self._conn.mav.autopilot_state_for_gimbal_device_send,
            self.system_id,
            0,
            usec,
            q,
            0,
            0.0,
            0.0,
            0.0,
            0,
            0.0,
            41791,
            0,
            0.0,
        )

    def command_long(
        self, now: float, target: tuple[int, int], command: int, params: Sequence[float]
    ) -> None:
        send = self._conn.mav.command_long_send
        self.send("COMMAND_LONG", now, send, *target, command, 0, *params)

    def command_ack(self, now: float, command: int, result: int, target: tuple[int, int]) -> None:
        send = self._conn.mav.command_ack_send
        self.send("COMMAND_ACK", now, send, command, result, 0, 0, *target)
