"""Reference vectors: frames and the values they mean, transcribed from the vendors' documents
(``tests/data/vectors/<family>.yaml``), checked against a profile and against its simulated
device by the same file, so a wrong profile and a simulator that shares its mistake cannot
agree with each other and still pass.

A vector file::

    profile: lk                       # the profile's YAML name
    sources:                          # every document a vector cites
      lk-can: {document: ..., version: ..., url: ...}
    vectors:
      - name: what it shows
        source: {doc: lk-can, section: "..."}     # a key of sources, and where in it
        options: {model: MF}                      # the servo's options (default: none)
        can_id: 1
        command: {angle_deg: 90, max_speed_dps: 500}   # a position command ...
        frame: {id: 0x141, data: "A4 00 F4 01 28 23 00 00"}
        # ... or a reply: the request that provokes it (none: a push), the reply, its meaning
        request: {id: 0x141, data: "9C 00 00 00 00 00 00 00"}
        reply: {id: 0x141, data: "9C 32 00 08 5A 00 00 20"}
        means: {temperature_c: 50, current_a: 16.5, velocity_dps: 90, position_deg: 180}
        before: [{id: 0x141, data: "80 00 00 00 00 00 00 00"}]   # frames the device hears first
        first_frames: [...]           # a multi-frame reply's frames before ``reply`` (DroneCAN):
                                      # the profile decodes them first, the device sends them too
        motor: {current_a: 1.0}       # simulator only: motor readings ``means`` does not carry
        simulator: false              # a profile-only vector (say why in ``why``)
        absent: true                  # simulator: the request gets no answer at all
        profile: false                # a simulator-only vector

``means`` takes ServoState fields (``faults`` as a list of Fault names) and profile attributes
named ``profile.<attribute>``; for a command, ``means`` is what the device is told to do
(``target_deg``, ``speed_dps``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import can
import yaml

from mavservo.servos import Fault, ServoProfile, get_profile
from tests.support.paths import TEST_DATA

VECTORS = TEST_DATA / "vectors"
TOLERANCE = 1e-6


def load(family: str) -> dict[str, Any]:
    """The vector file of ``family``, its sources checked (every vector cites a known one)."""
    document = yaml.safe_load((VECTORS / f"{family}.yaml").read_text())
    sources = document["sources"]
    for vector in document["vectors"]:
        cited = vector["source"]
        assert cited["doc"] in sources, f"{vector['name']}: unknown source {cited['doc']!r}"
        assert cited.get("section"), f"{vector['name']}: no section cited"
    for key, source in sources.items():
        assert source.get("document") and source.get("version"), f"source {key}: incomplete"
    return document


def _frame(spec: dict[str, Any]) -> can.Message:
    return can.Message(
        arbitration_id=int(spec["id"]),
        is_extended_id=bool(spec.get("extended", False)),
        data=bytes.fromhex(spec["data"]),
    )


def _describe(msg: can.Message) -> str:
    return f"0x{msg.arbitration_id:X} {'ext' if msg.is_extended_id else 'std'} {msg.data.hex(' ')}"


def _same(actual: float, expected: float, tolerance: float) -> bool:
    if math.isnan(expected):
        return math.isnan(actual)
    return math.isfinite(actual) and abs(actual - expected) <= tolerance


def _faults(names: list[str]) -> Fault:
    faults = Fault(0)
    for name in names:
        faults |= Fault[name]
    return faults


def profile_for(document: dict[str, Any], vector: dict[str, Any]) -> ServoProfile:
    cls = get_profile(document["profile"])
    return cls(int(vector.get("can_id", 1)), **vector.get("options", {}))


def profile_mismatches(document: dict[str, Any], vector: dict[str, Any]) -> list[str]:
    """What the profile gets wrong about one vector (empty: nothing)."""
    profile = profile_for(document, vector)
    name = vector["name"]
    if "command" in vector:
        command = vector["command"]
        msg = profile.position_command(command["angle_deg"], command.get("max_speed_dps"))
        expected = _frame(vector["frame"])
        if _describe(msg) != _describe(expected):
            return [f"{name}: sends {_describe(msg)}, the document says {_describe(expected)}"]
        return []
    for spec in vector.get("before_decode", []):
        profile.decode(_frame(spec), 0.0)
    for spec in vector.get("first_frames", []):
        profile.decode(_frame(spec), 1.0)
    reply = _frame(vector["reply"])
    if vector.get("means") is None:  # a frame the profile must refuse
        state = profile.decode(reply, 1.0)
        return [] if state is None else [f"{name}: decoded a frame it must refuse: {state}"]
    state = profile.decode(reply, 1.0)
    if state is None:
        return [f"{name}: the profile does not decode {_describe(reply)}"]
    problems = []
    tolerance = float(vector.get("tolerance", TOLERANCE))
    for key, expected in vector["means"].items():
        if key.startswith("profile."):
            actual = getattr(profile, key.removeprefix("profile."))
            if actual != expected:
                problems.append(f"{name}: {key} = {actual!r}, the document says {expected!r}")
        elif key == "faults":
            if state.faults != _faults(expected):
                problems.append(f"{name}: faults {state.faults!r}, the document says {expected}")
        else:
            actual = getattr(state, key)
            if actual is None or not _same(actual, float(expected), tolerance):
                problems.append(f"{name}: {key} = {actual!r}, the document says {expected!r}")
    return problems


@dataclass
class VectorMotor:
    """A motor with fixed readings for a simulated device (the ``SimMotor`` protocol): what it
    was told is recorded, nothing moves."""

    can_id: int = 1
    position_deg: float = 0.0
    velocity_dps: float = 0.0
    temperature_c: float = 25.0
    enabled: bool = True
    current: float = 0.0
    supply_v: float = 24.0
    faults: Fault = Fault(0)
    commands: list[tuple[float, float | None]] = field(default_factory=list)

    @property
    def voltage_v(self) -> float:
        return self.supply_v

    @property
    def active_faults(self) -> Fault:
        return self.faults

    def measured_current_a(self) -> float:
        return self.current

    def command_position(
        self, angle_deg: float, speed_dps: float | None, now: float, accel_dps2: float | None = None
    ) -> None:
        self.commands.append((angle_deg, speed_dps))

    def enable(self, now: float) -> None:
        self.enabled = True

    def disable(self, now: float) -> None:
        self.enabled = False

    def set_zero(self, now: float) -> None:
        self.position_deg = 0.0


def _motor(vector: dict[str, Any]) -> VectorMotor:
    readings = {**vector.get("means", {}), **vector.get("motor", {})}
    motor = VectorMotor(can_id=int(vector.get("can_id", 1)))
    for key, value in readings.items():
        if key == "position_deg":
            motor.position_deg = float(value)
        elif key == "velocity_dps":
            motor.velocity_dps = float(value)
        elif key == "temperature_c":
            motor.temperature_c = float(value)
        elif key == "current_a":
            motor.current = float(value)
        elif key == "voltage_v":
            motor.supply_v = float(value)
        elif key == "faults":
            motor.faults = _faults(value)
    return motor


def simulator_mismatches(document: dict[str, Any], vector: dict[str, Any]) -> list[str]:
    """What the simulated device gets wrong about one vector (empty: nothing)."""
    cls = get_profile(document["profile"])
    options = cls.Options.model_validate(vector.get("options", {}))
    motor = _motor(vector)
    device = cls.sim_device(motor, int(vector.get("can_id", 1)), options)
    name = vector["name"]
    for spec in vector.get("before", []):
        device.handle(_frame(spec), 0.0)
    motor.commands.clear()
    if "command" in vector:
        frame = _frame(vector["frame"])
        if not device.accepts(frame):
            return [f"{name}: the device does not take {_describe(frame)}"]
        device.handle(frame, 1.0)
        means = vector.get("means", {})
        if not motor.commands:
            return [f"{name}: the device was not told to move by {_describe(frame)}"]
        target, speed = motor.commands[-1]
        problems = []
        tolerance = float(vector.get("tolerance", TOLERANCE))
        if "target_deg" in means and not _same(target, means["target_deg"], tolerance):
            problems.append(f"{name}: target {target}, the document says {means['target_deg']}")
        if "speed_dps" in means and (
            speed is None or not _same(speed, means["speed_dps"], tolerance)
        ):
            problems.append(f"{name}: speed {speed}, the document says {means['speed_dps']}")
        return problems
    expected = _frame(vector["reply"])
    if "request" in vector:
        request = _frame(vector["request"])
        if not device.accepts(request):
            return [f"{name}: the device does not take {_describe(request)}"]
        replies = device.handle(request, 1.0)
    else:
        device.tick(1.0)
        replies = device.status(1.0)
    described = [_describe(reply) for reply in replies]
    if vector.get("absent"):  # the device must not send it
        return [f"{name}: the device answers {described}"] if replies else []
    problems = []
    for frame in [*(_frame(spec) for spec in vector.get("first_frames", [])), expected]:
        if _describe(frame) not in described:
            problems.append(
                f"{name}: the device answers {described}, the document says {_describe(frame)}"
            )
    return problems


def checked(family: str, side: str) -> list[tuple[dict[str, Any], dict[str, Any]]]:
    """``(document, vector)`` pairs of a family that ``side`` (profile / simulator) checks."""
    document = load(family)
    return [(document, v) for v in document["vectors"] if v.get(side, True)]
