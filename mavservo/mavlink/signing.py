"""MAVLink 2 signing for the link: the key on every encoder and the decoder, and the rules
pymavlink lacks on what a signed frame may do.

Why its own part: who may speak on the link (a correctly keyed frame, timestamped no further
ahead than this computer's clock allows, from the address its stream was first verified from)
is a security policy with its own state (the signed streams' origins), apart from the sockets,
sessions and threads of :class:`~.link.MavlinkLink`, which hands every received batch to
:meth:`LinkSigning.bound_to_origin` and asks it to set up each encoder and decoder. Tested alone
with pymavlink's own encoders, no socket.
"""

from __future__ import annotations

import logging
import struct
import time
from collections import Counter, OrderedDict
from collections.abc import Callable, Hashable
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.mavlink.settings import SigningSettings

log = logging.getLogger(__name__)

SIGNING_EPOCH = 1420070400  # MAVLink signing timestamps count 10 us units since 2015-01-01
SIGNING_UNITS_PER_S = 100_000
#: How far ahead of this computer's clock a signed frame's timestamp may be. The MAVLink spec
#: bounds only the past (a new stream more than one minute behind the local timestamp is
#: refused); without a bound ahead, one correctly keyed frame from a peer with a wrong clock
#: (10 years ahead) raised pymavlink's local timestamp and locked out every new stream.
SIGNING_FUTURE_S = 60.0
#: A signed stream (link id, system, component) is answered at the address it was first verified
#: from; another address takes it over only once the first was silent this long (a restarted
#: ground station on a new port), so a replay from elsewhere admits nobody.
SIGNED_STREAM_REBIND_S = 2.0
#: Signed streams remembered (least recently heard forgotten first).
MAX_SIGNED_STREAMS = 256


def signing_timestamp(wall_time: float) -> int:
    return int(max(0.0, wall_time - SIGNING_EPOCH) * SIGNING_UNITS_PER_S)


def frame_signing_timestamp(msgbuf: bytes | bytearray) -> int:
    """The 48-bit timestamp of a signed frame (the 6 bytes after the link id)."""
    low, high = struct.unpack_from("<IH", msgbuf, len(msgbuf) - 12)
    return int(low + (high << 32))


def _verify_signatures_against_the_clock(
    decoder: mavlink2.MAVLink,
    counters: Counter[str],
    wall_clock: Callable[[], float] = time.time,
    max_ahead_s: float | None = SIGNING_FUTURE_S,
) -> None:
    """Wrap pymavlink's signature check with three rules it lacks (pymavlink 2.4.50):

    * a stream's timestamp is only recorded once the signature verified: pymavlink records it
      *before*, so one forged far-future frame, made without the key, locked the genuine stream
      out (found by tests/redteam/test_bridge_security.py);
    * the timestamp of a correctly keyed frame may be at most ``max_ahead_s`` (default
      ``SIGNING_FUTURE_S``; None: no bound, for a companion without a synchronised clock) ahead
      of this computer's clock; further ahead it is refused and counted (``signing_future``);
    * the local timestamp a new stream is compared with (spec: refused when more than one
      minute behind it) is this computer's clock, never a received timestamp: pymavlink raised
      it to the largest timestamp accepted, so one frame 10 years ahead refused every new
      stream until restart.
    """
    check = decoder.check_signature
    signing = decoder.signing
    streams = signing.stream_timestamps

    def check_signature(msgbuf: bytearray, src_system: int, src_component: int) -> bool:
        now = signing_timestamp(wall_clock())
        signing.timestamp = now
        stream = (msgbuf[-13], src_system, src_component)
        before = streams.get(stream)
        verified = check(msgbuf, src_system, src_component)
        signing.timestamp = now
        ahead = frame_signing_timestamp(msgbuf) - now
        if verified and max_ahead_s is not None and ahead > max_ahead_s * SIGNING_UNITS_PER_S:
            verified = False
            counters["signing_future"] += 1
            if counters["signing_future"] == 1:
                log.warning(
                    "signed frame from %d/%d refused: its timestamp is %.0f s ahead of this "
                    "computer's clock (at most %.0f s accepted, mavlink.signing."
                    "max_clock_ahead_s; check both clocks; repeats counted in signing_future)",
                    src_system,
                    src_component,
                    ahead / SIGNING_UNITS_PER_S,
                    max_ahead_s,
                )
        if verified:
            return True
        if before is None:
            streams.pop(stream, None)
        else:
            streams[stream] = before
        return False

    decoder.check_signature = check_signature


class LinkSigning:
    """The link's signing: a key from :class:`~.settings.SigningSettings`, counters it adds to
    (``signing_future``, ``signed_stream_elsewhere``) and the origin of each signed stream."""

    def __init__(
        self,
        settings: SigningSettings,
        counters: Counter[str],
        clock: Callable[[], float] = time.monotonic,
        wall_clock: Callable[[], float] = time.time,
    ) -> None:
        self.settings = settings
        self.counters = counters
        self._clock = clock
        self._wall_clock = wall_clock
        self._stream_origins: OrderedDict[tuple[int, int, int], tuple[Hashable, float]] = (
            OrderedDict()
        )

    def verify_inbound(self, decoder: mavlink2.MAVLink) -> None:
        """Give ``decoder`` the key and the rules on inbound frames (unsigned refused unless
        ``accept_unsigned``; see :func:`_verify_signatures_against_the_clock`)."""
        decoder.signing.secret_key = self.settings.key
        decoder.signing.timestamp = signing_timestamp(self._wall_clock())
        if self.settings.accept_unsigned:
            decoder.signing.allow_unsigned_callback = lambda mav, msg_id: True
        _verify_signatures_against_the_clock(
            decoder,
            self.counters,
            wall_clock=self._wall_clock,
            max_ahead_s=self.settings.max_clock_ahead_s,
        )

    def sign_outbound(self, encoder: mavlink2.MAVLink, link_id: int) -> None:
        """Sign everything ``encoder`` sends, as signing stream ``link_id``."""
        encoder.signing.secret_key = self.settings.key
        encoder.signing.sign_outgoing = True
        encoder.signing.link_id = link_id
        encoder.signing.timestamp = signing_timestamp(self._wall_clock())

    def bound_to_origin(self, messages: list[Any], origin: Hashable) -> list[Any]:
        """``messages`` without signed frames of a stream first verified from elsewhere.

        Why: a captured signed frame replayed first from a new address verified (a timestamp
        newer than any the bridge had seen of that stream) and admitted that address for good
        (issue 32, finding 5). A signed stream (link id, system, component) belongs to the
        address it was first verified from; another address takes it over only after
        :data:`SIGNED_STREAM_REBIND_S` of silence from the first (a restarted ground station)."""
        now = self._clock()
        kept = []
        for msg in messages:
            if not getattr(msg, "_signed", False):
                kept.append(msg)
                continue
            stream = (msg.get_msgbuf()[-13], msg.get_srcSystem(), msg.get_srcComponent())
            bound = self._stream_origins.get(stream)
            if bound is not None and bound[0] != origin and now - bound[1] < SIGNED_STREAM_REBIND_S:
                self.counters["signed_stream_elsewhere"] += 1
                continue
            self._stream_origins[stream] = (origin, now)
            self._stream_origins.move_to_end(stream)
            while len(self._stream_origins) > MAX_SIGNED_STREAMS:
                self._stream_origins.popitem(last=False)
            kept.append(msg)
        return kept
