"""Exact classic-CAN frame lengths and the bus load R of paper eq. (4).

Pure arithmetic: no I/O, no clock. The scheduler uses it twice: at construction, to refuse a
schedule whose *worst-case* load exceeds the configured limit (so an impossible configuration
fails loudly at start-up instead of silently starving telemetry in flight), and while running,
to turn the frames it actually sent and received into a measured R.

Frame layout (CAN 2.0, classic):

* standard data frame: SOF 1, identifier 11, RTR 1, IDE 1, r0 1, DLC 4, data 8*DLC, CRC 15
  -- these are the bits subject to bit stuffing -- then CRC delimiter 1, ACK slot 1,
  ACK delimiter 1, EOF 7 and the 3-bit interframe space (IFS) that must follow before the
  next frame can start: 47 + 8*DLC bits.
* extended data frame: SOF 1, base identifier 11, SRR 1, IDE 1, identifier extension 18, RTR 1,
  r1 1, r0 1, DLC 4, data, CRC 15, then the same 13-bit tail: 67 + 8*DLC bits.
* remote frames carry no data field whatever their DLC says.

Worst-case stuffing: after five equal bits the transmitter inserts a complementary bit, and a
stuff bit can itself start a new run, so the worst case over the n stuffable bits (SOF..CRC)
is floor((n - 1) / 4) extra bits.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Literal, Protocol

from mavservo.servos import ServoProfile, node_reports_of, unsolicited_hz_of

Stuffing = Literal["worst", "none"]

# Bits after the CRC sequence that are never stuffed: CRC delimiter, ACK slot, ACK delimiter,
# end of frame (7) and the interframe space (3).
_UNSTUFFED_TAIL_BITS = 1 + 1 + 1 + 7 + 3
# SOF + ID 11 + RTR + IDE + r0 + DLC 4 + CRC 15
_STANDARD_STUFFABLE_HEADER_AND_CRC = 1 + 11 + 1 + 1 + 1 + 4 + 15
# SOF + base ID 11 + SRR + IDE + ID extension 18 + RTR + r1 + r0 + DLC 4 + CRC 15
_EXTENDED_STUFFABLE_HEADER_AND_CRC = 1 + 11 + 1 + 1 + 18 + 1 + 1 + 1 + 4 + 15


def _check_dlc(dlc: int) -> None:
    if not isinstance(dlc, int) or isinstance(dlc, bool) or not 0 <= dlc <= 8:
        raise ValueError(f"classic CAN DLC must be an int in 0..8, got {dlc!r}")


def stuffable_bits(extended: bool, dlc: int, remote: bool = False) -> int:
    """Number of bits from SOF to the end of the CRC sequence, the span bit stuffing covers."""
    _check_dlc(dlc)
    header_and_crc = (
        _EXTENDED_STUFFABLE_HEADER_AND_CRC if extended else _STANDARD_STUFFABLE_HEADER_AND_CRC
    )
    data_bits = 0 if remote else 8 * dlc
    return header_and_crc + data_bits


def worst_case_stuff_bits(extended: bool, dlc: int, remote: bool = False) -> int:
    """Maximum number of stuff bits a frame of this shape can carry."""
    return (stuffable_bits(extended, dlc, remote) - 1) // 4


def frame_bits(extended: bool, dlc: int, remote: bool = False, stuffing: Stuffing = "worst") -> int:
    """Bits a frame occupies on the wire, interframe space included.

    ``stuffing="worst"`` (the default) adds the maximum possible number of stuff bits, which is
    what a budget must assume; ``stuffing="none"`` gives the minimum length.
    """
    if stuffing not in ("worst", "none"):
        raise ValueError(f"stuffing must be 'worst' or 'none', got {stuffing!r}")
    bits = stuffable_bits(extended, dlc, remote) + _UNSTUFFED_TAIL_BITS
    if stuffing == "worst":
        bits += worst_case_stuff_bits(extended, dlc, remote)
    return bits


def frame_time(extended: bool, dlc: int, bitrate: int, remote: bool = False) -> float:
    """Worst-case time in seconds a frame holds the bus at ``bitrate`` bit/s."""
    if bitrate <= 0:
        raise ValueError(f"bitrate must be positive, got {bitrate!r}")
    return frame_bits(extended, dlc, remote) / bitrate


class _FrameLike(Protocol):
    is_extended_id: bool
    is_remote_frame: bool
    dlc: int


def message_bits(msg: _FrameLike, stuffing: Stuffing = "worst") -> int:
    """``frame_bits`` for a ``can.Message`` (or anything with the same three attributes).

    CAN FD frames are out of scope: the servo buses this project drives are classic CAN.
    """
    return frame_bits(bool(msg.is_extended_id), int(msg.dlc), bool(msg.is_remote_frame), stuffing)


@dataclass(frozen=True)
class FrameFlow:
    """A periodic stream of identical-shape frames: ``rate_hz`` frames per second."""

    rate_hz: float
    extended: bool
    dlc: int
    remote: bool = False

    @property
    def bits_per_second(self) -> float:
        return self.rate_hz * frame_bits(self.extended, self.dlc, self.remote)


def load_ratio(flows: Iterable[FrameFlow], bitrate: int) -> float:
    """Paper eq. (4) as a fraction of the bus capacity: sum(N_i * S_i) / (T * bitrate).

    Dividing by the bitrate makes R dimensionless (0.4 means 40 % of the bus), which is what a
    limit such as ``max_load=0.5`` is expressed in.
    """
    if bitrate <= 0:
        raise ValueError(f"bitrate must be positive, got {bitrate!r}")
    return sum(flow.bits_per_second for flow in flows) / bitrate


@dataclass(frozen=True)
class ServoTraffic:
    """The worst-case traffic one servo generates, in the shapes ``worst_case_load`` needs.

    ``command_hz`` must already be the worst case for the servo's mode (an ``immediate`` servo
    can send up to ``1 / immediate_min_spacing_s`` commands per second, not just ``1 / T_c``).
    Replies are assumed to be full 8-byte frames of the same identifier format as the request,
    which is how every profile in this project answers. ``push_hz``: status frames a push-style
    servo (CubeMars servo mode) sends on its own, unpolled, in the command's identifier format.
    """

    command_hz: float
    command_extended: bool
    command_dlc: int
    replies_per_command: int
    request_hz: float
    request_shapes: tuple[tuple[bool, int], ...]  # (extended, dlc) per request frame
    replies_per_request: int
    reply_dlc: int = 8
    push_hz: float = 0.0
    lifecycle_hz: float = 0.0
    lifecycle_shapes: tuple[tuple[bool, int], ...] = ()
    replies_per_lifecycle: int = 0
    heartbeat_hz: float = 0.0
    """A node's own heartbeat (DroneCAN NodeStatus), 8-byte frames besides its status."""

    def flows(self) -> list[FrameFlow]:
        flows = [FrameFlow(self.command_hz, self.command_extended, self.command_dlc)]
        if self.replies_per_command:
            flows.append(
                FrameFlow(
                    self.command_hz * self.replies_per_command,
                    self.command_extended,
                    self.reply_dlc,
                )
            )
        for extended, dlc in self.request_shapes:
            flows.append(FrameFlow(self.request_hz, extended, dlc))
            if self.replies_per_request:
                flows.append(
                    FrameFlow(self.request_hz * self.replies_per_request, extended, self.reply_dlc)
                )
        if self.push_hz:
            flows.append(FrameFlow(self.push_hz, self.command_extended, self.reply_dlc))
        if self.heartbeat_hz:
            flows.append(FrameFlow(self.heartbeat_hz, self.command_extended, self.reply_dlc))
        for extended, dlc in self.lifecycle_shapes:
            flows.append(FrameFlow(self.lifecycle_hz, extended, dlc))
            if self.replies_per_lifecycle:
                flows.append(
                    FrameFlow(
                        self.lifecycle_hz * self.replies_per_lifecycle, extended, self.reply_dlc
                    )
                )
        return flows


def servo_traffic(
    profile: ServoProfile,
    *,
    command_hz: float,
    poll_hz: float,
    status_hz: float,
    max_speed_dps: float | None,
    startup_hz: float = 0.0,
) -> ServoTraffic:
    """One servo's worst-case traffic, from its profile's own frames: what the scheduler's
    start-up budget and ``mavservo check`` both count, so that they agree.

    ``profile`` gives the frames (``position_command``, ``telemetry_requests``, a query) and
    ``replies_per_*``. The command is shaped as the scheduler sends it, with the speed limit
    (a CubeMars command is 4 bytes without one, 8 with). A polled servo answers ``poll_hz``
    requests; a push-style one (no requests) sends ``status_hz`` status frames on its own. Any
    servo may also send ``profile.unsolicited_hz()`` frames unasked (ODrive's heartbeat).
    ``startup_hz``: how often the start-up frames may go out (the scheduler's retry limit).
    """
    command = profile.position_command(0.0, max_speed_dps)
    requests = profile.telemetry_requests()
    startup = profile.startup_frames()
    reports = node_reports_of(profile)
    heartbeat = None if reports is None else reports.heartbeat_period_s
    frames_per_push = 1 if reports is None else reports.frames_per_push
    return ServoTraffic(
        command_hz=command_hz,
        command_extended=bool(command.is_extended_id),
        command_dlc=int(command.dlc),
        replies_per_command=profile.replies_per_command,
        request_hz=poll_hz if requests else 0.0,
        request_shapes=tuple((bool(r.is_extended_id), int(r.dlc)) for r in requests),
        replies_per_request=profile.replies_per_request,
        # a multi-frame status transfer (DroneCAN Status: two frames) counts every frame
        push_hz=(0.0 if requests else status_hz * frames_per_push) + unsolicited_hz_of(profile),
        lifecycle_hz=startup_hz,
        lifecycle_shapes=tuple((bool(f.is_extended_id), int(f.dlc)) for f in startup),
        replies_per_lifecycle=profile.replies_per_lifecycle,
        heartbeat_hz=1 / heartbeat if heartbeat else 0.0,
    )


def worst_case_load(servos: Iterable[ServoTraffic], bitrate: int) -> float:
    """Worst-case R of a whole schedule: every servo's commands, requests and their replies."""
    return load_ratio((flow for servo in servos for flow in servo.flows()), bitrate)
