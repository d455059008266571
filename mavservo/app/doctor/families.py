"""What the doctor knows of each family beyond its profile: the modes a motor of the family can
be in (so a motor heard in another mode is named), which requests are safe besides the
profile's telemetry polls, which frames would enable it (sent only with ``--allow-enable``),
and what to tell a user whose motor stays silent.

The profiles' own API stays the source of frame layouts: a servo is recognised with
``is_reply``/``decode``, polled with ``telemetry_requests`` (documented as queries that change
nothing: ``ServoProfile.telemetry_requests``), and advised with ``diagnose``/``silence_hint``.
What is here comes from the vendors' documents (cited per entry), for the cases the bridge
never needs: the identity reads, the other modes, the texts.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import can

from .wire_facts import damiao_mode_request, odrive_version_request, rmdx_identity_requests

#: The MIT packing's special frames (CubeMars AK manual, "MIT mode" table; Damiao DM-J manual,
#: "MIT control": the same bytes): enter motor mode (enable) and exit (disable).
ENTER_MOTOR_MODE = bytes([0xFF] * 7 + [0xFC])
EXIT_MOTOR_MODE = bytes([0xFF] * 7 + [0xFD])

#: Robstride private protocol (Robstride RS0x manual, "communication type 0: get device ID"):
#: ``0 << 24 | host_id << 8 | motor_id``, 8 zero bytes; the answer carries the 64-bit MCU id
#: (type 0, ``motor_id << 8 | 0xFE``). A read: it changes nothing.
ROBSTRIDE_GET_ID = 0x00
ROBSTRIDE_HOST_ID = 0xFD

#: Robstride private protocol (RS0x manual, "communication type 4: stop"): torque off,
#: answered with a feedback frame (type 2). It changes the run state of a running motor, so
#: it is sent only with ``--allow-enable``, to a motor that answers no read.
ROBSTRIDE_STOP = 0x04


@dataclass(frozen=True)
class FamilyFacts:
    """One family (profile name) as the doctor sees it."""

    profile: str
    #: option sets its motors can be in (protocols, modes); the configured one is added
    variants: tuple[Mapping[str, Any], ...] = ({},)
    #: other profiles the same motor may be speaking (another mode of the same hardware)
    siblings: tuple[str, ...] = ()
    #: likely causes and fixes when nothing of it is heard at all
    silence: str = ""
    #: why a probe alone may not find it (a family that answers only to commands)
    probe_note: str = ""
    #: safe identity reads for ``(can_id, options)`` besides the telemetry polls
    identity: Callable[[int, Mapping[str, Any]], list[can.Message]] = field(
        default=lambda can_id, options: []
    )
    #: frames that enable the motor so that it answers (only with ``--allow-enable``),
    #: each followed by the frames that undo it
    enable: (
        Callable[[int, Mapping[str, Any]], tuple[list[can.Message], list[can.Message]]] | None
    ) = None
    #: how to change the motor's mode from ``heard`` (profile, options) to ``wanted``
    mode_fix: Callable[[str, Mapping[str, Any], str, Mapping[str, Any]], str] | None = None


def _std(arbitration_id: int, data: bytes) -> can.Message:
    return can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False)


def _robstride_identity(can_id: int, options: Mapping[str, Any]) -> list[can.Message]:
    if options.get("protocol", "private") != "private":
        return []  # the MIT protocol has no read that changes nothing
    host = int(options.get("host_id", ROBSTRIDE_HOST_ID))
    return [
        can.Message(
            arbitration_id=ROBSTRIDE_GET_ID << 24 | host << 8 | can_id,
            data=bytes(8),
            is_extended_id=True,
        )
    ]


def _robstride_stop(can_id: int, options: Mapping[str, Any]) -> can.Message:
    host = int(options.get("host_id", ROBSTRIDE_HOST_ID))
    return can.Message(
        arbitration_id=ROBSTRIDE_STOP << 24 | host << 8 | can_id, data=bytes(8), is_extended_id=True
    )


def _mit_enable(
    can_id: int, options: Mapping[str, Any]
) -> tuple[list[can.Message], list[can.Message]]:
    return [_std(can_id, ENTER_MOTOR_MODE)], [_std(can_id, EXIT_MOTOR_MODE)]


def _cubemars_mode(heard: str, heard_options: Mapping[str, Any], wanted: str, _: Any) -> str:
    if heard == "cubemars-ak":
        return (
            "it is in servo mode (extended-id status pushes): switch it to MIT mode with "
            "CubeMars' upper computer (R-Link, 'Mode' -> MIT) and power-cycle it, or keep servo "
            "mode and configure `profile: cubemars-ak`"
        )
    return (
        "it is in MIT mode: switch it to servo mode with CubeMars' upper computer (R-Link, "
        "'Mode' -> Servo), or configure `profile: cubemars-ak-mit`"
    )


def _robstride_mode(
    heard: str, heard_options: Mapping[str, Any], wanted: str, wanted_options: Mapping[str, Any]
) -> str:
    now = heard_options.get("protocol", "private")
    want = wanted_options.get("protocol", "private")
    return (
        f"it speaks the {now} protocol, configured {want}: set `options: {{protocol: {now}}}`, "
        f"or switch the motor to {want} (communication type 0x19, then a power cycle; "
        "Robstride manual, 'protocol switch')"
    )


def _damiao_mode(
    heard: str, heard_options: Mapping[str, Any], wanted: str, wanted_options: Mapping[str, Any]
) -> str:
    now = heard_options.get("mode", "mit")
    want = wanted_options.get("mode", "mit")
    return (
        f"it answers in {now} mode, configured {want}: set `options: {{mode: {now}}}` or write "
        "its CTRL_MODE register (rid 10, Damiao DM-J manual; the bridge writes it at start-up "
        "when the motor takes it)"
    )


def _rmd_lk_mode(heard: str, heard_options: Mapping[str, Any], wanted: str, _: Any) -> str:
    return (
        f"its replies have the {heard} layout, configured {wanted}: set `profile: {heard}` "
        "(LK-Tech and older MyActuator firmware share ids, not the reply layout)"
    )


FACTS: dict[str, FamilyFacts] = {
    "rmd-x": FamilyFacts(
        "rmd-x",
        siblings=("lk",),
        mode_fix=_rmd_lk_mode,
        identity=lambda can_id, options: rmdx_identity_requests(can_id),
        silence=(
            "an RMD-X answers every request on 0x240 + id at its firmware's bitrate (1 Mbit/s "
            "from the factory): check the id (MyActuator's tool, 'Motor ID'), CAN_H/CAN_L and a "
            "120 ohm terminator at each end of the bus"
        ),
    ),
    "lk": FamilyFacts(
        "lk",
        siblings=("rmd-x",),
        mode_fix=_rmd_lk_mode,
        silence=(
            "an LK motor answers every request on the request's own id, 0x140 + id, at its "
            "bitrate (1 Mbit/s from the factory; LK's tool sets both): check the id, wiring "
            "and terminators"
        ),
    ),
    "cubemars-ak": FamilyFacts(
        "cubemars-ak",
        siblings=("cubemars-ak-mit",),
        mode_fix=_cubemars_mode,
        silence=(
            "a CubeMars AK in servo mode pushes its status unasked (extended id 0x29 << 8 | id) "
            "once its upload rate is set: silence means another bitrate (R-Link sets it), no "
            "power, wiring, or the motor in MIT mode"
        ),
    ),
    "cubemars-ak-mit": FamilyFacts(
        "cubemars-ak-mit",
        siblings=("cubemars-ak",),
        mode_fix=_cubemars_mode,
        enable=_mit_enable,
        probe_note=(
            "in MIT mode a CubeMars answers only its commands and enter-motor-mode, which the "
            "doctor sends only with --allow-enable"
        ),
        silence="a CubeMars in MIT mode is silent until commanded",
    ),
    "damiao-dm": FamilyFacts(
        "damiao-dm",
        identity=lambda can_id, options: [damiao_mode_request(can_id)],
        variants=({"mode": "mit"}, {"mode": "position-velocity"}),
        mode_fix=_damiao_mode,
        silence=(
            "a Damiao answers the 0x7FF refresh on its master id (MST_ID, 0 by default): check "
            "the id and master id (Damiao's tool), the bitrate (1 Mbit/s default), terminators"
        ),
    ),
    "robstride": FamilyFacts(
        "robstride",
        variants=({"protocol": "private"}, {"protocol": "mit"}),
        mode_fix=_robstride_mode,
        identity=_robstride_identity,
        enable=lambda can_id, options: (
            _mit_enable(can_id, options)
            if options.get("protocol") == "mit"
            else ([_robstride_stop(can_id, options)], [])
        ),
        probe_note=(
            "a Robstride that does not answer 'get device id' (some firmware, the simulation) "
            "and one in the MIT protocol answer only a stop or enable, which the doctor sends "
            "only with --allow-enable"
        ),
        silence=(
            "a Robstride answers 'get device id' (type 0) in its private protocol at 1 Mbit/s: "
            "silence means another id (CAN_ID), the MIT protocol, bitrate or wiring"
        ),
    ),
    "odrive": FamilyFacts(
        "odrive",
        identity=lambda can_id, options: [odrive_version_request(can_id)],
        silence=(
            "an ODrive sends a heartbeat every 100 ms unasked: silence means another bitrate "
            "(`odrv0.can.config.baud_rate`), CAN not enabled on the axis "
            "(`axis0.config.can.node_id`, `odrv0.config.enable_can_a`), wiring or terminators"
        ),
    ),
    "dronecan": FamilyFacts(
        "dronecan",
        silence=(
            "every DroneCAN node sends NodeStatus once a second: silence means another bitrate "
            "(DroneCAN buses run at 1 Mbit/s), no node id (a node waiting for dynamic "
            "allocation sends only anonymous requests), wiring or terminators"
        ),
    ),
}


def facts(profile: str) -> FamilyFacts:
    """The doctor's facts of ``profile`` (a plug-in family gets the neutral defaults)."""
    return FACTS.get(profile, FamilyFacts(profile))
