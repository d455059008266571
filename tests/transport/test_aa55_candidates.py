"""The AA-55 candidate judge alone (mavservo/transport/aa55/candidates.py): a few bytes in, a
verdict out, with no decoder around it. The decoder's own tests (test_aa55_codec.py) cover the
same rules through whole streams."""

from __future__ import annotations

from mavservo.transport.aa55.candidates import CandidateJudge, Verdict
from mavservo.transport.aa55.codec import Frame, encode

REAL = encode(Frame(0x123, False, False, 2, b"\x01\x02"))  # AA C2 23 01 01 02 55
# A false start: a standard-ID 6-byte header whose 6 data bytes and end marker are REAL's.
FALSE_START = bytes((0xAA, 0xC6, 0x00, 0x00)) + REAL


def test_a_match_after_garbage_that_ends_with_a_real_frame_inside_is_rejected() -> None:
    judge = CandidateJudge("variable")
    end = len(FALSE_START)
    verdict = judge.judge(FALSE_START, 0, end, end, gap=True, idle=False)
    assert verdict is Verdict.REJECT


def test_the_same_match_on_a_clean_line_waits_then_stands_when_the_line_goes_idle() -> None:
    judge = CandidateJudge("variable")
    end = len(FALSE_START)
    assert judge.judge(FALSE_START, 0, end, end, gap=False, idle=False) is Verdict.WAIT
    assert judge.judge(FALSE_START, 0, end, end, gap=False, idle=True) is Verdict.ACCEPT


def test_a_frame_with_no_0xaa_inside_is_accepted_at_once() -> None:
    judge = CandidateJudge("variable")
    assert judge.judge(REAL, 0, len(REAL), len(REAL), gap=True, idle=False) is Verdict.ACCEPT


def test_a_cut_frame_may_complete_and_a_whole_non_frame_may_not() -> None:
    judge = CandidateJudge("variable")
    assert all(judge.could_complete(REAL[:n], 0, n) for n in range(1, len(REAL)))
    broken = REAL[:-1] + b"\x00"  # whole length, wrong end marker
    assert not judge.could_complete(broken, 0, len(broken))
    assert not judge.could_complete(b"\xaa\xc9\x00", 0, 3)  # DLC 9
    assert not judge.could_complete(b"\xaa\xc2\xff\xff", 0, 4)  # ID above 0x7FF


def test_the_fixed_protocol_waits_only_for_20_byte_frames() -> None:
    judge = CandidateJudge("fixed")
    assert judge.could_complete(b"\xaa\x55" + bytes(10), 0, 12)
    assert not judge.could_complete(REAL[:3], 0, 3)  # a variable-length header: never here


def test_the_first_0xaa_that_may_still_grow_is_where_the_held_bytes_start() -> None:
    judge = CandidateJudge("variable")
    buf = b"\x00\xaa\xc9\x01" + REAL[:4]  # garbage, a DLC-9 false start, a cut real frame
    assert judge.incomplete_start(buf, 0, len(buf)) == 4
    assert judge.held_back(buf, 0, len(buf), len(buf))
    assert judge.incomplete_start(b"\x00\x01", 0, 2) == 2
