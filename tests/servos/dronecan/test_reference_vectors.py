"""DroneCAN's reference vectors (``tests/data/vectors/dronecan.yaml``) against the ``dronecan``
package, the field's implementation of the DSDL and the transport layer: every well-formed frame
of the file is what the package makes of the vector's ``dsdl`` description (so the file was not
written from the profile's ``wire`` module), and a deliberately wrong decoder fails both the
profile's and the simulated node's side of the same file."""

from __future__ import annotations

import math
from typing import Any

import dronecan
import pytest

from mavservo.servos.dronecan import profile as dronecan_profile
from mavservo.servos.dronecan import sim as dronecan_sim
from tests.support.vectors import checked, load, profile_mismatches, simulator_mismatches

DOCUMENT = load("dronecan")
DESCRIBED = [v for v in DOCUMENT["vectors"] if "dsdl" in v]


def _payload(description: dict[str, Any]) -> Any:
    node: Any = dronecan
    for part in description["type"].split("."):
        node = getattr(node, part)
    if "commands" in description:
        command = dronecan.uavcan.equipment.actuator.Command
        return node(commands=[command(**entry) for entry in description["commands"]])
    # YAML's .nan may carry a sign bit; the DSDL's "unknown" is the quiet NaN
    fields = {
        key: math.nan if isinstance(value, float) and math.isnan(value) else value
        for key, value in description["fields"].items()
    }
    return node(**fields)


def _frames_of(vector: dict[str, Any]) -> list[tuple[int, str]]:
    frames = [*vector.get("first_frames", []), vector.get("reply") or vector.get("frame")]
    return [(int(f["id"]), bytes.fromhex(f["data"]).hex()) for f in frames]


@pytest.mark.parametrize("vector", DESCRIBED, ids=[v["name"] for v in DESCRIBED])
def test_the_dronecan_package_makes_the_vector_frames(vector) -> None:
    description = vector["dsdl"]
    transfer = dronecan.transport.Transfer(
        transfer_id=description["transfer_id"],
        source_node_id=description["source_node"],
        payload=_payload(description),
        transfer_priority=description["priority"],
    )
    made = [(f.message_id, bytes(f.bytes).hex()) for f in transfer.to_frames()]
    assert made == _frames_of(vector)


def test_every_command_reply_and_node_status_type_has_a_vector() -> None:
    types = {v["dsdl"]["type"] for v in DESCRIBED}
    assert types == {
        "uavcan.equipment.actuator.ArrayCommand",
        "uavcan.equipment.actuator.Status",
        "uavcan.protocol.NodeStatus",
    }
    befores = [f for v in DOCUMENT["vectors"] for f in v.get("before", [])]
    safety = dronecan.ardupilot.indication.SafetyState.default_dtid
    assert any((int(f["id"]) >> 8) & 0xFFFF == safety for f in befores)


def test_profile_reading_status_radians_as_degrees_fails_the_vectors(monkeypatch) -> None:
    monkeypatch.setattr(dronecan_profile, "_degrees", lambda value: float(value))
    failures = [
        m for _, v in checked("dronecan", "profile") for m in profile_mismatches(DOCUMENT, v)
    ]
    assert any("Status 90 deg at 180 deg/s" in failure for failure in failures), failures


def test_simulator_reading_position_commands_as_degrees_fails_the_vectors(monkeypatch) -> None:
    def wrong(self, command_type: int, value: float) -> float | None:
        return value if math.isfinite(value) else None  # radians taken for degrees

    monkeypatch.setattr(dronecan_sim.DroneCanDevice, "_angle", wrong)
    failures = [
        m for _, v in checked("dronecan", "simulator") for m in simulator_mismatches(DOCUMENT, v)
    ]
    assert any("POSITION 90 deg" in failure for failure in failures), failures


def test_simulator_reporting_position_in_degrees_fails_the_vectors(monkeypatch) -> None:
    monkeypatch.setattr(dronecan_sim.math, "radians", lambda value: value)
    failures = [
        m for _, v in checked("dronecan", "simulator") for m in simulator_mismatches(DOCUMENT, v)
    ]
    assert any("Status 90 deg at 180 deg/s" in failure for failure in failures), failures
