"""ArduPilot SITL's multicast CAN datagrams (libraries/AP_HAL_SITL/CAN_Multicast.cpp) as the
``sitl-mcast`` interface writes and reads them, checked against pydronecan's CRC and the
format's own layout, and two members exchanging frames on a group of this host."""

from __future__ import annotations

import binascii
import struct

import can
import pytest
from dronecan.dsdl.common import crc16_from_bytes
from hypothesis import given
from hypothesis import strategies as st

from mavservo.transport.sitl_mcast import MAGIC, SitlMulticastBus, decode, encode

frames = st.builds(
    lambda ext, ident, data, rtr: can.Message(
        arbitration_id=ident & (0x1FFFFFFF if ext else 0x7FF),
        is_extended_id=ext,
        data=b"" if rtr else data,
        is_remote_frame=rtr,
    ),
    st.booleans(),
    st.integers(0, 0x1FFFFFFF),
    st.binary(max_size=8),
    st.booleans(),
)


def test_crc_is_ccitt_false_as_pydronecan_and_arducopter_compute_it() -> None:
    assert binascii.crc_hqx(b"123456789", 0xFFFF) == 0x29B1  # CRC-16/CCITT-FALSE check value
    body = struct.pack("<HI", 0, 0x141) + b"\xa4\x01"
    assert binascii.crc_hqx(body, 0xFFFF) == crc16_from_bytes(body)


def test_a_datagram_is_laid_out_as_can_multicast_cpp_sends_it() -> None:
    datagram = encode(can.Message(arbitration_id=0x1015501, is_extended_id=True, data=b"\x01\x02"))
    magic, crc, flags, raw_id = struct.unpack_from("<HHHI", datagram)
    assert (magic, flags, raw_id) == (MAGIC, 0, 0x1015501 | 1 << 31)
    assert datagram[10:] == b"\x01\x02" and crc == crc16_from_bytes(datagram[4:])


@given(frames)
def test_every_frame_survives_encode_and_decode(msg: can.Message) -> None:
    back = decode(encode(msg))
    assert back is not None
    assert (back.arbitration_id, back.is_extended_id, back.is_remote_frame, bytes(back.data)) == (
        msg.arbitration_id,
        msg.is_extended_id,
        msg.is_remote_frame,
        bytes(msg.data),
    )


@given(st.binary(max_size=80))
def test_garbage_is_refused_never_raised(datagram: bytes) -> None:
    msg = decode(datagram)
    if msg is not None:  # only with the magic and a matching CRC
        assert datagram[:2] == b"\x34\x29" and encode(msg) == datagram


def test_bad_crc_magic_and_error_frames_are_dropped() -> None:
    good = encode(can.Message(arbitration_id=0x141, is_extended_id=False, data=b"\x01"))
    assert decode(good[:2] + b"\x00\x00" + good[4:]) is None
    assert decode(b"\x00\x00" + good[2:]) is None
    body = struct.pack("<HI", 0, 0x141 | 1 << 29)
    assert decode(struct.pack("<HH", MAGIC, binascii.crc_hqx(body, 0xFFFF)) + body) is None


def test_two_members_of_a_group_hear_each_other_not_themselves() -> None:
    try:
        a = SitlMulticastBus(channel=9)
        b = SitlMulticastBus(channel=9)
    except can.CanInitializationError as exc:  # no multicast on this machine
        pytest.skip(str(exc))
    try:
        a.send(can.Message(arbitration_id=0x141, is_extended_id=False, data=b"\xa4\x01"))
        got = b.recv(2.0)
        assert got is not None and got.arbitration_id == 0x141 and bytes(got.data) == b"\xa4\x01"
        assert a.recv(0.1) is None  # its own frame is not delivered back
    finally:
        a.shutdown()
        b.shutdown()


@pytest.mark.parametrize("channel", [-1, 256, "can0", True])
def test_channel_is_the_interface_index(channel: object) -> None:
    with pytest.raises(can.CanInitializationError, match="0 = CAN_P1"):
        SitlMulticastBus(channel=channel)
