"""The shared MIT packing (mavservo.servos.mit): vectors from the vendors' documents, round
trips, refusals, and cross-checks against two independent implementations from PyPI.

Vendor documents the vectors are built from:

* CubeMars "AK Series Actuator Driver Manual" V1.0.8, section 5.3 "MIT power mode communication
  protocol" (pp. 48-49): special CAN codes FC/FD/FE, the receive layout (position 16 bits in
  D0-D1, speed 12 bits D2-D3[7:4], KP 12 bits D3[3:0]-D4, KD 12 bits D5-D6[7:4], current 12 bits
  D6[3:0]-D7), the sending layout (D0 driver id, then position, speed, current the same way,
  D6 temperature, D7 error code) and the per-module range table (AK80-9: +-12.5 rad,
  +-50 rad/s, +-18, kp 0..500, kd 0..5) with its ``float_to_uint`` routine
  (``(x - min) * ((1 << bits) - 1) / span``, cast to int: truncation).
* Damiao "DM-J4310-2EC" manual V1.0 (2022-10-14), "MIT模式下控制帧" table (the same layout,
  kp range [0, 500], kd range [0, 5]) and the "反馈帧" table (D0 = ID | ERR << 4, POS 16,
  VEL 12, T 12, T_MOS, T_Rotor).
"""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mavservo.servos import mit
from mavservo.servos.mit import MitCommand, MitRanges, Span

AK80_9 = MitRanges(
    position_rad=Span.symmetric(12.5),
    velocity_rad_s=Span.symmetric(50.0),
    torque_nm=Span.symmetric(18.0),
    kp=Span(0.0, 500.0),
    kd=Span(0.0, 5.0),
)
DM_J4310 = MitRanges(
    position_rad=Span.symmetric(12.5),
    velocity_rad_s=Span.symmetric(30.0),
    torque_nm=Span.symmetric(10.0),
    kp=Span(0.0, 500.0),
    kd=Span(0.0, 5.0),
)

# (command, ranges, frame): each field's count is the manual's float_to_uint of the value, laid
# out as the receive table says. Mid-range values truncate (32767.5 -> 32767, 2047.5 -> 2047).
VECTORS = [
    # all zero set points on an AK80-9: p 0x7FFF, v 0x7FF, kp 0, kd 0, t 0x7FF
    (MitCommand(0.0, 0.0, 0.0, 0.0, 0.0), AK80_9, "7fff7ff0000007ff"),
    # every field at an end: p max 0xFFFF, v min 0, kp max 0xFFF, kd max 0xFFF, t min 0
    (MitCommand(12.5, -50.0, 500.0, 5.0, -18.0), AK80_9, "ffff000ffffff000"),
    # p min 0, v max 0xFFF, kp 0, kd 0, t max 0xFFF
    (MitCommand(-12.5, 50.0, 0.0, 0.0, 18.0), AK80_9, "0000fff000000fff"),
    # a hold on a DM-J4310: p 1 rad -> int(13.5 * 65535 / 25) = 35388 = 0x8A3C,
    # v 0 -> 0x7FF, kp 20 -> int(20 * 4095 / 500) = 163 = 0x0A3, kd 1 -> 819 = 0x333,
    # t 0 -> 0x7FF
    (MitCommand(1.0, 0.0, 20.0, 1.0, 0.0), DM_J4310, "8a3c7ff0a33337ff"),
]


@pytest.mark.parametrize(("command", "ranges", "frame"), VECTORS)
def test_command_vectors(command: MitCommand, ranges: MitRanges, frame: str) -> None:
    assert mit.pack_command(command, ranges).hex() == frame


def test_special_frames_are_the_documented_codes() -> None:
    """CubeMars 5.3 "Special Can code" and the Damiao vendor routines (clear error FB)."""
    assert mit.ENTER_MOTOR_MODE.hex() == "fffffffffffffffc"
    assert mit.EXIT_MOTOR_MODE.hex() == "fffffffffffffffd"
    assert mit.SET_ZERO.hex() == "fffffffffffffffe"
    assert mit.CLEAR_ERROR.hex() == "fffffffffffffffb"
    assert all(mit.is_special(f) for f in (mit.ENTER_MOTOR_MODE, mit.CLEAR_ERROR))
    assert not mit.is_special(bytes.fromhex("7fff7ff0000007ff"))


def test_reply_vector_damiao_feedback_table() -> None:
    """D0 = ID | ERR << 4 = 0x11 (status 1 enabled, id 1); POS 0x7FFF; VEL 0x7FF; T 0x7FF."""
    reply = mit.unpack_reply(bytes.fromhex("117fff7ff7ff191a"), DM_J4310)
    assert reply.head == 0x11
    assert reply.position_rad == pytest.approx(-12.5 + 32767 * 25 / 65535)
    assert reply.velocity_rad_s == pytest.approx(-30 + 2047 * 60 / 4095)
    assert reply.torque_nm == pytest.approx(-10 + 2047 * 20 / 4095)


def test_reply_pack_lays_out_the_sending_table() -> None:
    data = mit.pack_reply(0x03, 12.5, -50.0, 18.0, AK80_9)
    assert data.hex() == "03ffff000fff"


@pytest.mark.parametrize(
    "command",
    [
        MitCommand(12.6, 0, 0, 0, 0),
        MitCommand(0, -50.01, 0, 0, 0),
        MitCommand(0, 0, -1, 0, 0),
        MitCommand(0, 0, 0, 5.5, 0),
        MitCommand(0, 0, 0, 0, math.nan),
        MitCommand(math.inf, 0, 0, 0, 0),
    ],
)
def test_out_of_range_set_points_are_refused_not_clamped(command: MitCommand) -> None:
    with pytest.raises(ValueError, match="outside"):
        mit.pack_command(command, AK80_9)


def test_a_command_that_would_look_like_a_special_frame_is_refused() -> None:
    # p, v, kp, kd all at their maxima and t near max: FF FF FF FF FF FF FF xx
    with pytest.raises(ValueError, match="special frame"):
        mit.pack_command(MitCommand(12.5, 50.0, 500.0, 5.0, 18.0), AK80_9)


def test_special_frames_are_not_decoded_as_commands() -> None:
    with pytest.raises(ValueError, match="special"):
        mit.unpack_command(mit.ENTER_MOTOR_MODE, AK80_9)


def test_bad_ranges_and_short_frames_are_refused() -> None:
    with pytest.raises(ValueError):
        Span(1.0, 1.0)
    with pytest.raises(ValueError):
        Span(-math.inf, 1.0)
    with pytest.raises(ValueError, match="6 bytes"):
        mit.unpack_reply(b"\x01\x02\x03", AK80_9)
    with pytest.raises(ValueError, match="8 bytes"):
        mit.unpack_command(b"\x00" * 7, AK80_9)


def test_reply_readings_past_the_range_saturate_on_the_device_side() -> None:
    reply = mit.unpack_reply(mit.pack_reply(1, 99.0, math.nan, -99.0, AK80_9), AK80_9)
    assert reply.position_rad == pytest.approx(12.5)
    assert reply.torque_nm == pytest.approx(-18.0)
    assert abs(reply.velocity_rad_s) <= mit.step(AK80_9.velocity_rad_s, mit.VELOCITY_BITS)


def _in(span: Span) -> st.SearchStrategy[float]:
    return st.floats(span.low, span.high, allow_nan=False, allow_infinity=False)


ranges_strategy = st.builds(
    MitRanges,
    position_rad=st.floats(0.5, 100.0).map(Span.symmetric),
    velocity_rad_s=st.floats(0.5, 100.0).map(Span.symmetric),
    torque_nm=st.floats(0.5, 500.0).map(Span.symmetric),
    kp=st.just(Span(0.0, 500.0)),
    kd=st.just(Span(0.0, 5.0)),
)


@st.composite
def commands(draw: st.DrawFn) -> tuple[MitRanges, MitCommand]:
    ranges = draw(ranges_strategy)
    command = MitCommand(
        draw(_in(ranges.position_rad)),
        draw(_in(ranges.velocity_rad_s)),
        draw(_in(ranges.kp)),
        draw(st.floats(0.0, 4.9)),  # kd below its top keeps the frame clear of FF x7
        draw(_in(ranges.torque_nm)),
    )
    return ranges, command


@given(commands())
def test_command_round_trip_within_one_count(case: tuple[MitRanges, MitCommand]) -> None:
    ranges, command = case
    back = mit.unpack_command(mit.pack_command(command, ranges), ranges)
    for field, span, bits in (
        ("position_rad", ranges.position_rad, mit.POSITION_BITS),
        ("velocity_rad_s", ranges.velocity_rad_s, mit.VELOCITY_BITS),
        ("kp", ranges.kp, mit.GAIN_BITS),
        ("kd", ranges.kd, mit.GAIN_BITS),
        ("torque_nm", ranges.torque_nm, mit.TORQUE_BITS),
    ):
        sent, got = getattr(command, field), getattr(back, field)
        # truncation: the decoded value is at most one count below, never above
        assert got <= sent + 1e-9 * max(1.0, abs(sent))
        assert sent - got <= mit.step(span, bits) * (1 + 1e-9)


@given(
    ranges_strategy,
    st.integers(0, 255),
    st.integers(0, 0xFFFF),
    st.integers(0, 0xFFF),
    st.integers(0, 0xFFF),
)
def test_reply_round_trip_is_exact_on_counts(
    ranges: MitRanges, head: int, p: int, v: int, t: int
) -> None:
    data = bytes([head, p >> 8, p & 0xFF, v >> 4, (v & 0xF) << 4 | t >> 8, t & 0xFF])
    reply = mit.unpack_reply(data, ranges)
    again = mit.pack_reply(
        reply.head, reply.position_rad, reply.velocity_rad_s, reply.torque_nm, ranges
    )
    # from_field then the truncating to_field may land one count low on a float rounding
    twice = mit.unpack_reply(again, ranges)
    assert twice.head == head
    for field, span, bits in (
        ("position_rad", ranges.position_rad, mit.POSITION_BITS),
        ("velocity_rad_s", ranges.velocity_rad_s, mit.VELOCITY_BITS),
        ("torque_nm", ranges.torque_nm, mit.TORQUE_BITS),
    ):
        gap = getattr(reply, field) - getattr(twice, field)
        assert -1e-9 <= gap <= mit.step(span, bits) * (1 + 1e-9)


# -- cross-checks against independent implementations (test extras only; never copied) -----


@given(commands())
def test_cross_check_damiao_motor_encoder(case: tuple[MitRanges, MitCommand]) -> None:
    """`damiao-motor` (PyPI) packs the same bits: its float_to_uint also truncates."""
    motor_module = pytest.importorskip("damiao_motor.core.motor")
    ranges, c = case
    # its kp/kd ranges are the fixed 0..500 / 0..5 of the Damiao manual
    expected = bytes(
        [
            *_damiao_fields(motor_module, c, ranges),
        ]
    )
    assert mit.pack_command(c, ranges) == expected


def _damiao_fields(module, c: MitCommand, r: MitRanges) -> bytes:  # type: ignore[no-untyped-def]
    f = module.float_to_uint
    p = f(c.position_rad, r.position_rad.low, r.position_rad.high, 16)
    v = f(c.velocity_rad_s, r.velocity_rad_s.low, r.velocity_rad_s.high, 12)
    kp = f(c.kp, module.KP_MIN, module.KP_MAX, 12)
    kd = f(c.kd, module.KD_MIN, module.KD_MAX, 12)
    t = f(c.torque_nm, r.torque_nm.low, r.torque_nm.high, 12)
    return bytes(
        [p >> 8, p & 0xFF, v >> 4, (v & 0xF) << 4 | kp >> 8, kp & 0xFF, kd >> 4,
         (kd & 0xF) << 4 | t >> 8, t & 0xFF]
    )  # fmt: skip


@given(ranges_strategy, st.binary(min_size=8, max_size=8))
def test_cross_check_damiao_motor_decoder(ranges: MitRanges, data: bytes) -> None:
    module = pytest.importorskip("damiao_motor.core.motor")
    ours = mit.unpack_reply(data, ranges)
    u2f = module.uint_to_float
    assert ours.position_rad == pytest.approx(
        u2f(data[1] << 8 | data[2], ranges.position_rad.low, ranges.position_rad.high, 16)
    )
    assert ours.velocity_rad_s == pytest.approx(
        u2f(data[3] << 4 | data[4] >> 4, ranges.velocity_rad_s.low, ranges.velocity_rad_s.high, 12)
    )
    assert ours.torque_nm == pytest.approx(
        u2f((data[4] & 0xF) << 8 | data[5], ranges.torque_nm.low, ranges.torque_nm.high, 12)
    )


def test_cross_check_tmotorcancontrol_layout_and_where_it_disagrees() -> None:
    """`TMotorCANControl` (PyPI) lays the bits out as the manual does, but scales by
    ``2**bits / span`` and caps one count short of the top, where the CubeMars manual's
    float_to_uint scales by ``(2**bits - 1) / span``. We follow the manual: for 0 rad on
    +-12.5 the library sends 0x8000 where the manual's routine gives 0x7FFF, and for the
    maximum 0xFFFE where the manual gives 0xFFFF."""
    mit_can = pytest.importorskip("TMotorCANControl.mit_can")
    f = mit_can.CAN_Manager.float_to_uint
    assert f(0.0, -12.5, 12.5, 16) == 0x8000  # 2**16 / 2: one count above the manual's 0x7FFF
    assert mit.to_field(0.0, Span.symmetric(12.5), 16) == 0x7FFF
    assert f(12.5, -12.5, 12.5, 16) == 0xFFFE
    assert mit.to_field(12.5, Span.symmetric(12.5), 16) == 0xFFFF
    # the decoders agree: both divide by 2**bits - 1
    u2f = mit_can.CAN_Manager.uint_to_float
    for count in (0, 1, 0x7FF, 0xFFF):
        assert mit.from_field(count, Span.symmetric(50.0), 12) == pytest.approx(
            u2f(count, -50.0, 50.0, 12)
        )
