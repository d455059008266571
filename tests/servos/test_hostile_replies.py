"""Hostile replies to every family's decoder in every option variant (review of issue 27).

tests/redteam/test_decoder_fuzz.py feeds random frames to each profile with its default options;
most of them never reach a decoder's body (a wrong id). Here every frame carries one of the
identifiers the profile itself says its servo sends (``identifiers()``, ``from_servo``), masked bits
drawn at random, with any length 0..8 and any bytes: truncated replies, wrong DLC, every bit pattern
of an IEEE float or a scaled integer. A decoder must never raise, and whatever it reports must be a
number (finite) or NaN, never an infinity, in every option variant that changes a layout (LK's
status_1, model and encoder bits; Robstride's protocol; Damiao's mode; gear ratios).
"""

from __future__ import annotations

import math
from typing import Any

import can
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mavservo.servos import Advising, FrameId, ServoProfile, get_profile

#: (profile, options) pairs: every option that selects another reply layout or scale.
VARIANTS: list[tuple[str, dict[str, Any]]] = [
    ("rmd-x", {}),
    ("rmd-x", {"brake": True}),
    ("lk", {}),
    ("lk", {"model": "MS", "encoder_bits": 16}),
    ("lk", {"model": "MG", "status_1": "legacy", "gear_ratio": 36.0}),
    ("cubemars-ak", {}),
    ("cubemars-ak-mit", {}),
    ("damiao-dm", {}),
    ("damiao-dm", {"mode": "position-velocity"}),
    ("robstride", {}),
    ("robstride", {"protocol": "mit"}),
    ("odrive", {}),
    ("odrive", {"input_mode": "trap-traj", "motor_turns_per_rev": 8.0}),
]


#: Command bytes RMD-X and LK replies echo in byte 0 (their documents' command tables).
COMMAND_BYTES = [0x92, 0x9A, 0x9B, 0x9C, 0xA4, 0x80, 0x81, 0x88, 0x77, 0x78, 0xB3, 0x00, 0xFF]


def _profile(name: str, options: dict[str, Any], can_id: int) -> ServoProfile:
    cls = get_profile(name)
    return cls(can_id, cls.Options.model_validate(options))


def _sent_by_servo(profile: ServoProfile) -> list[FrameId]:
    return [f for f in profile.identifiers() if f.direction == "from_servo"]


@st.composite
def hostile_replies(draw: st.DrawFn, ids: list[FrameId]) -> can.Message:
    frame_id = draw(st.sampled_from(ids))
    width = 0x1FFFFFFF if frame_id.extended else 0x7FF
    mask = frame_id.id_mask & width
    arbitration_id = (frame_id.arbitration_id & mask) | (draw(st.integers(0, width)) & ~mask)
    data = bytearray(draw(st.binary(min_size=0, max_size=8)))
    if frame_id.first_byte is not None and data and draw(st.booleans()):
        value, byte_mask = frame_id.first_byte
        data[0] = (value & byte_mask) | (data[0] & ~byte_mask & 0xFF)
    if draw(st.booleans()):  # a command byte the request/reply families echo, at any length
        head = draw(st.sampled_from(COMMAND_BYTES))
        data = bytearray([head]) + data[1:] if data else bytearray([head])
    if draw(st.booleans()) and data:  # the all-zero / all-ones tails of fault reports
        fill = draw(st.sampled_from([0x00, 0xFF, 0x7F, 0x80]))
        start = draw(st.integers(1, len(data)))
        data[start:] = bytes([fill]) * (len(data) - start)
    return can.Message(
        arbitration_id=arbitration_id,
        is_extended_id=frame_id.extended,
        data=bytes(data),
        dlc=len(data),
        check=False,
    )


@st.composite
def cases(draw: st.DrawFn) -> tuple[ServoProfile, list[can.Message]]:
    name, options = draw(st.sampled_from(VARIANTS))
    cls = get_profile(name)
    can_id = draw(st.integers(max(cls.min_id, 1), min(cls.max_id, 32)))
    profile = _profile(name, options, can_id)
    ids = _sent_by_servo(profile)
    return profile, draw(st.lists(hostile_replies(ids), min_size=1, max_size=25))


def _number_or_nan(value: float | None) -> bool:
    return value is None or math.isnan(value) or math.isfinite(value)


@settings(max_examples=600, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases())
def test_every_decoder_takes_any_reply_on_its_own_ids(
    case: tuple[ServoProfile, list[can.Message]],
) -> None:
    profile, messages = case
    for index, msg in enumerate(messages):
        profile.is_reply(msg)
        profile.exchange_key(msg)
        if isinstance(profile, Advising):
            profile.diagnose(msg)
        state = profile.decode(msg, float(index))
        if state is None:
            continue
        profile.last_state = state  # what the scheduler does: the next decode builds on it
        for field in ("position_deg", "velocity_dps", "current_a", "temperature_c", "voltage_v"):
            value = getattr(state, field)
            assert _number_or_nan(value), (profile.name, field, value, msg)
