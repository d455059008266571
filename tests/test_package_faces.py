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


def _reaching_past_a_face() -> list[str]:
    """Every import, in a module of another layer (the app and the CLI included), that names a
    layer's module instead of its face: ``from mavservo.mavlink.settings import X``,
    ``import mavservo.mavlink.settings``, ``from mavservo.records import runlog``."""
    found = []
    for path in PACKAGE_DIR.rglob("*.py"):
        rel = path.relative_to(PACKAGE_DIR)
        own = rel.parts[0] if len(rel.parts) > 1 else None
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                modules = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                modules = [node.module] + [f"{node.module}.{alias.name}" for alias in node.names]
            else:
                continue
            for module in modules:
                parts = module.split(".")
                if parts[0] != "mavservo" or len(parts) < 3 or parts[1] not in LAYERS:
                    continue
                if parts[1] == own or not _is_module(parts):
                    continue
                found.append(f"mavservo/{rel}:{node.lineno} imports {module}")
    return sorted(set(found))


def _is_module(parts: list[str]) -> bool:
    where = PACKAGE_DIR.joinpath(*parts[1:])
    return where.with_suffix(".py").exists() or where.is_dir()


def test_other_layers_import_names_from_the_face_never_its_modules() -> None:
    """Issue 31 item 4: what a layer keeps in its modules is its own business; another layer
    sees only the face, so a module can be split or renamed without touching its users."""
    assert _reaching_past_a_face() == []


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
def test_no_name_of_the_face_is_also_a_module_of_the_layer(layer: str) -> None:
    """Importing a submodule binds its name on the package, and that binding hides the lazy
    face's name for good: ``from mavservo.transport import interface_options`` gave the function
    until something imported the module ``interface_options``, then the module."""
    package = importlib.import_module(f"mavservo.{layer}")
    clashes = [name for name in package.__all__ if _is_module(["mavservo", layer, name])]
    assert clashes == [], f"rename the module or the name: {clashes}"


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


def test_no_module_name_repeats_across_the_package() -> None:
    """Issue 31 item 4: a module's name says which one it is (two ``pacing.py``, one a token
    bucket for the MAVLink link and one the scheduler's waits, read alike in a traceback and a
    log). The family folders' ``profile.py`` and ``sim.py`` are the one shape every family has,
    and ``__init__``/``__main__`` are Python's."""
    shared = {"__init__.py", "__main__.py", "profile.py", "sim.py"}
    seen: dict[str, list[str]] = {}
    for path in PACKAGE_DIR.rglob("*.py"):
        if path.name not in shared:
            seen.setdefault(path.name, []).append(str(path.relative_to(PACKAGE_DIR)))
    assert {name: where for name, where in seen.items() if len(where) > 1} == {}
