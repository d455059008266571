"""Every built-in family's reference vectors (``tests/data/vectors``), against its profile and
against its simulated device: the same file, so a profile and a simulator that share a mistake
cannot both pass (``tests/support/vectors.py``)."""

from __future__ import annotations

import pytest

from mavservo.servos import PROFILES
from tests.support.vectors import VECTORS, checked, profile_mismatches, simulator_mismatches

FAMILIES = sorted(path.stem for path in VECTORS.glob("*.yaml"))
PROFILE_SIDE = [pair for family in FAMILIES for pair in checked(family, "profile")]
SIMULATOR_SIDE = [pair for family in FAMILIES for pair in checked(family, "simulator")]


def _ids(pairs):
    return [f"{document['profile']}: {vector['name']}" for document, vector in pairs]


@pytest.mark.parametrize(("document", "vector"), PROFILE_SIDE, ids=_ids(PROFILE_SIDE))
def test_profile_matches_the_reference_vector(document, vector) -> None:
    assert profile_mismatches(document, vector) == []


@pytest.mark.parametrize(("document", "vector"), SIMULATOR_SIDE, ids=_ids(SIMULATOR_SIDE))
def test_simulator_matches_the_reference_vector(document, vector) -> None:
    assert simulator_mismatches(document, vector) == []


def test_every_vector_file_names_its_profile_and_cites_a_source() -> None:
    for family in FAMILIES:
        document = checked(family, "profile")[0][0]  # loading checks every citation
        assert document["profile"] == family
    assert FAMILIES, "no vector files"


def test_every_built_in_family_has_vectors_and_a_simulator_of_its_own() -> None:
    """The design of issue 27: each family's simulated device lives in a module of its own
    (``<family>_sim``, which imports nothing of the profile: lint-imports) and is what the
    profile's ``sim_device`` returns; DroneCAN's node encodes and decodes with the dronecan
    package, not the profile's ``wire`` module."""
    from mavservo.sim.servo import SimServo

    for cls in PROFILES.values():
        assert cls.name in FAMILIES, f"{cls.name}: no tests/data/vectors/{cls.name}.yaml"
        device = SimServo(cls.name, cls.min_id + 1)._device  # noqa: SLF001
        module = type(device).__module__
        assert module.endswith("sim") and module != cls.__module__, (cls.name, module)
