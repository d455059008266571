"""LinkSigning alone: keys on pymavlink encoders and decoders, the clock rule, stream origins."""

from __future__ import annotations

from collections import Counter

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.mavlink.framing import FrameScanner
from mavservo.mavlink.settings import SigningSettings
from mavservo.mavlink.signing import SIGNED_STREAM_REBIND_S, LinkSigning

KEY = bytes(range(32))
WALL = 1.8e9  # a fixed wall clock (2027), so the test never reads the real one
TEN_YEARS_S = 10 * 365 * 86400.0


def signing(accept_unsigned: bool = False) -> tuple[LinkSigning, Counter[str], list[float]]:
    counters: Counter[str] = Counter()
    now = [0.0]
    settings = SigningSettings(KEY, accept_unsigned=accept_unsigned)
    return (
        LinkSigning(settings, counters, clock=lambda: now[0], wall_clock=lambda: WALL),
        counters,
        now,
    )


def scanner(link_signing: LinkSigning, counters: Counter[str]) -> FrameScanner:
    decoder = mavlink2.MAVLink(None)
    decoder.robust_parsing = True
    link_signing.verify_inbound(decoder)
    return FrameScanner(decoder, counters)


def heartbeat(key: bytes | None, wall: float = WALL, link_id: int = 0) -> bytes:
    """A HEARTBEAT from 255/190, signed with ``key`` at wall time ``wall`` (None: unsigned)."""
    encoder = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    if key is not None:
        sender = LinkSigning(SigningSettings(key), Counter(), wall_clock=lambda: wall)
        sender.sign_outbound(encoder, link_id)
    return bytes(mavlink2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(encoder))


def test_a_frame_signed_with_the_key_passes_and_anything_else_is_refused() -> None:
    link_signing, counters, _ = signing()
    frames = scanner(link_signing, counters)
    assert len(frames.datagram(heartbeat(KEY))) == 1
    assert frames.datagram(heartbeat(None)) == []
    assert frames.datagram(heartbeat(bytes(32))) == []
    assert counters["signing_rejected"] == 2


def test_unsigned_frames_pass_when_accepted() -> None:
    link_signing, counters, _ = signing(accept_unsigned=True)
    assert len(scanner(link_signing, counters).datagram(heartbeat(None))) == 1


def test_a_keyed_frame_far_ahead_of_the_clock_is_refused_and_locks_nobody_out() -> None:
    link_signing, counters, _ = signing()
    frames = scanner(link_signing, counters)
    assert frames.datagram(heartbeat(KEY, wall=WALL + TEN_YEARS_S)) == []
    assert counters["signing_future"] == 1
    # the stream's timestamp was not raised: a frame on time from the same stream passes
    assert len(frames.datagram(heartbeat(KEY))) == 1


def test_a_signed_stream_answers_only_where_it_was_first_verified_until_it_falls_silent() -> None:
    link_signing, counters, now = signing()
    frames = scanner(link_signing, counters)
    first = frames.datagram(heartbeat(KEY, wall=WALL))
    assert link_signing.bound_to_origin(first, "gcs") == first
    now[0] = 1.0
    replay = frames.datagram(heartbeat(KEY, wall=WALL + 1.0))
    assert link_signing.bound_to_origin(replay, "stranger") == []
    assert counters["signed_stream_elsewhere"] == 1
    now[0] = 1.0 + SIGNED_STREAM_REBIND_S + 0.1  # the first address was silent: taken over
    moved = frames.datagram(heartbeat(KEY, wall=WALL + 4.0))
    assert link_signing.bound_to_origin(moved, "gcs-restarted") == moved


def test_another_signing_stream_of_the_same_sender_is_bound_on_its_own() -> None:
    link_signing, counters, _ = signing()
    frames = scanner(link_signing, counters)
    a = frames.datagram(heartbeat(KEY, link_id=0))
    b = frames.datagram(heartbeat(KEY, wall=WALL + 0.5, link_id=1))
    assert link_signing.bound_to_origin(a, "radio") == a
    assert link_signing.bound_to_origin(b, "wifi") == b
    assert counters["signed_stream_elsewhere"] == 0
