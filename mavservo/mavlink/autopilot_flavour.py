"""Which autopilot the bridge follows (ArduPilot, PX4, another), and what differs between them.

The HEARTBEAT's ``autopilot`` field says it (minimal.xml, MAV_AUTOPILOT: 3 ARDUPILOTMEGA, 12 PX4);
``mavlink.autopilot.flavour`` can fix it instead (``auto`` learns it from the followed
autopilot's HEARTBEAT). Each difference lives in the part that deals with it; this module only
holds the facts, each with where it was read:

* **ACTUATOR_OUTPUT_STATUS.active.** common.xml (mavlink/mavlink, message 375) declares ``active``
  a bitmask (``display="bitmask"``, "Active outputs"). PX4 fills it with the NUMBER of outputs:
  ``msg.active = act.noutputs`` (PX4-Autopilot ``src/modules/mavlink/streams/
  ACTUATOR_OUTPUT_STATUS.hpp`` line 68, main bb59c637, Aug 2026; ``noutputs`` is "valid outputs"
  in ``msg/ActuatorOutputs.msg``, 16 in SITL), so outputs 1..active are valid. ArduPilot does
  not send the message at all (no sender in ``libraries/GCS_MAVLink``, master 90700977c5: it
  sends SERVO_OUTPUT_RAW, ``GCS_MAVLINK::send_servo_output_raw``, GCS_Common.cpp line 3347), and
  MAVSDK passes the field through uninterpreted (``TelemetryImpl::process_actuator_output_status``,
  cpp/src/mavsdk/plugins/telemetry/telemetry_impl.cpp line 1400, MAVSDK 158e339). Rule: from a
  PX4 the field is a count; from anything else (the bridge's own telemetry, a sender following
  the spec) the spec's bitmask.
* **Messages its parser knows.** ArduPilot fails messages 290 (ESC_INFO), 291 (ESC_STATUS) and
  397 (COMPONENT_METADATA) on its CRC check and never routes them (measured against ArduPlane
  90700977c5, ../shared/ARDUPILOT-SITL.md); PX4 does not know ArduPilot's ESC_TELEMETRY_x_TO_y
  (ardupilotmega.xml 11030-11044): it drops them and counts the sequence gaps as lost, and
  forwards ESC_INFO/ESC_STATUS (PX4 SITL, ../shared/PX4-SITL.md). :mod:`.link_carriage` decides
  from these what the link gets.
* **Stream requests.** PX4 sends GIMBAL_DEVICE_SET_ATTITUDE as a MAVLink stream at 5 Hz on its
  onboard link (``mavlink_main.cpp`` MAVLINK_MODE_ONBOARD: ``configure_stream_local(
  "GIMBAL_DEVICE_SET_ATTITUDE", 5.0f)``, line 1741) and takes SET_MESSAGE_INTERVAL for it
  (``MavlinkReceiver::set_message_interval`` configures any stream by id); ArduPilot's mount
  driver sends it from its own update, not as a stream. :mod:`.stream_request` asks PX4 only.

Pure: no I/O.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Literal

log = logging.getLogger(__name__)

#: MAV_AUTOPILOT (minimal.xml): the HEARTBEAT ``autopilot`` values this module tells apart.
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_PX4 = 12
MAV_AUTOPILOT_INVALID = 8

Flavour = Literal["ardupilot", "px4", "other"]
"""What the followed autopilot is; "other" is any autopilot that is neither."""
ConfiguredFlavour = Literal["auto", "ardupilot", "px4"]

#: ESC_TELEMETRY_1_TO_4 .. 29_TO_32 (ardupilotmega.xml: 11030-11032, then 11040-11044), unknown
#: to a common-dialect parser. Written out, so the settings (and the config) do not import a
#: dialect; tests/mavlink/test_autopilot_flavour.py checks them against pymavlink's.
ESC_TELEMETRY_IDS = frozenset({11030, 11031, 11032, 11040, 11041, 11042, 11043, 11044})
MSG_ESC_INFO = 290
MSG_ESC_STATUS = 291
MSG_COMPONENT_METADATA = 397


@dataclass(frozen=True)
class FlavourFacts:
    """What one kind of autopilot does differently (see the module docstring for sources)."""

    name: str
    #: ACTUATOR_OUTPUT_STATUS.active is the number of valid outputs, not a bitmask
    active_is_count: bool
    #: message ids its MAVLink parser drops (never routed on, never answered)
    unknown_ids: frozenset[int]
    #: it streams GIMBAL_DEVICE_SET_ATTITUDE and takes SET_MESSAGE_INTERVAL for it
    streams_gimbal_setpoints: bool
    #: how the user raises a stream's rate on that autopilot (for the low-rate warning)
    rate_advice: str


ARDUPILOT = FlavourFacts(
    name="ArduPilot",
    active_is_count=False,
    unknown_ids=frozenset({MSG_ESC_INFO, MSG_ESC_STATUS, MSG_COMPONENT_METADATA}),
    streams_gimbal_setpoints=False,
    rate_advice="On ArduPilot set the port's stream rate (MAVn_RC_CHAN on 4.7+, SRn_RC_CHAN "
    "before) or let the bridge ask (mavlink.request_streams)",
)
PX4 = FlavourFacts(
    name="PX4",
    active_is_count=True,
    unknown_ids=ESC_TELEMETRY_IDS,
    streams_gimbal_setpoints=True,
    rate_advice="On PX4 raise it in the onboard link's start-up (`mavlink stream -u 14580 -s "
    "NAME -r HZ` in etc/extras.txt; SERVO_OUTPUT_RAW is SERVO_OUTPUT_RAW_0) or let the bridge "
    "ask (mavlink.request_streams)",
)
#: Another autopilot: assumed to follow common.xml (a bitmask; no ardupilotmega messages).
OTHER = FlavourFacts(
    name="autopilot",
    active_is_count=False,
    unknown_ids=ESC_TELEMETRY_IDS,
    streams_gimbal_setpoints=False,
    rate_advice="Set the autopilot's stream rate for the bridge's port or let the bridge ask "
    "(mavlink.request_streams)",
)
FACTS: dict[Flavour, FlavourFacts] = {"ardupilot": ARDUPILOT, "px4": PX4, "other": OTHER}


def flavour_of_heartbeat(autopilot: int) -> Flavour | None:
    """The flavour a HEARTBEAT's ``autopilot`` field names (None: INVALID, not an autopilot)."""
    if autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA:
        return "ardupilot"
    if autopilot == MAV_AUTOPILOT_PX4:
        return "px4"
    if autopilot == MAV_AUTOPILOT_INVALID:
        return None
    return "other"


class AutopilotFlavour:
    """The followed autopilot's flavour: configured, or learned from its HEARTBEAT.

    ``auto`` starts unknown (:attr:`known` False, the facts of "other") and takes the flavour
    of the followed autopilot's HEARTBEATs. A HEARTBEAT that names another flavour than the
    configured one is logged once (the config wins: a misconfiguration is said, never
    followed silently); with ``auto`` a change of flavour (another autopilot flashed, a spoofer
    on an unsigned link) is logged and followed.
    """

    def __init__(self, configured: ConfiguredFlavour = "auto") -> None:
        self.configured = configured
        self.heard: Flavour | None = None
        self._mismatch_logged = False

    @property
    def flavour(self) -> Flavour | None:
        """The flavour in force (None: ``auto`` and no HEARTBEAT yet)."""
        if self.configured != "auto":
            return self.configured
        return self.heard

    @property
    def known(self) -> bool:
        return self.flavour is not None

    @property
    def facts(self) -> FlavourFacts:
        flavour = self.flavour
        return OTHER if flavour is None else FACTS[flavour]

    def on_heartbeat(self, autopilot: int) -> bool:
        """The followed autopilot's HEARTBEAT ``autopilot`` field; True when the flavour in
        force changed (the parts that depend on it re-plan)."""
        heard = flavour_of_heartbeat(int(autopilot))
        if heard is None or heard == self.heard:
            return False
        before = self.flavour
        previous, self.heard = self.heard, heard
        if self.configured != "auto":
            if heard != self.configured and not self._mismatch_logged:
                self._mismatch_logged = True
                log.warning(
                    "mavlink.autopilot.flavour is %s but the autopilot's HEARTBEAT says %s "
                    "(autopilot %d): the bridge goes on as for %s; fix the config",
                    self.configured,
                    FACTS[heard].name,
                    int(autopilot),
                    FACTS[self.configured].name,
                )
            return False
        if previous is None:
            log.info("autopilot is %s (HEARTBEAT autopilot %d)", FACTS[heard].name, int(autopilot))
        else:
            log.warning(
                "autopilot changed from %s to %s (HEARTBEAT autopilot %d)",
                FACTS[previous].name,
                FACTS[heard].name,
                int(autopilot),
            )
        return self.flavour != before

    def stats(self) -> dict[str, str | None]:
        return {"configured": self.configured, "heard": self.heard, "in_force": self.flavour}
