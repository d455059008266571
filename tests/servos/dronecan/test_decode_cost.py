"""What a received DroneCAN transfer costs: the profile unpacks into kept payload objects.

The ``dronecan`` package builds a new payload object for every transfer (every field
constructed, float16 ones converted), most of its 0.1-0.2 ms per Status. A servo's reassembler
keeps one object per message type made only of primitive fields and unpacks into it with the
package's own code. These tests check that it does (objects built once, not per transfer, so
no timing threshold), that it decodes exactly what the package's ``Transfer.from_frames``
decodes, hostile input included, and that the shortcuts (the C CRC, the inlined ``is_reply``)
agree with what they replace.
"""

from __future__ import annotations

import binascii
import math

import can
import dronecan
import pytest
from dronecan.dsdl.common import crc16_from_bytes
from dronecan.transport import CompoundValue, Frame, Transfer
from hypothesis import given, settings
from hypothesis import strategies as st

from mavservo.servos.dronecan import wire
from mavservo.servos.dronecan.profile import DroneCanServo

actuator = dronecan.uavcan.equipment.actuator


def frames_of(payload, source: int, tid: int) -> list[can.Message]:  # type: ignore[no-untyped-def]
    transfer = Transfer(transfer_id=tid, source_node_id=source, payload=payload)
    return [
        can.Message(arbitration_id=f.message_id, is_extended_id=True, data=bytes(f.bytes))
        for f in transfer.to_frames()
    ]


def fields(payload) -> dict[str, object]:  # type: ignore[no-untyped-def]
    """A payload's field values, NaN as a string (NaN != NaN)."""
    out: dict[str, object] = {}
    for name in dronecan.get_fields(payload):
        if name.startswith("_void"):
            continue
        value = getattr(payload, name)
        out[name] = "nan" if isinstance(value, float) and math.isnan(value) else value
    return out


def test_a_servo_builds_each_payload_object_once_not_per_transfer(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    built = []
    original = CompoundValue.__init__

    def counting(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        built.append(args[0].full_name if args else "?")
        original(self, *args, **kwargs)

    status = [
        frames_of(actuator.Status(actuator_id=1, position=0.01 * i, speed=0.0), 11, i % 32)
        for i in range(20)
    ]
    beat = [
        frames_of(dronecan.uavcan.protocol.NodeStatus(uptime_sec=i, health=0, mode=0), 11, i)
        for i in range(5)
    ]
    profile = DroneCanServo(11, actuator_id=1)
    monkeypatch.setattr(CompoundValue, "__init__", counting)
    for transfer in [*status, *beat]:
        for msg in transfer:
            state = profile.decode(msg, 1.0)
    monkeypatch.undo()
    assert state is not None
    assert state.position_deg == pytest.approx(math.degrees(0.19), abs=0.01)
    assert profile.node_health == 0
    # before: one Status and one NodeStatus object per transfer (25)
    assert sorted(built) == ["uavcan.equipment.actuator.Status", "uavcan.protocol.NodeStatus"]


payloads = st.one_of(
    st.builds(
        lambda a, p, f, s, r: actuator.Status(
            actuator_id=a, position=p, force=f, speed=s, power_rating_pct=r
        ),
        st.integers(0, 255),
        st.floats(-70000, 70000) | st.just(math.nan),
        st.floats(-100, 100),
        st.floats(-100, 100) | st.just(math.inf),
        st.integers(0, 127),
    ),
    st.builds(
        lambda u, h, m, v: dronecan.uavcan.protocol.NodeStatus(
            uptime_sec=u, health=h, mode=m, vendor_specific_status_code=v
        ),
        st.integers(0, 2**32 - 1),
        st.integers(0, 3),
        st.integers(0, 7),
        st.integers(0, 0xFFFF),
    ),
    st.builds(
        lambda a, p, c, v, t: dronecan.com.volz.servo.ActuatorStatus(
            actuator_id=a, actual_position=p, current=c, voltage=v, motor_temperature=t
        ),
        st.integers(0, 255),
        st.floats(-3, 3),
        st.integers(0, 255),
        st.integers(0, 255),
        st.integers(0, 255),
    ),
)


@settings(max_examples=150, deadline=None)
@given(
    st.lists(st.tuples(payloads, st.integers(0, 31), st.booleans()), min_size=1, max_size=8),
)
def test_kept_objects_decode_what_the_package_decodes(
    transfers: list[tuple[object, int, bool]],
) -> None:
    """One reassembler keeps its objects across transfers of every type, valid and corrupted
    in turn; each valid transfer decodes to what a fresh ``Transfer.from_frames`` gives."""
    kept = wire.Reassembler(reuse_payloads=True)
    fresh = wire.Reassembler()
    for i, (payload, tid, corrupt) in enumerate(transfers):
        msgs = frames_of(payload, 7, tid)
        if corrupt:
            data = bytearray(msgs[0].data)
            data[0] ^= 0x5A
            msgs[0] = can.Message(arbitration_id=msgs[0].arbitration_id, data=bytes(data))
        got = want = None
        for msg in msgs:
            got = kept.push(msg, float(i))
            want = fresh.push(msg, float(i))
        if want is None:
            assert got is None
            continue
        assert got is not None
        reference = Transfer()
        reference.from_frames([Frame(m.arbitration_id, bytes(m.data)) for m in msgs])
        assert fields(got.payload) == fields(want.payload) == fields(reference.payload)
        assert (got.dtid, got.source, got.transfer_id, got.full_name, got.priority) == (
            want.dtid,
            want.source,
            want.transfer_id,
            want.full_name,
            want.priority,
        )
        assert (got.service, got.request, got.destination) == (False, False, None)
    assert kept.errors == fresh.errors


def test_a_truncated_transfer_is_counted_and_the_kept_object_still_decodes_the_next() -> None:
    kept = wire.Reassembler(reuse_payloads=True)
    ns_id = wire.message_id(wire.DTID_NODE_STATUS, 5, 24)
    assert kept.push(can.Message(arbitration_id=ns_id, data=bytes([1, 2, 0xC0])), 0.0) is None
    assert kept.errors["malformed"] == 1
    good = dronecan.uavcan.protocol.NodeStatus(uptime_sec=77, health=2, mode=1)
    (msg,) = frames_of(good, 5, 1)
    received = kept.push(msg, 0.1)
    assert received is not None
    assert (received.payload.uptime_sec, received.payload.health, received.payload.mode) == (
        77,
        2,
        1,
    )


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=64), st.integers(0, 0xFFFF))
def test_the_c_crc_is_the_packages_crc(data: bytes, initial: int) -> None:
    assert binascii.crc_hqx(data, initial) == crc16_from_bytes(data, initial=initial)


@settings(max_examples=500, deadline=None)
@given(
    st.integers(0, 0x1FFFFFFF)
    | st.sampled_from([wire.DTID_ACTUATOR_STATUS, wire.DTID_NODE_STATUS, 999]).map(
        lambda d: wire.message_id(d, 9, 16)
    ),
    st.booleans(),
    st.booleans(),
)
def test_is_reply_is_the_wire_helpers_definition(arb: int, extended: bool, remote: bool) -> None:
    msg = can.Message(
        arbitration_id=arb if extended else arb & 0x7FF,
        is_extended_id=extended,
        is_remote_frame=remote,
        data=b"" if remote else b"\xc0",
    )
    profile = DroneCanServo(9, actuator_id=1)
    feedback = {
        wire.DTID_NODE_STATUS,
        wire.DTID_ACTUATOR_STATUS,
        wire.DTID_VOLZ_STATUS,
        wire.DTID_HIMARK_INFO,
    }
    expected = (
        wire.is_message_frame(msg)
        and wire.source_node(msg) == 9
        and wire.message_dtid(msg) in feedback
    )
    assert profile.is_reply(msg) == expected
