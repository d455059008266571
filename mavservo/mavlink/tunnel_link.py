"""A MAVLink link of its own for a :class:`~mavservo.mavlink.can_tunnel.CanTunnel`: what a tool
without the bridge's MAVLink side (``mavservo doctor``) opens to reach the autopilot's CAN port.

The bridge attaches its tunnel to its :class:`~mavservo.mavlink.side.MavlinkSide`; the doctor has
no side (no backend, no telemetry), only the link: the same :class:`~mavservo.mavlink.link.
MavlinkLink` (signing, peer rules, receive thread) hosting the servo component, the autopilot
followed from its HEARTBEAT as the bridge does (``system_id: follow`` takes the first autopilot
HEARTBEAT of the configured component, not a ground station's), and every other message given to
the tunnel.
"""

from __future__ import annotations

import threading
from typing import Any

from mavservo.mavlink.can_tunnel import CanTunnel
from mavservo.mavlink.link import MavlinkLink
from mavservo.mavlink.settings import FOLLOW, MavlinkSettings

#: How long :meth:`TunnelLink.start` waits for the autopilot (a little over two heartbeats).
AUTOPILOT_WAIT_S = 2.5
_MAV_TYPE_GCS = 6
_MAV_AUTOPILOT_INVALID = 8


class TunnelLink:
    """``start()`` opens the link, ``stop()`` closes it; :attr:`tunnel` is the carrier."""

    def __init__(self, settings: MavlinkSettings) -> None:
        self._settings = settings
        self._lock = threading.Lock()
        following = settings.system_id == FOLLOW
        self._system_id = settings.autopilot_system if following else int(settings.system_id)
        self._following = following
        self._autopilot: tuple[int, int] | None = None
        self._heard = threading.Event()
        self.tunnel = CanTunnel()
        self.link = MavlinkLink(
            settings.url, self._on_message, baud=settings.baud, signing=settings.signing
        )
        component = settings.servo_component_id
        self.link.add_component(component, self._system_id)
        # the autopilot pins the address it is first heard from, as on the bridge's side: else
        # (issue 40, review) a stranger claiming its ids from elsewhere on an unsigned link fed
        # the doctor's tunnel CAN frames it took for servo replies (CanTunnel._for_us)
        self.link.privileged = lambda source: source == self._expected_autopilot()
        self.tunnel.attach(
            send=lambda msg: self._send(component, msg),
            autopilot=lambda: self._autopilot,
            own=lambda: (self._system_id, component),
        )

    def _expected_autopilot(self) -> tuple[int, int]:
        """The autopilot once heard, else the (system, component) it is expected as."""
        return self._autopilot or (self._system_id, self._settings.autopilot_component)

    def _send(self, component_id: int, msg: Any) -> bool:
        if not self.link.is_open:
            return False
        self.link.send(component_id, msg, self._system_id, to_monitors=False)
        return True

    def _on_message(self, msg: Any, now: float) -> None:
        if msg.get_type() == "HEARTBEAT":
            self._heartbeat(msg)
            return
        self.tunnel.take(msg, now)

    def _heartbeat(self, msg: Any) -> None:
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        settings = self._settings
        if source[1] != settings.autopilot_component:
            return
        if msg.type == _MAV_TYPE_GCS or msg.autopilot == _MAV_AUTOPILOT_INVALID:
            return
        with self._lock:
            if self._following and self._autopilot is None:
                self._system_id = source[0]
            if source == (self._system_id, settings.autopilot_component):
                self._autopilot = source
                self._heard.set()

    def start(self, wait_s: float = AUTOPILOT_WAIT_S) -> bool:
        """Open the link and wait up to ``wait_s`` for the autopilot's HEARTBEAT (1 Hz from
        ArduPilot): a tool's first frames would otherwise be refused. True once heard."""
        self.link.start()
        return self._heard.wait(wait_s)

    def stop(self) -> None:
        self.link.stop()
