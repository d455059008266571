"""Notice a gimbal the autopilot never looks for, and say why and what to do.

ArduPilot's MAVLink gimbal driver (``libraries/AP_Mount/AP_Mount_Gremsy.cpp``,
``AP_Mount_Gremsy::find_gimbal``, ArduPilot master 3d099b0) looks for a gimbal component only
from 10 s after boot, and stops once it is past 60 s *and* armed. Once it has seen the gimbal's
HEARTBEAT it asks for GIMBAL_DEVICE_INFORMATION every second (MAV_CMD_REQUEST_MESSAGE to the
gimbal's component), then streams GIMBAL_DEVICE_SET_ATTITUDE and
AUTOPILOT_STATE_FOR_GIMBAL_DEVICE. A bridge started after that window is never found: ArduPilot
still ACKs MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW as ACCEPTED and nothing moves, without a word.

PX4's gimbal manager (``src/modules/gimbal/output_mavlink.cpp``, OutputMavlinkV2::update) asks
every component for GIMBAL_DEVICE_INFORMATION every second from boot until a device answers, so
there is no start order to keep; it does so only with ``MNT_MODE_OUT 2`` (MAVLink gimbal v2)
and ``MNT_MODE_IN`` set (the gimbal module runs only then), and a PX4 without them never turns
to the gimbal, as silently. A PX4 heard for :data:`GRACE_S` that has not asked gets its own
warning with those parameters.

So for each hosted gimbal of an ArduPilot vehicle (its HEARTBEAT says so) this watch waits
until the autopilot has been heard for
:data:`GRACE_S` and is at least :data:`SEARCH_STARTS_S` + :data:`GRACE_S` past its own boot (its
boot time read from the messages it sends), and if by then the autopilot has neither asked the
gimbal for anything nor sent it a setpoint, it returns one warning with the fix (the log and a
STATUSTEXT). Once the autopilot does turn to the gimbal it says so once. Sans-I/O.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from mavservo.mavlink.autopilot_flavour import flavour_of_heartbeat
from mavservo.mavlink.stream_request import boot_time_s

#: ArduPilot starts looking for gimbals this long after its boot (AP_Mount_Gremsy.cpp).
SEARCH_STARTS_S = 10.0
#: ... and stops past this, once armed (AP_MOUNT_GREMSY_SEARCH_MS).
SEARCH_STOPS_S = 60.0
#: How long the autopilot may take to turn to a gimbal it can see (it asks every second).
GRACE_S = 5.0
#: What the autopilot sends a gimbal it has found.
_GIMBAL_TRAFFIC = ("GIMBAL_DEVICE_SET_ATTITUDE", "AUTOPILOT_STATE_FOR_GIMBAL_DEVICE")
_COMMANDS = ("COMMAND_LONG", "COMMAND_INT")
#: MAV_CMD_REQUEST_MESSAGE and GIMBAL_DEVICE_INFORMATION (common.xml)
MAV_CMD_REQUEST_MESSAGE = 512
MSG_GIMBAL_DEVICE_INFORMATION = 283


def not_found_text(component_id: int, flavour: str = "ardupilot") -> str:
    """The warning: what happened, why, and the fix (fits four STATUSTEXT chunks)."""
    if flavour == "px4":
        return (
            f"gimbal {component_id} not found by the autopilot: PX4 looks for a MAVLink gimbal "
            "only with MNT_MODE_OUT 2 and MNT_MODE_IN 4 (or 0); set them and reboot PX4"
        )
    return (
        f"gimbal {component_id} not found by the autopilot: ArduPilot looks for gimbals only "
        "10-60 s after boot (longer while disarmed). Reboot the autopilot with the bridge "
        "running; start the bridge first"
    )


def log_hint(component_id: int, flavour: str) -> str:
    """What the log line adds to the warning (the parameter to check)."""
    if flavour == "px4":
        return "PX4: MNT_MODE_OUT 2, MNT_MODE_IN 4; it asks every second once they are set"
    return f"ArduPilot: MNT1_TYPE 6; it looks for component {component_id} only then"


class GimbalDiscoveryWatch:
    """Whether the autopilot turned to each hosted gimbal; the warnings due when it did not."""

    def __init__(self, gimbal_ids: Iterable[int]) -> None:
        self.gimbal_ids = tuple(gimbal_ids)
        self._heard_since: float | None = None
        self._uptime: tuple[float, float] | None = None  # (autopilot boot time s, our time)
        self._found: set[int] = set()
        self._warned: set[int] = set()
        #: the followed autopilot's flavour (its HEARTBEAT): the search rules differ
        self.flavour: str | None = None

    def on_autopilot_message(self, msg: Any, now: float) -> list[str]:
        """A message from the watched autopilot (HEARTBEAT included). Returns notices."""
        if self._heard_since is None:
            self._heard_since = now
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            self.flavour = flavour_of_heartbeat(int(msg.autopilot))
        boot = boot_time_s(kind, msg)
        if boot is not None:
            self._uptime = (boot, now)
        out = []
        for target in _gimbal_targets(msg, kind, self.gimbal_ids):
            if target in self._found:
                continue
            self._found.add(target)
            if target in self._warned:
                out.append(f"gimbal {target} found by the autopilot after all")
        return out

    def lost_autopilot(self) -> None:
        """The autopilot went silent: the wait starts again when it is heard."""
        self._heard_since = None
        self._uptime = None

    def due(self, now: float) -> list[tuple[int, str]]:
        """(gimbal, warning) for each gimbal the autopilot should have found by now."""
        if not self.gimbal_ids or self._heard_since is None:
            return []
        if self.flavour not in ("ardupilot", "px4") or now - self._heard_since < GRACE_S:
            return []
        if self.flavour == "ardupilot" and self._uptime is not None:
            boot, at = self._uptime
            if boot + (now - at) < SEARCH_STARTS_S + GRACE_S:
                return []  # the autopilot is not looking yet
        out = []
        for gimbal in self.gimbal_ids:
            if gimbal in self._found or gimbal in self._warned:
                continue
            self._warned.add(gimbal)
            out.append((gimbal, not_found_text(gimbal, self.flavour)))
        return out

    def stats(self) -> dict[str, list[int]]:
        return {"found": sorted(self._found), "warned": sorted(self._warned)}


def _gimbal_targets(msg: Any, kind: str, gimbal_ids: tuple[int, ...]) -> tuple[int, ...]:
    """The hosted gimbals an autopilot message turns to, when it is gimbal business.

    PX4's gimbal manager asks every component at once (REQUEST_MESSAGE for
    GIMBAL_DEVICE_INFORMATION to 0/0, ``src/modules/gimbal/output_mavlink.cpp``,
    ``_request_gimbal_device_information``): that looks for every hosted gimbal."""
    if kind not in _GIMBAL_TRAFFIC and kind not in _COMMANDS:
        return ()
    target = int(msg.target_component)
    if target == 0 and kind in _COMMANDS:
        asks_for_gimbals = (
            msg.command == MAV_CMD_REQUEST_MESSAGE and msg.param1 == MSG_GIMBAL_DEVICE_INFORMATION
        )
        return gimbal_ids if asks_for_gimbals else ()
    return (target,) if target in gimbal_ids else ()  # any command to it: it knows the gimbal
