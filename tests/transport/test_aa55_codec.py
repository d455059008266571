"""The AA-55 codec: pinned bytes, round trips, chunking, garbage and corruption (hypothesis)."""

from __future__ import annotations

import io

import can
import pytest
from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st

from mavservo.transport.aa55 import codec as aa55
from mavservo.transport.aa55.codec import (
    AdapterSettings,
    ControlFrame,
    Decoder,
    Frame,
    Rejection,
    encode,
)
from mavservo.transport.aa55.layout import checksum_ok


@st.composite
def frames(draw: st.DrawFn) -> Frame:
    ext = draw(st.booleans())
    rtr = draw(st.booleans())
    arb_id = draw(st.integers(0, aa55.MAX_EXT_ID if ext else aa55.MAX_STD_ID))
    dlc = draw(st.integers(0, 8))
    data = b"" if rtr else draw(st.binary(min_size=dlc, max_size=dlc))
    return Frame(arb_id, ext, rtr, dlc, data)


protocols = st.sampled_from(["variable", "fixed"])


def data_frames_only(items: list) -> list[Frame]:
    return [i for i in items if isinstance(i, Frame)]


# -- pinned bytes --------------------------------------------------------------------------------


def test_design_example_is_encoded_byte_for_byte() -> None:
    msg = can.Message(
        arbitration_id=0x123, data=bytes.fromhex("1122334455667788"), is_extended_id=False
    )
    assert encode(msg) == bytes.fromhex("AA C8 23 01 11 22 33 44 55 66 77 88 55")


def test_extended_remote_frame_has_no_data_bytes_and_dlc_nibble() -> None:
    msg = can.Message(arbitration_id=0x1ABCDEF0, is_extended_id=True, is_remote_frame=True, dlc=4)
    assert encode(msg) == bytes.fromhex("AA F4 F0 DE BC 1A 55")
    (frame,) = Decoder().feed(encode(msg))
    assert frame.is_remote_frame and frame.dlc == 4 and frame.data == b""


def test_fixed_frame_layout_and_checksum() -> None:
    msg = can.Message(arbitration_id=0x141, data=b"\x9c", is_extended_id=False)
    raw = encode(msg, "fixed")
    assert len(raw) == 20
    assert raw[:5] == bytes.fromhex("AA 55 01 01 01")
    assert raw[5:9] == (0x141).to_bytes(4, "little")
    assert raw[9] == 1 and raw[10] == 0x9C and raw[11:18] == bytes(7)
    assert raw[19] == sum(raw[2:19]) & 0xFF


def test_settings_frame_matches_the_documented_layout() -> None:
    raw = aa55.settings_frame(500_000, extended=True, filter_id=0x141, mask=0x7FF, mode="loopback")
    assert raw[:5] == bytes.fromhex("AA 55 12 03 02")
    assert raw[5:9] == (0x141).to_bytes(4, "little") and raw[9:13] == (0x7FF).to_bytes(4, "little")
    assert raw[13:19] == bytes.fromhex("01 01 00 00 00 00")
    assert raw[19] == sum(raw[2:19]) & 0xFF
    (settings,) = Decoder().feed(raw)
    assert settings == AdapterSettings(500_000, True, 0x141, 0x7FF, "loopback", "variable", raw)


def test_settings_frame_equals_python_can_seeedstudio_init_frame() -> None:
    """python-can's seeedstudio driver is an independent implementation of the same frame."""
    from can.interfaces.seeedstudio.seeedstudio import SeeedBus

    written = io.BytesIO()
    bus = SeeedBus.__new__(SeeedBus)
    bus.ser = written
    bus.bit_rate, bus.frame_type, bus.op_mode = 250_000, "STD", "normal"
    bus.filter_id = bytearray(4)
    bus.mask_id = bytearray(4)
    bus.init_frame()
    assert written.getvalue() == aa55.settings_frame(250_000)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(arbitration_id=0x800, is_extended_id=False), "out of range for a standard"),
        (dict(arbitration_id=0x20000000, is_extended_id=True), "out of range for an? extended"),
    ],
)
def test_encode_rejects_impossible_ids(kwargs: dict, match: str) -> None:
    msg = can.Message(data=b"", check=False, **kwargs)
    with pytest.raises(ValueError, match=match):
        encode(msg)


def test_encode_rejects_long_data_and_unknown_protocol() -> None:
    long = Frame(0x10, False, False, 8, bytes(9))
    with pytest.raises(ValueError, match="at most 8"):
        encode(long)
    with pytest.raises(ValueError, match="unknown protocol"):
        encode(Frame(1, False, False, 0, b""), "bogus")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="bitrate 123"):
        aa55.settings_frame(123)


# -- properties ----------------------------------------------------------------------------------


@given(st.lists(frames(), max_size=30), protocols)
def test_round_trip(sent: list[Frame], protocol: str) -> None:
    stream = b"".join(encode(f, protocol) for f in sent)
    dec = Decoder(protocol)
    out = dec.feed(stream)
    # only the last frame may wait for what follows it (a clean stream never waits longer)
    assert out == sent[: len(out)] and len(out) >= len(sent) - 1
    assert out + dec.flush() == sent
    assert dec.frames == len(sent) and dec.bytes_discarded == 0 and not dec.rejected
    assert dec.pending == 0


@given(st.lists(frames(), max_size=20), protocols, st.data())
def test_any_chunking_decodes_the_same(
    sent: list[Frame], protocol: str, data: st.DataObject
) -> None:
    stream = b"".join(encode(f, protocol) for f in sent)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=40)))
    dec = Decoder(protocol)
    out: list = []
    prev = 0
    for cut in [*cuts, len(stream)]:
        out += dec.feed(stream[prev:cut])
        prev = cut
    assert out + dec.flush() == sent


@settings(suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=2000), protocols)
def test_arbitrary_bytes_never_raise_and_memory_is_bounded(junk: bytes, protocol: str) -> None:
    dec = Decoder(protocol)
    for i in range(0, len(junk), 7):
        dec.feed(junk[i : i + 7])
        assert dec.pending < aa55.MAX_PENDING
    dec.flush()
    assert dec.pending == 0


@given(st.lists(st.tuples(st.binary(max_size=6), frames()), min_size=1, max_size=15))
@example(  # garbage AA 55 starts a 20-byte candidate whose checksum passes over three frames
    [
        (b"", Frame(0x28F, False, True, 3, b"")),
        (b"\x8d", Frame(0x7FF, True, True, 2, b"")),
        (b"\xaaU", Frame(0x70A, True, False, 1, b"\x45")),
        (b"NV", Frame(0x7FF, False, False, 0, b"")),
        (b"\xe8\xf8\x7f", Frame(0x100, False, True, 8, b"")),
    ]
)
def test_garbage_between_frames_loses_no_intact_frame(pieces: list[tuple[bytes, Frame]]) -> None:
    """Whatever precedes a frame, the frame comes out (the decoder rescans every false start)."""
    stream = b"".join(g + encode(f) for g, f in pieces)
    dec = Decoder()
    out = dec.feed(stream) + dec.flush()
    got = data_frames_only(out)
    # every intact frame appears, in order (garbage may add frames of its own, never remove ours)
    it = iter(got)
    assert all(any(x == f for x in it) for _, f in pieces)


@st.composite
def servo_like_stream(draw: st.DrawFn) -> bytes:
    """Runs of one or two layouts (as servo replies are) with false starts and damage inside."""
    layouts = draw(st.lists(st.tuples(st.booleans(), st.integers(0, 8)), min_size=1, max_size=2))
    pieces = []
    for _ in range(draw(st.integers(1, 40))):
        ext, dlc = draw(st.sampled_from(layouts))
        frame = Frame(
            draw(st.integers(0, aa55.MAX_EXT_ID if ext else aa55.MAX_STD_ID)),
            ext,
            False,
            dlc,
            draw(st.binary(min_size=dlc, max_size=dlc)),
        )
        raw = bytearray(encode(frame))
        damage = draw(st.sampled_from(["none"] * 6 + ["flip", "cut", "false_start"]))
        if damage == "flip":
            raw[draw(st.integers(0, len(raw) - 1))] ^= draw(st.integers(1, 255))
        elif damage == "cut":
            del raw[draw(st.integers(1, len(raw) - 1)) :]
        elif damage == "false_start":
            raw[:0] = bytes((0xAA, raw[1]))
        pieces.append(bytes(raw))
    return b"".join(pieces)


@given(servo_like_stream())
def test_runs_of_one_layout_decode_as_frame_by_frame(stream: bytes) -> None:
    """The run fast path (whole chunk) gives what one byte at a time (never a run) gives."""
    whole, bytewise = Decoder(), Decoder()
    out_whole = whole.feed(stream) + whole.flush()
    out_bytewise = [f for i in range(len(stream)) for f in bytewise.feed(stream[i : i + 1])]
    out_bytewise += bytewise.flush()
    assert out_whole == out_bytewise
    assert [type(f) for f in out_whole] == [type(f) for f in out_bytewise]
    assert whole.frames == bytewise.frames
    assert whole.bytes_discarded == bytewise.bytes_discarded
    assert whole.rejected == bytewise.rejected


def test_run_fast_path_frames_are_complete_frames() -> None:
    sent = [Frame(0x241 + i, False, False, 8, bytes([i] * 8)) for i in range(50)]
    sent += [Frame(0x1ABCDEF0 + i, True, True, 3, b"") for i in range(5)]
    out = Decoder().feed(b"".join(encode(f) for f in sent), timestamp=12.5)
    assert out == sent
    assert all(type(f) is Frame and f.timestamp == 12.5 for f in out)
    msg = out[3].to_message("can0")
    assert isinstance(msg, can.Message) and msg.equals(
        can.Message(
            timestamp=12.5,
            arbitration_id=0x244,
            is_extended_id=False,
            data=bytes([3] * 8),
            channel="can0",
            is_rx=True,
        )
    )
    assert isinstance(msg.data, bytearray)
    assert out[-1].to_message().dlc == 3 and out[-1].to_message().is_remote_frame


@given(st.lists(frames(), min_size=1, max_size=10), st.data())
def test_fixed_protocol_never_emits_a_frame_that_was_not_sent(
    sent: list[Frame], data: st.DataObject
) -> None:
    """The checksum catches one corrupted byte per frame: every frame out is one that went in.

    (Two compensating errors in one frame can pass a byte-sum checksum; see
    docs/engineering/reliability.md.)
    """
    stream = bytearray(b"".join(encode(f, "fixed") for f in sent))
    frames_hit = data.draw(st.sets(st.integers(0, len(sent) - 1), min_size=1, max_size=4))
    for index in frames_hit:
        i = index * aa55.FIXED_LENGTH + data.draw(st.integers(0, aa55.FIXED_LENGTH - 1))
        stream[i] ^= data.draw(st.integers(1, 255))
    dec = Decoder("fixed")
    got = data_frames_only(dec.feed(bytes(stream)) + dec.flush())
    assume(got != sent)
    assert set(got) <= set(sent)


def test_false_start_overlapping_a_real_frame_is_rescanned() -> None:
    real = encode(Frame(0x010, False, False, 8, bytes.fromhex("9C1E0A0014000500")))
    # A 0xAA whose "type" claims an 8-byte extended frame swallows the start of the real one:
    # its ID (01 AA C8 10) is in range, and it fails only at its end marker, inside the real frame.
    stream = b"\xaa\xe8\x01" + real
    dec = Decoder()
    (frame,) = dec.feed(stream)
    assert frame.arbitration_id == 0x010
    assert dec.rejected[Rejection.BAD_END] == 1
    assert dec.rejected[Rejection.BAD_ID] == 0


def test_payload_containing_aa_and_55_is_not_split() -> None:
    frame = Frame(0x0AA, False, False, 8, bytes.fromhex("AA55AAC85555AA55"))
    dec = Decoder()
    assert dec.feed(encode(frame)) + dec.flush() == [frame] and not dec.rejected
    nxt = Frame(0x0AB, False, False, 0, b"")
    assert dec.feed(encode(frame) + encode(nxt)) == [frame, nxt] and not dec.rejected


def test_a_frame_that_could_hide_another_waits_only_for_the_next_frame() -> None:
    """A payload that begins a plausible frame running past the end is held until the frame
    after it is whole (a USB read brings it at once) or the line goes idle."""
    frame = Frame(0x0AA, False, False, 8, bytes.fromhex("0102AAC8220103AA"))
    nxt = encode(Frame(0x0AB, False, False, 2, b"\x01\x02"))
    dec = Decoder()
    assert dec.feed(encode(frame)) == []  # its inner candidate could still be the real frame
    assert dec.pending == 13
    assert dec.feed(nxt[:3]) == []  # a frame start, maybe a garbage 0xAA: not known yet
    after = Frame(0x0AB, False, False, 2, b"\x01\x02")
    assert dec.feed(nxt[3:]) == [frame, after]  # a whole frame follows it: it was real
    assert dec.pending == 0
    idle = Decoder()
    assert idle.feed(encode(frame)) == [] and idle.flush() == [frame]


def test_the_most_the_decoder_holds_is_below_max_pending() -> None:
    """The worst case behind ``MAX_PENDING``: a 15-byte frame, a frame starting on its 13th
    byte and running past it, and 14 of the 15 bytes of the frame after that: 41 bytes, all
    held until the last byte tells whether a whole frame follows the inner one."""
    inner = encode(Frame(0x01020355, True, False, 8, bytes(8)))  # AA E8 55 03 02 01 ...
    outer = b"\xaa\xe8\x01\x00\x00\x00" + bytes(6) + inner[:2] + inner[2:3]
    assert len(outer) == 15 and outer[-1] == 0x55  # a valid frame: its end marker is inner's ID
    follower = encode(Frame(0x1ABCDEF, True, False, 8, bytes(range(8))))
    stream = outer + inner[3:] + follower
    dec = Decoder()
    assert dec.feed(stream[:41]) == []
    assert dec.pending == 41 < aa55.MAX_PENDING
    out = dec.feed(stream[41:]) + dec.flush()
    assert [f.arbitration_id for f in out] == [0x01020355, 0x1ABCDEF]  # outer's 0xAA was false


def test_without_overlap_resolution_nothing_waits_and_the_first_candidate_wins() -> None:
    frame = Frame(0x0AA, False, False, 8, bytes.fromhex("0102AAC8220103AA"))
    dec = Decoder(resolve_overlaps=False)
    assert dec.feed(encode(frame)) == [frame] and dec.pending == 0


def test_truncated_frame_does_not_swallow_the_next_one() -> None:
    """A cut frame whose length runs into the next frame and happens to end on a 0x55 there."""
    cut = encode(Frame(0x101, False, False, 8, bytes(8)))[:7]  # AA C8 01 01 00 00 00
    real = Frame(0x202, False, False, 8, bytes.fromhex("1155131415161718"))
    after = Frame(0x303, False, False, 1, b"\x01")
    stream = cut + encode(real) + encode(after)
    assert stream[12] == 0x55  # the cut frame's 13th byte is a 0x55 inside ``real``
    dec = Decoder()
    got = dec.feed(stream) + dec.flush()
    assert got == [real, after]
    assert dec.rejected[Rejection.OVERLAP] == 1


def test_cut_frame_ending_with_the_next_one_gives_way_when_garbage_follows() -> None:
    """A cut frame runs exactly to the end of the next one: alone, that reads as a clean frame
    (the decoder must keep it, see test_a_clean_stream_can_hold_a_cut_frame_and_its_follower);
    followed by garbage instead of a frame start, the inner frame is the likelier one."""
    cut = encode(Frame(0x101, False, False, 8, bytes(8)))[:5]  # AA C8 01 01 00
    real = Frame(0x202, False, False, 3, b"\x01\x02\x03")  # 8 bytes: 5 + 8 = 13, C8's length
    after = Frame(0x303, False, False, 1, b"\x01")
    dec = Decoder()
    got = dec.feed(cut + encode(real) + b"\x07" + encode(after)) + dec.flush()
    assert got == [real, after]
    assert dec.rejected[Rejection.OVERLAP] == 1


def test_a_clean_stream_can_hold_a_cut_frame_and_its_follower() -> None:
    """Why 100% recovery is out of reach without a checksum: the same bytes are a clean stream.

    A frame cut after 5 bytes, then an intact 8-byte frame, then a frame: these 26 bytes are,
    byte for byte, a 13-byte frame whose payload ends like a frame, then that frame. Decoding
    every clean stream exactly means emitting the 13-byte frame, so the intact one inside is
    lost. The bench counts such losses apart (``forced_losses`` in bench/bench_aa55.py).
    """
    cut = encode(Frame(0x101, False, False, 8, bytes(8)))[:5]
    real = Frame(0x202, False, False, 3, b"\x01\x02\x03")
    after = Frame(0x303, False, False, 1, b"\x01")
    corrupted = cut + encode(real) + encode(after)
    clean_outer = Frame(0x101, False, False, 8, b"\x00" + encode(real)[:-1])
    assert corrupted == encode(clean_outer) + encode(after)
    dec = Decoder()
    assert dec.feed(corrupted) + dec.flush() == [clean_outer, after]


def test_garbage_start_does_not_swallow_the_frame_it_covers() -> None:
    """Garbage AA E8 (extended, DLC 8: 15 bytes) ends exactly on a following 13-byte frame."""
    real = Frame(0x123, False, False, 8, bytes(range(8)))
    dec = Decoder()
    got = dec.feed(b"\x00\x00\xaa\xe8" + encode(real) + b"\x07") + dec.flush()
    assert got == [real]


def _with_checksum(frame: Frame, checksum: int) -> Frame:
    """``frame`` with its first data byte set so that its 20-byte encoding ends in ``checksum``."""
    data = bytearray(frame.data)
    data[0] = 0
    data[0] = (checksum - encode(frame._replace(data=bytes(data)), "fixed")[19]) & 0xFF
    out = frame._replace(data=bytes(data))
    assert encode(out, "fixed")[19] == checksum
    return out


@pytest.mark.parametrize("garbage", [b"", b"\x05\xd6", b"\xaa\x04"])
def test_fixed_frame_cut_before_its_checksum_does_not_swallow_the_next_one(
    garbage: bytes,
) -> None:
    """Cut just before a checksum of 0xAA, a frame takes the next frame's 0xAA as its checksum.

    The 20 bytes pass the check; what gives them away is that ``55 01 ...`` follows them, not a
    frame start, while the frame beginning on their last byte has a valid checksum too (and is
    followed by a frame, or by garbage: then neither is, and the inner one still wins).
    """
    cut = _with_checksum(Frame(0x101, False, False, 2, b"\x00\x07"), 0xAA)
    real = Frame(0x202, False, False, 8, bytes(range(8)))
    after = Frame(0x1ABCDE, True, False, 1, b"\x09")
    stream = encode(cut, "fixed")[:19] + encode(real, "fixed") + garbage + encode(after, "fixed")
    dec = Decoder("fixed")
    assert data_frames_only(dec.feed(stream) + dec.flush()) == [real, after]
    assert dec.rejected[Rejection.OVERLAP] == 1
    # a read that ends right after the 20 bytes (their last byte 0xAA) waits for the next byte
    bytewise, _ = _decoded_in_chunks(stream, "fixed", list(range(len(stream))))
    assert data_frames_only(bytewise) == [real, after]
    # the same frame whole, followed by a frame, is a frame like any other
    clean = Decoder("fixed")
    whole = encode(cut, "fixed") + encode(real, "fixed")
    assert clean.feed(whole) == [cut, real] and not clean.rejected


@given(
    st.lists(frames(), min_size=1, max_size=6),
    st.integers(0, 5),
    st.integers(3, 19),
    st.binary(min_size=17, max_size=17),
    st.binary(max_size=3),
)
def test_fixed_false_start_passing_its_checksum_never_swallows_a_frame(
    sent: list[Frame], where: int, cut: int, junk: bytes, garbage_after: bytes
) -> None:
    """The worst case of a cut 20-byte frame: its bytes and the next frame's pass the checksum.

    ``cut`` bytes of a false ``AA 55`` start sit before frame ``where`` (and ``garbage_after``
    after it); one of them is chosen so that the 20-byte candidate they make with that frame's
    first bytes checks out (by chance one false start in 256 does). Excluded: that frame's own
    bytes continue with ``AA 55`` right after the candidate, which makes the candidate a frame
    followed by a frame.
    """
    where = min(where, len(sent) - 1)
    before = b"".join(encode(f, "fixed") for f in sent[:where])
    rest = encode(sent[where], "fixed") + garbage_after
    rest += b"".join(encode(f, "fixed") for f in sent[where + 1 :])
    false = bytearray(b"\xaa\x55" + junk[: cut - 2])
    candidate = false + rest[: aa55.FIXED_LENGTH - cut]
    false[2] = (candidate[19] - sum(candidate[3:19])) & 0xFF
    stream = before + bytes(false) + rest
    assume(stream[len(before) + 20 : len(before) + 22] != b"\xaa\x55")
    dec = Decoder("fixed")
    got = iter(data_frames_only(dec.feed(stream) + dec.flush()))
    assert all(any(g == f for g in got) for f in sent)  # every frame, in order
    assert dec.rejected[Rejection.OVERLAP] >= 1


def test_a_false_20_byte_start_does_not_swallow_variable_frames() -> None:
    """From the bench's corrupted stream: a frame with a bad type byte (B0) ends in ``AA 55``
    (payload byte 0xAA, end marker), and the 20 bytes from there pass the checksum by chance.

    Taken as an adapter reply they would swallow three intact frames; the first of them is
    followed by a frame start, so the 20-byte candidate gives way.
    """
    stream = bytes.fromhex(
        "aac1fc052a55"  # 0x5FC
        "aab03d06d5d88c6cc8f1aa55"  # bad type byte; payload ends in AA, then the end marker
        "aae2dae13304c85655"  # 0x433E1DA, extended
        "aac03a0455"  # 0x43A
        "aac2aa04f37d55"  # 0x4AA
        "aae2cc353a06a62355"  # 0x63A35CC, extended
    )
    candidate = stream[16:36]
    assert candidate[:2] == b"\xaa\x55" and checksum_ok(candidate, 0)
    dec = Decoder()
    got = dec.feed(stream) + dec.flush()
    assert [(f.arbitration_id, f.is_extended_id) for f in got] == [
        (0x5FC, False),
        (0x433E1DA, True),
        (0x43A, False),
        (0x4AA, False),
        (0x63A35CC, True),
    ]
    assert dec.rejected[Rejection.OVERLAP] == 1 and dec.control == 0


@given(
    st.lists(frames(), min_size=1, max_size=8),
    st.integers(0, 7),
    st.integers(2, 19),
    st.binary(min_size=17, max_size=17),
)
def test_variable_line_false_20_byte_start_passing_its_checksum_swallows_nothing(
    sent: list[Frame], where: int, cut: int, junk: bytes
) -> None:
    """``cut`` bytes of a false ``AA 55`` start before frame ``where`` of a variable-protocol
    stream, one of them chosen so that the 20 bytes from there pass the checksum (when ``cut``
    is 2, the following frames' bytes are left as drawn and the case is skipped unless they
    pass)."""
    where = min(where, len(sent) - 1)
    before = b"".join(encode(f) for f in sent[:where])
    rest = b"".join(encode(f) for f in sent[where:])
    false = bytearray(b"\xaa\x55" + junk[: cut - 2])
    candidate = bytearray(false + rest)[: aa55.FIXED_LENGTH]
    assume(len(candidate) == aa55.FIXED_LENGTH)
    if cut > 2:
        false[2] = (candidate[19] - sum(candidate[3:19])) & 0xFF
        candidate[2] = false[2]
    assume(checksum_ok(candidate, 0))
    dec = Decoder()
    got = iter(data_frames_only(dec.feed(before + bytes(false) + rest) + dec.flush()))
    assert all(any(g == f for g in got) for f in sent)  # every frame, in order


def test_each_rejection_reason_is_counted() -> None:
    good = encode(Frame(0x100, False, False, 1, b"\x01"))
    bad_dlc = b"\xaa\xc9\x00\x01" + bytes(9) + b"\x55"
    bad_id = b"\xaa\xc1\x00\x08\x01\x55"
    bad_end = b"\xaa\xc1\x00\x01\x01\x56"
    bad_checksum = bytearray(encode(Frame(0x100, False, False, 1, b"\x01"), "fixed"))
    bad_checksum[10] ^= 1
    dec = Decoder()
    out = dec.feed(bad_dlc + good + bad_id + good + bad_end + good + bytes(bad_checksum) + good)
    assert len(data_frames_only(out)) == 4
    assert dec.rejected[Rejection.BAD_DLC] == 1
    assert dec.rejected[Rejection.BAD_ID] == 1
    assert dec.rejected[Rejection.BAD_END] == 1
    assert dec.rejected[Rejection.BAD_CHECKSUM] == 1
    assert all(raw[0] == 0xAA for _, raw in dec.rejections)


def test_truncated_candidate_is_released_by_flush() -> None:
    real = encode(Frame(0x010, False, False, 0, b""))
    dec = Decoder()
    assert dec.feed(b"\xaa\xe8\x00" + real) == []  # could still be an extended 8-byte frame
    assert dec.flush() == [Frame(0x010, False, False, 0, b"")]
    assert dec.rejected[Rejection.TRUNCATED] == 1


def test_status_replies_are_recognised_not_mistaken_for_data() -> None:
    status = bytearray(b"\xaa\x55\x04" + bytes(16))
    status.append(sum(status[2:]) & 0xFF)
    dec = Decoder()
    out = dec.feed(bytes(status) + encode(Frame(5, False, False, 0, b"")))
    assert isinstance(out[0], ControlFrame) and out[0].command == 0x04
    assert out[1] == Frame(5, False, False, 0, b"")


# -- cross-check against python-can's seeedstudio (an independent implementation) -----------------


class _FakeSerial:
    def __init__(self, data: bytes = b"") -> None:
        self.rx = io.BytesIO(data)
        self.tx = bytearray()

    def read(self, n: int = 1) -> bytes:
        return self.rx.read(n)

    def write(self, data: bytes) -> int:
        self.tx += data
        return len(data)


def _seeed(data: bytes = b"") -> can.BusABC:
    from can.interfaces.seeedstudio.seeedstudio import SeeedBus

    bus = SeeedBus.__new__(SeeedBus)
    bus.ser = _FakeSerial(data)
    return bus


data_frames = frames().filter(lambda f: not f.is_remote_frame)


@given(st.lists(data_frames, min_size=1, max_size=20))
def test_seeedstudio_writes_what_we_read_and_reads_what_we_write(sent: list[Frame]) -> None:
    # Remote frames are left out: seeedstudio reads DLC data bytes after a remote frame's ID,
    # which the adapter does not send (see docs/engineering/architecture.md).
    writer = _seeed()
    for f in sent:
        writer.send(f.to_message(is_rx=False))
    ours_reader = Decoder()
    assert ours_reader.feed(bytes(writer.ser.tx)) + ours_reader.flush() == sent

    ours = b"".join(encode(f) for f in sent)
    assert bytes(writer.ser.tx) == ours
    reader = _seeed(ours)
    got = []
    for _ in range(len(sent) * 2):
        msg, _ = reader._recv_internal(0)
        if msg is not None:
            got.append(
                Frame(
                    msg.arbitration_id,
                    msg.is_extended_id,
                    msg.is_remote_frame,
                    msg.dlc,
                    bytes(msg.data),
                )
            )
    assert got == sent


@st.composite
def noisy_streams(draw: st.DrawFn) -> bytes:
    """Frames, frames nested in payloads, and junk rich in 0xAA / 0x55 / type bytes."""
    parts = []
    for _ in range(draw(st.integers(1, 12))):
        kind = draw(st.integers(0, 2))
        if kind == 0:
            parts.append(encode(draw(frames())))
        elif kind == 1:
            junk = st.sampled_from([0xAA, 0x55, 0xC8, 0xE8, 0x00, 0x10, 0x07])
            parts.append(bytes(draw(st.lists(junk, max_size=8))))
        else:
            inner = encode(Frame(draw(st.integers(0, 0x7FF)), False, False, 0, b""))
            parts.append(b"\xaa\xe8" + bytes(draw(st.binary(min_size=1, max_size=2))) + inner)
    return b"".join(parts)


@st.composite
def noisy_fixed_streams(draw: st.DrawFn) -> bytes:
    """20-byte frames, cut ones, junk rich in 0xAA / 0x55, and false ``AA 55`` starts whose 20
    bytes with the next frame's pass the checksum (the overlaps the decoder must judge)."""
    parts = []
    for _ in range(draw(st.integers(1, 8))):
        kind = draw(st.integers(0, 3))
        frame = encode(draw(frames()), "fixed")
        if kind == 0:
            parts.append(frame)
        elif kind == 1:
            parts.append(frame[: draw(st.integers(1, aa55.FIXED_LENGTH - 1))])
        elif kind == 2:
            junk = st.sampled_from([0xAA, 0x55, 0x01, 0x00])
            parts.append(bytes(draw(st.lists(junk, max_size=6))))
        else:
            cut = draw(st.integers(3, aa55.FIXED_LENGTH - 1))
            false = bytearray(b"\xaa\x55" + draw(st.binary(min_size=cut - 2, max_size=cut - 2)))
            candidate = false + frame[: aa55.FIXED_LENGTH - cut]
            false[2] = (candidate[19] - sum(candidate[3:19])) & 0xFF
            parts.append(bytes(false) + frame)
    return b"".join(parts)


def _decoded_in_chunks(stream: bytes, protocol: str, cuts: list[int]) -> tuple[list, Decoder]:
    dec = Decoder(protocol)  # type: ignore[arg-type]
    got: list = []
    prev = 0
    for cut in [*cuts, len(stream)]:
        got += dec.feed(stream[prev:cut])
        prev = cut
    return got + dec.flush(), dec


@settings(max_examples=300)
@given(
    st.one_of(
        noisy_streams().map(lambda s: (s, "variable")),
        noisy_fixed_streams().map(lambda s: (s, "fixed")),
    ),
    st.data(),
)
def test_output_does_not_depend_on_chunking_even_for_noisy_streams(
    case: tuple[bytes, str], data: st.DataObject
) -> None:
    stream, protocol = case
    expected, whole = _decoded_in_chunks(stream, protocol, [])
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=len(stream))))
    got, dec = _decoded_in_chunks(stream, protocol, cuts)
    assert got == expected
    assert dec.rejected == whole.rejected
    bytewise, _ = _decoded_in_chunks(stream, protocol, list(range(len(stream))))
    assert bytewise == expected


# -- can.Message output (what the aa55 bus asks for) ----------------------------------------------


def _message_fields(item: object) -> tuple:
    """Every slot of a ``can.Message`` (data with its type), or the item itself otherwise."""
    if not isinstance(item, can.Message):
        return ("other", item)
    return (
        type(item),
        item.timestamp,
        item.arbitration_id,
        item.is_extended_id,
        item.is_remote_frame,
        item.is_error_frame,
        item.channel,
        item.dlc,
        type(item.data),
        bytes(item.data),
        item.is_fd,
        item.is_rx,
        item.bitrate_switch,
        item.error_state_indicator,
    )


@settings(max_examples=200)
@given(st.one_of(servo_like_stream(), noisy_streams()), st.data())
def test_message_mode_emits_what_to_message_makes_of_each_frame(
    stream: bytes, data: st.DataObject
) -> None:
    """``messages=True`` is the Frame output converted, item for item, for any chunking."""
    frames_dec = Decoder()
    messages_dec = Decoder(messages=True, channel="can7")
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=20)))
    expected: list = []
    got: list = []
    prev = 0
    for k, cut in enumerate([*cuts, len(stream)]):
        expected += frames_dec.feed(stream[prev:cut], float(k))
        got += messages_dec.feed(stream[prev:cut], float(k))
        prev = cut
    expected += frames_dec.flush(99.0)
    got += messages_dec.flush(99.0)
    converted = [f.to_message("can7") if type(f) is Frame else f for f in expected]
    assert [_message_fields(m) for m in got] == [_message_fields(m) for m in converted]
    assert messages_dec.frames == frames_dec.frames
    assert messages_dec.rejected == frames_dec.rejected


@given(st.lists(frames(), min_size=1, max_size=20))
def test_message_mode_covers_fixed_frames_remote_frames_and_empty_payloads(
    sent: list[Frame],
) -> None:
    for protocol in ("variable", "fixed"):
        stream = b"".join(encode(f, protocol) for f in sent)  # type: ignore[arg-type]
        dec = Decoder(protocol, messages=True)  # type: ignore[arg-type]
        got = dec.feed(stream) + dec.flush()
        assert all(type(m) is can.Message for m in got)
        keys = [(m.arbitration_id, m.is_extended_id, m.is_remote_frame, m.dlc) for m in got]
        assert keys == [
            (f.arbitration_id, f.is_extended_id, f.is_remote_frame, f.dlc) for f in sent
        ]
        assert [bytes(m.data) for m in got] == [f.data for f in sent]


def test_feed_accepts_any_bytes_like_and_keeps_no_reference_to_it() -> None:
    """A fresh ``bytes`` chunk is scanned in place; other types are copied. Either way the tail
    held back is the decoder's own copy, so a caller reusing its buffer changes nothing."""
    raw = encode(Frame(0x141, False, False, 8, bytes(range(8))))
    for kind in (bytes, bytearray, memoryview):
        dec = Decoder()
        head = bytearray(raw[:7])
        assert dec.feed(kind(head)) == []  # type: ignore[arg-type]
        assert dec.pending == 7
        head[:] = b"\x00" * 7  # the caller reuses its buffer
        assert dec.feed(raw[7:]) == [Frame(0x141, False, False, 8, bytes(range(8)))]
        assert dec.pending == 0
