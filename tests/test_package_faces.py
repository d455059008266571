"""Package faces (issue 31 item 4): each layer's ``__init__`` names, in ``__all__``, what the other
layers import from it; every name of a face resolves to its module's object; and a lazy face
imports nothing until a name is asked for (importing ``mavservo.mavlink.quaternion`` must not
drag pymavlink's dialect in through the package)."""

from __future__ import annotations

import ast
import importlib
import subprocess
import sys
from pathlib import Path

import pytest

import mavservo
from tests.support.paths import REPO

PACKAGE_DIR = Path(mavservo.__file__).parent
LAYERS = ["config", "control", "mavlink", "records", "scheduling", "servos", "sim", "transport"]
LAZY = ["control", "mavlink", "records", "scheduling", "transport"]


def _cross_layer_imports() -> dict[str, set[tuple[str, str]]]:
    """For each layer: (name, importing file) of every ``from mavservo.<layer>.<module> import
    name`` in a module of another layer (modules imported by name left out)."""
    found: dict[str, set[tuple[str, str]]] = {layer: set() for layer in LAYERS}
    for path in PACKAGE_DIR.rglob("*.py"):
        rel = path.relative_to(PACKAGE_DIR)
        own = rel.parts[0] if len(rel.parts) > 1 else None
        for node in ast.walk(ast.parse(path.read_text())):
            if not (isinstance(node, ast.ImportFrom) and node.module and node.level == 0):
                continue
            parts = node.module.split(".")
            if parts[0] != "mavservo" or len(parts) < 3 or parts[1] not in LAYERS:
                continue
            if parts[1] == own:
                continue
            module_dir = PACKAGE_DIR.joinpath(*parts[1:])
            for alias in node.names:
                if (module_dir / f"{alias.name}.py").exists():
                    continue
                found[parts[1]].add((alias.name, str(rel)))
    return found


@pytest.mark.parametrize("layer", LAYERS)
def test_the_face_names_everything_the_other_layers_import(layer: str) -> None:
    face = set(importlib.import_module(f"mavservo.{layer}").__all__)
    missing = sorted(
        f"{name} (used by mavservo/{user})"
        for name, user in _cross_layer_imports()[layer]
        if name not in face
    )
    assert not missing, f"add to mavservo/{layer}/__init__.py's face: {missing}"


@pytest.mark.parametrize("layer", LAYERS)
def test_every_name_of_the_face_resolves_once(layer: str) -> None:
    package = importlib.import_module(f"mavservo.{layer}")
    assert len(set(package.__all__)) == len(package.__all__), "a name listed twice"
    for name in package.__all__:
        getattr(package, name)  # a name whose module lacks it raises here


def test_an_unknown_name_is_an_attribute_error() -> None:
    import mavservo.mavlink as face

    with pytest.raises(AttributeError, match="no_such_name"):
        face.no_such_name  # noqa: B018


@pytest.mark.parametrize("layer", LAZY)
def test_importing_a_lazy_face_imports_none_of_its_modules(layer: str) -> None:
    code = (
        f"import sys, mavservo.{layer}; "
        f"print(sorted(m for m in sys.modules if m.startswith('mavservo.{layer}.')))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=REPO
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"
