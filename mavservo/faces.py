"""Lazy package faces: a layer's ``__init__`` names what the other layers use (its ``__all__``)
and imports the module that defines a name only when that name is first asked for.

Why lazy: importing one small module of a layer (``mavservo.mavlink.quaternion``) runs the
package's ``__init__`` first; an eager face would drag the whole layer in with it (pymavlink's
large dialect module for the MAVLink side, which the bridge keeps off the command clock at
start-up) and would make every import inside the package a possible cycle. Type checkers read
the ``if TYPE_CHECKING:`` imports beside the table instead; ``tests/test_package_faces.py``
holds the two to each other and to what the other layers really import.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any


def lazy_face(package: str, where: Mapping[str, str]) -> Callable[[str], Any]:
    """The module-level ``__getattr__`` (PEP 562) of ``package``: ``where`` maps each name of
    its face to the submodule, relative to ``package``, that defines it; ``"module:original"``
    when the face gives a name a clearer one among its neighbours (``encode`` of the AA-55
    codec is ``encode_aa55`` in the transport face)."""

    def __getattr__(name: str) -> Any:
        place = where.get(name)
        if place is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        module, _, original = place.partition(":")
        return vars(importlib.import_module(f"{package}.{module}"))[original or name]

    return __getattr__
