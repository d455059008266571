"""The built-in sim.yaml is the template it says it is: every key of the schema is in it, set or
in a comment, and every built-in servo family is named (issue 37: it claimed "every key" and
missed the health checks, stream requests, gimbal poses and three families)."""

from __future__ import annotations

import re
import typing
from collections.abc import Iterator

from pydantic import BaseModel

from mavservo.config import Config, default_config_path
from mavservo.servos import BUILT_IN
from tests.support.paths import REPO

TEXT = default_config_path().read_text()


def _models(annotation: typing.Any) -> Iterator[type[BaseModel]]:
    """The models inside an annotation (through Annotated, unions, lists, tuples, dicts)."""
    origin = typing.get_origin(annotation)
    if origin is not None:
        for argument in typing.get_args(annotation):
            yield from _models(argument)
    elif isinstance(annotation, type) and issubclass(annotation, BaseModel):
        yield annotation


def _key_paths(model: type[BaseModel], prefix: tuple[str, ...] = ()) -> Iterator[tuple[str, ...]]:
    for name, field in model.model_fields.items():
        yield (*prefix, name)
        for inner in _models(field.annotation):
            yield from _key_paths(inner, (*prefix, name))


def _section(name: str) -> str:
    """The lines of top-level section ``name`` (up to the next top-level key)."""
    found = re.search(rf"^{name}:.*?(?=^[a-z_]+:|\Z)", TEXT, re.M | re.S)
    assert found, name
    return found.group(0)


def test_every_schema_key_is_in_sim_yaml() -> None:
    paths = sorted(set(_key_paths(Config)))
    assert len(paths) > 100  # the walk found the schema, not an empty model
    missing = [
        ".".join(path)
        for path in paths
        if not re.search(rf"(^|[\s{{,#(\[]){re.escape(path[-1])}:", _section(path[0]), re.M)
    ]
    assert missing == [], f"not in sim.yaml: {missing}"


def test_every_built_in_family_is_named() -> None:
    servos = _section("servos")
    for family in BUILT_IN:
        assert family in servos, family


def test_the_repository_copy_is_the_shipped_one() -> None:
    assert (REPO / "config" / "sim.yaml").read_text() == TEXT
