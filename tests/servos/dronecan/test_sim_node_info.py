"""The simulated DroneCAN node answers ``uavcan.protocol.GetNodeInfo`` as the DSDL says
(``uavcan/protocol/1.GetNodeInfo.uavcan``: a request with an empty section, a response with
NodeStatus, software and hardware version, a 16-byte unique id and a name), built and read here
by the ``dronecan`` package itself, not by the project's wire helpers or the doctor's reader: a
framing mistake in those is not repeated here. Only a request addressed to the node is answered;
a request to another node, another service, or a response never is."""

from __future__ import annotations

import can
import dronecan
import pytest
from dronecan.transport import Frame, Transfer

from mavservo.config.simulation import Faults
from mavservo.servos.dronecan.profile import DroneCanOptions
from mavservo.sim.servo import SimServo

GET_NODE_INFO = dronecan.uavcan.protocol.GetNodeInfo


def request_frames(
    destination: int, source: int = 127, transfer_id: int = 5, *, request: bool = True
) -> list[can.Message]:
    payload = GET_NODE_INFO.Request() if request else GET_NODE_INFO.Response(name="x")
    transfer = Transfer(
        transfer_id=transfer_id,
        source_node_id=source,
        dest_node_id=destination,
        payload=payload,
        transfer_priority=30,
        service_not_message=True,
        request_not_response=request,
    )
    return [
        can.Message(arbitration_id=f.message_id, is_extended_id=True, data=bytes(f.bytes))
        for f in transfer.to_frames()
    ]


def answer(sim: SimServo, frames: list[can.Message], now: float = 0.5) -> Transfer | None:
    """The node's reply frames, reassembled and decoded by the package (None: no reply)."""
    replies = [msg for frame in frames for _, msg in sim.receive(frame, now)]
    if not replies:
        return None
    transfer = Transfer()
    transfer.from_frames([Frame(m.arbitration_id, bytes(m.data)) for m in replies])
    return transfer


def test_a_request_to_the_node_is_answered_to_the_asker_with_its_transfer_id() -> None:
    sim = SimServo("dronecan", 21, reply_latency_s=0.0)
    got = answer(sim, request_frames(21, source=127, transfer_id=9))
    assert got is not None
    assert got.service_not_message and not got.request_not_response
    assert (got.source_node_id, got.dest_node_id, got.transfer_id) == (21, 127, 9)
    info = got.payload
    assert info.name.decode() == "org.mavservo.sim.actuator"
    assert (info.software_version.major, info.software_version.minor) == (1, 0)
    assert (info.hardware_version.major, info.hardware_version.minor) == (1, 0)
    unique = bytes(int(b) for b in info.hardware_version.unique_id)
    assert unique == b"mavservo-sim" + (21).to_bytes(4, "big")
    assert int(info.status.health) == 0  # OK


def test_ardupilot_firmware_names_itself_as_ap_periph_does_and_health_follows_faults() -> None:
    sim = SimServo(
        "dronecan",
        22,
        options=DroneCanOptions(firmware="ardupilot", actuator_id=1, command="pwm"),
        faults=Faults(over_temperature=True),
        reply_latency_s=0.0,
    )
    got = answer(sim, request_frames(22))
    assert got is not None
    assert got.payload.name.decode() == "org.ardupilot.ap_periph"
    assert int(got.payload.status.health) == 1  # WARNING while a motor reports a fault


@pytest.mark.parametrize(
    "frames",
    [
        pytest.param(request_frames(23), id="another node's request"),
        pytest.param(request_frames(21, request=False), id="a response, not a request"),
        pytest.param(request_frames(21, source=21), id="its own id as the asker"),
    ],
)
def test_what_is_not_a_request_to_the_node_is_not_answered(frames: list[can.Message]) -> None:
    sim = SimServo("dronecan", 21, reply_latency_s=0.0)
    assert answer(sim, frames) is None


def test_a_node_still_allocating_its_id_answers_nothing() -> None:
    """A node that has no id yet (``unique_id`` configured: dynamic allocation) is not
    addressable: a request to the id it will get is not for it yet."""
    sim = SimServo(
        "dronecan",
        24,
        options=DroneCanOptions(actuator_id=1, unique_id="00112233445566778899aabbccddeeff"),
        reply_latency_s=0.0,
    )
    assert answer(sim, request_frames(24)) is None
