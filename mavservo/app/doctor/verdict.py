"""What the doctor's findings mean for each configured servo: found as configured, or the
likely cause of its silence and the fix, and the ``servos:`` block that would work.

The causes, most likely first (issue 29, from the CAN motor drivers' issue trackers): the
bitrate, the id (the motor answers on another one), the mode (the motor speaks another protocol
or mode of its family), an ODrive idle or in error, a DroneCAN node alive but silent for its
actuator, and last the wiring.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from mavservo.config import ServoConfig, bitrate_text
from mavservo.servos import Advising, get_profile

from .families import facts
from .findings import BusFindings, Sighting
from .wire_facts import CLOSED_LOOP_CONTROL


@dataclass
class Verdict:
    """One configured servo: ``ok``, and if not the ``cause`` and ``fix``; ``notes`` add what
    was learnt (state, identity); ``entry`` is its corrected YAML entry."""

    servo: ServoConfig
    ok: bool
    cause: str = ""
    fix: str = ""
    notes: list[str] = field(default_factory=list)
    entry: dict[str, Any] = field(default_factory=dict)


def mode_of(profile: str, options: Mapping[str, Any]) -> tuple[tuple[str, Any], ...]:
    """The options that make a mode of ``profile`` (those its variants set), defaults filled."""
    keys = sorted({k for variant in facts(profile).variants for k in variant})
    defaults = get_profile(profile).Options.model_fields
    out = []
    for key in keys:
        default = defaults[key].default if key in defaults else None
        out.append((key, options.get(key, default)))
    return tuple(out)


def _same_mode(sighting: Sighting, profile: str, options: Mapping[str, Any]) -> bool:
    return sighting.profile == profile and mode_of(profile, sighting.options) == mode_of(
        profile, options
    )


def _entry(servo: ServoConfig) -> dict[str, Any]:
    """The servo as the user wrote it (keys left out stay out)."""
    return servo.model_dump(mode="json", exclude_unset=True)


def judge(findings: BusFindings, servos: list[ServoConfig]) -> list[Verdict]:
    """A verdict per configured servo of the bus (see module)."""
    verdicts = []
    configured_ids = {(s.profile, s.can_id) for s in servos}
    rate = findings.working_bitrate
    for servo in servos:
        verdict = Verdict(servo, ok=False, entry=_entry(servo))
        sightings = [
            s
            for s in findings.sightings.values()
            if (rate is None or s.bitrate == rate) and s.states > 0
        ]
        exact = [
            s
            for s in sightings
            if s.can_id == servo.can_id and _same_mode(s, servo.profile, servo.options)
        ]
        other_id = [
            s
            for s in sightings
            if s.can_id != servo.can_id
            and _same_mode(s, servo.profile, servo.options)
            and (s.profile, s.can_id) not in configured_ids
        ]
        other_mode = [
            s
            for s in sightings
            if s.can_id == servo.can_id
            and not _same_mode(s, servo.profile, servo.options)
            and s.profile in (servo.profile, *facts(servo.profile).siblings)
        ]
        if exact:
            verdict.ok = True
            verdict.notes.append(_how(exact[0]))
        elif other_mode:
            heard = other_mode[0]
            verdict.cause = (
                f"wrong mode: heard {_name(heard)} from id {servo.can_id}, configured "
                f"{servo.profile}{_options_text(servo.profile, servo.options)}"
            )
            mode_fix = facts(servo.profile).mode_fix
            verdict.fix = (
                mode_fix(heard.profile, heard.options, servo.profile, servo.options)
                if mode_fix
                else ""
            )
            verdict.entry["profile"] = heard.profile
            verdict.entry.pop("options", None)
            if options := _heard_options(heard, servo):
                verdict.entry["options"] = options
        elif other_id:
            heard = min(other_id, key=lambda s: s.can_id)
            verdict.cause = (
                f"wrong id: nothing answers on id {servo.can_id}; {_name(heard)} "
                f"{heard.how} on id {heard.can_id}"
            )
            verdict.fix = (
                f"set `can_id: {heard.can_id}` for {servo.name}, or give the motor id "
                f"{servo.can_id} with the vendor's tool"
            )
            verdict.entry["can_id"] = heard.can_id
        else:
            verdict.cause, verdict.fix = _silence(findings, servo)
        identity = findings.identities.get((servo.profile, servo.can_id))
        if identity is not None:
            verdict.notes.append(identity)
        _family_notes(findings, servo, verdict)
        verdicts.append(verdict)
    return verdicts


def _name(sighting: Sighting) -> str:
    return f"{sighting.profile}{_options_text(sighting.profile, sighting.options)}"


def _options_text(profile: str, options: Mapping[str, Any]) -> str:
    mode = [f"{k}: {v}" for k, v in mode_of(profile, options)]
    return f" ({', '.join(mode)})" if mode else ""


def _heard_options(heard: Sighting, servo: ServoConfig) -> dict[str, Any]:
    """The configured options in the heard mode (a sibling profile starts from none)."""
    if heard.profile != servo.profile:
        return dict(heard.options)
    return {**servo.options, **heard.options}


def _how(sighting: Sighting) -> str:
    verb = "answered the doctor's requests" if sighting.how == "answered" else "heard unasked"
    return f"{verb} ({sighting.frames} frames at {bitrate_text(sighting.bitrate)})"


def _silence(findings: BusFindings, servo: ServoConfig) -> tuple[str, str]:
    family = facts(servo.profile)
    tried = sorted({*findings.listened, *findings.probed_bitrates}, reverse=True)
    rates = ", ".join(bitrate_text(r) for r in tried) or "none"
    cause = f"silent: no frame of it at any bitrate tried ({rates})"
    hints = [family.probe_note, family.silence]
    profile = get_profile(servo.profile)(servo.can_id, servo.profile_options())
    profile_hint = profile.silence_hint() if isinstance(profile, Advising) else None
    if profile_hint:
        hints.append(profile_hint)
    return cause, "; ".join(h for h in hints if h)


def _family_notes(findings: BusFindings, servo: ServoConfig, verdict: Verdict) -> None:
    """What the family's "I am here" frames say: an ODrive's state and errors, a DroneCAN
    node's health and mode (and a node alive but silent for its actuator)."""
    if servo.profile == "odrive":
        beat = findings.heartbeats.get(servo.can_id)
        if beat is None:
            return
        errors = beat.error_names
        verdict.notes.append(
            f"ODrive heartbeat: {beat.state_name}, errors: {', '.join(errors) or 'none'}"
        )
        if errors:
            verdict.ok = False
            verdict.cause = f"ODrive in error: {', '.join(errors)}"
            verdict.fix = (
                "fix the cause the error names, then clear it (CANSimple Clear_Errors 0x18, "
                "or `odrv0.clear_errors()`); the bridge cannot enter closed loop while it stays"
            )
        elif beat.axis_state != CLOSED_LOOP_CONTROL:
            verdict.notes.append(
                f"the axis is {beat.state_name}: the bridge requests CLOSED_LOOP_CONTROL at "
                "start-up; if it falls back, the motor/encoder is not calibrated (run "
                "FULL_CALIBRATION_SEQUENCE and save the configuration)"
            )
    if servo.profile == "dronecan":
        _dronecan_notes(findings, servo, verdict)
    if servo.profile == "damiao-dm" and servo.can_id in findings.damiao_modes:
        register = findings.damiao_modes[servo.can_id]
        wanted = servo.options.get("mode", "mit")
        verdict.notes.append(f"CTRL_MODE register: {register}")
        if register != wanted:
            verdict.notes.append(
                f"it answers in {register} mode, configured {wanted}: the bridge writes "
                "CTRL_MODE at start-up; if the motor keeps the old mode, write and store it "
                "with Damiao's tool (or set `options: {mode: " + register + "}`)"
            )


def _dronecan_notes(findings: BusFindings, servo: ServoConfig, verdict: Verdict) -> None:
    """A DroneCAN node is its servo only when its actuator Status carries the configured
    actuator id: NodeStatus says the node lives, not that it drives this actuator."""
    status = findings.node_statuses.get(servo.can_id)
    if status is not None:
        verdict.notes.append(
            f"DroneCAN node {status.node_id}: health {status.health}, mode {status.mode}, "
            f"up {status.uptime_s} s"
        )
    actuator = servo.options.get("actuator_id", 1)
    reported = sorted(findings.actuators.get(servo.can_id, ()))
    if actuator in reported:
        return
    if reported:
        verdict.ok = False
        verdict.cause = (
            f"wrong actuator id: node {servo.can_id} is alive and reports actuator "
            f"{', '.join(map(str, reported))}, configured {actuator}"
        )
        verdict.fix = (
            f"set `options: {{actuator_id: {reported[0]}}}` (ArduPilot numbers actuators from "
            "1, PX4 from 0), or change the node's actuator id"
        )
        verdict.entry["options"] = {**servo.options, "actuator_id": reported[0]}
    elif status is not None:
        verdict.ok = False
        verdict.cause = (
            f"node {servo.can_id} is alive (NodeStatus {status.health}, {status.mode}) but "
            f"sends no actuator Status for actuator {actuator}"
        )
        verdict.fix = (
            "a node reports the actuators it is commanded with, and ignores command types it "
            "does not take: ArduPilot's AP_Periph takes only UNITLESS and PWM (set `options: "
            "{command: unitless}`) and numbers actuators from 1, PX4 from 0 (check "
            "`actuator_id`); the doctor sends no command without --allow-enable"
        )


def extra_entries(findings: BusFindings, verdicts: list[Verdict]) -> list[dict[str, Any]]:
    """Motors found that no configured servo explains (a scan, passive traffic), each once."""
    explained = {
        (v.entry.get("profile", v.servo.profile), v.entry.get("can_id", v.servo.can_id))
        for v in verdicts
    }
    names = {f"{p} {i}" for p, i in explained}
    out: list[dict[str, Any]] = []
    seen: set[tuple[str, int]] = set()
    for sighting in sorted(findings.sightings.values(), key=lambda s: (s.profile, s.can_id)):
        key = (sighting.profile, sighting.can_id)
        if key in explained or key in seen or sighting.alternatives & names:
            continue
        if findings.working_bitrate is not None and sighting.bitrate != findings.working_bitrate:
            continue
        if findings.noisy and sighting.how != "answered":
            continue  # chance matches of a busy foreign bus (BusFindings.noisy): not listed
        seen.add(key)
        entry: dict[str, Any] = {
            "name": f"{sighting.profile.replace('-', '_')}_{sighting.can_id}",
            "profile": sighting.profile,
            "can_id": sighting.can_id,
        }
        if sighting.options:
            entry["options"] = dict(sighting.options)
        out.append(entry)
    return out
