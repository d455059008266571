"""busload: exact frame lengths against hand-counted field layouts, and R arithmetic."""

from __future__ import annotations

import can
import pytest
from hypothesis import given
from hypothesis import strategies as st

from mavservo.scheduling.busload import (
    FrameFlow,
    ServoTraffic,
    frame_bits,
    frame_time,
    load_ratio,
    message_bits,
    stuffable_bits,
    worst_case_load,
    worst_case_stuff_bits,
)


def count_stuff_bits(bits: list[int]) -> int:
    """Reference CAN bit stuffer: a complementary bit after every run of five equal bits.

    Stuff bits count towards the next run, as on the wire.
    """
    stuffed = 0
    run_value, run_length = None, 0
    for bit in bits:
        if bit == run_value:
            run_length += 1
        else:
            run_value, run_length = bit, 1
        if run_length == 5:
            stuffed += 1
            run_value, run_length = 1 - bit, 1
    return stuffed


def adversarial_bits(n: int) -> list[int]:
    """Five equal bits, then runs of four that each combine with the previous stuff bit."""
    bits = [0] * min(5, n)
    value = 1
    while len(bits) < n:
        bits.extend([value] * min(4, n - len(bits)))
        value = 1 - value
    return bits


# Hand counts from the CAN 2.0 field layout (see module docstring), IFS included.
@pytest.mark.parametrize(
    ("extended", "dlc", "remote", "no_stuffing", "worst"),
    [
        (False, 8, False, 111, 135),  # 47 + 64; stuffable 98 -> +24
        (False, 0, False, 47, 55),  # stuffable 34 -> +8
        (False, 2, False, 63, 75),  # stuffable 50 -> +12
        (True, 8, False, 131, 160),  # 67 + 64; stuffable 118 -> +29
        (True, 0, False, 67, 80),  # stuffable 54 -> +13
        (False, 8, True, 47, 55),  # remote frame: no data field whatever the DLC
        (True, 4, True, 67, 80),
    ],
)
def test_frame_bits_match_hand_counts(extended, dlc, remote, no_stuffing, worst):
    assert frame_bits(extended, dlc, remote, stuffing="none") == no_stuffing
    assert frame_bits(extended, dlc, remote) == worst


@given(st.integers(min_value=5, max_value=200))
def test_adversarial_pattern_reaches_the_worst_case_formula(n):
    assert count_stuff_bits(adversarial_bits(n)) == (n - 1) // 4


@given(st.booleans(), st.integers(0, 8), st.booleans(), st.data())
def test_no_bit_pattern_needs_more_stuff_bits_than_the_worst_case(extended, dlc, remote, data):
    n = stuffable_bits(extended, dlc, remote)
    bits = data.draw(st.lists(st.integers(0, 1), min_size=n, max_size=n))
    assert count_stuff_bits(bits) <= worst_case_stuff_bits(extended, dlc, remote)


@given(st.booleans(), st.integers(0, 7), st.booleans())
def test_lengths_grow_with_dlc_and_extended_costs_twenty_bits(extended, dlc, remote):
    assert frame_bits(extended, dlc + 1) > frame_bits(extended, dlc)
    assert frame_bits(True, dlc, remote, "none") - frame_bits(False, dlc, remote, "none") == 20
    assert frame_bits(extended, dlc, remote) >= frame_bits(extended, dlc, remote, "none")


@pytest.mark.parametrize("dlc", [-1, 9, 2.0, True])
def test_bad_dlc_is_refused(dlc):
    with pytest.raises(ValueError):
        frame_bits(False, dlc)


def test_bad_stuffing_and_bitrate_are_refused():
    with pytest.raises(ValueError):
        frame_bits(False, 8, stuffing="best")
    with pytest.raises(ValueError):
        frame_time(False, 8, 0)


def test_frame_time_at_one_megabit():
    assert frame_time(False, 8, 1_000_000) == pytest.approx(135e-6)
    assert frame_time(True, 8, 500_000) == pytest.approx(320e-6)


def test_message_bits_reads_the_message_shape():
    std = can.Message(arbitration_id=0x141, is_extended_id=False, data=bytes(8))
    ext = can.Message(arbitration_id=0x401, is_extended_id=True, data=bytes(3))
    rtr = can.Message(arbitration_id=0x141, is_extended_id=False, is_remote_frame=True, dlc=8)
    assert message_bits(std) == 135
    assert message_bits(ext) == frame_bits(True, 3)
    assert message_bits(rtr) == 55
    assert message_bits(std, stuffing="none") == 111


def test_load_ratio_is_bits_per_second_over_bitrate():
    # 20 Hz of 135-bit frames + 10 Hz of 160-bit frames = 4300 bit/s at 100 kbit/s.
    flows = [FrameFlow(20.0, False, 8), FrameFlow(10.0, True, 8)]
    assert load_ratio(flows, 100_000) == pytest.approx(0.043)
    assert load_ratio([], 1_000_000) == 0.0


def test_worst_case_load_of_a_paper_schedule():
    # RMD-X style: standard 8-byte command at 20 Hz (T_c = 50 ms) with one reply each,
    # one 8-byte request at 1/0.09 Hz with one reply. 8 servos at 1 Mbit/s.
    servo = ServoTraffic(
        command_hz=20.0,
        command_extended=False,
        command_dlc=8,
        replies_per_command=1,
        request_hz=1 / 0.09,
        request_shapes=((False, 8),),
        replies_per_request=1,
    )
    expected_bits_per_s = 8 * (20 * 135 * 2 + (1 / 0.09) * 135 * 2)
    assert worst_case_load([servo] * 8, 1_000_000) == pytest.approx(expected_bits_per_s / 1e6)


def test_push_style_servo_without_replies_or_requests():
    servo = ServoTraffic(
        command_hz=100.0,
        command_extended=True,
        command_dlc=4,
        replies_per_command=0,
        request_hz=0.0,
        request_shapes=(),
        replies_per_request=0,
    )
    assert worst_case_load([servo], 250_000) == pytest.approx(100 * frame_bits(True, 4) / 250_000)
