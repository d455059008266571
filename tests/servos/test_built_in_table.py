"""The built-in table (issue 31 item 2): a family is one folder plus one line of ``BUILT_IN``,
imported on first use, as python-can keeps its interfaces."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from mavservo.servos import PROFILES, ServoProfile, get_profile, registry
from mavservo.servos.sim_registry import simulated_device
from mavservo.sim.servo import SimServo

SERVOS_DIR = Path(registry.__file__).parent


def _imported_after(code: str) -> list[str]:
    """The ``mavservo.servos`` modules a fresh interpreter has imported after ``code``."""
    script = (
        f"import sys, json\n{code}\n"
        "print(json.dumps(sorted(m for m in sys.modules if m.startswith('mavservo.servos'))))"
    )
    out = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=60, check=True
    )
    return list(json.loads(out.stdout.strip().splitlines()[-1]))


def _families(modules: list[str]) -> set[str]:
    return {m.split(".")[2] for m in modules if m.count(".") >= 3}


def test_importing_the_package_imports_no_family() -> None:
    assert _families(_imported_after("import mavservo.servos")) == set()


def test_looking_up_one_family_imports_that_family_alone() -> None:
    modules = _imported_after("from mavservo.servos import get_profile\nget_profile('lk')")
    assert _families(modules) == {"lk"}
    assert "mavservo.servos.lk.sim" not in modules, "the simulated device waits for a simulation"


def test_listing_the_names_imports_no_family() -> None:
    code = "from mavservo.servos import registry\nassert 'robstride' in registry.names()"
    assert _families(_imported_after(code)) == set()


@pytest.mark.parametrize("name", sorted(registry.BUILT_IN))
def test_each_table_line_names_its_family_in_its_own_folder(name: str) -> None:
    line = registry.BUILT_IN[name]
    cls = PROFILES[name]
    assert issubclass(cls, ServoProfile) and cls.name == name
    folder = line.profile.split(".")[0]
    assert cls.__module__ == f"mavservo.servos.{line.profile.split(':')[0]}"
    assert (SERVOS_DIR / folder / "__init__.py").is_file()
    if line.device is not None:
        assert line.device.split(".")[0] == folder, "profile and device share the folder"
        device = SimServo(name, cls.min_id)._device  # noqa: SLF001
        assert type(device).__name__ == line.device.split(":")[1]


def test_every_family_folder_has_a_line_in_the_table() -> None:
    folders = {p.parent.name for p in SERVOS_DIR.glob("*/__init__.py")}
    assert folders == {line.profile.split(".")[0] for line in registry.BUILT_IN.values()}


def test_a_family_package_imports_nothing_on_its_own() -> None:
    """A family's ``__init__`` is empty, so importing its simulated device never drags in the
    profile (the simulators-apart contract would not see an import the package makes)."""
    modules = _imported_after("import mavservo.servos.odrive.sim")
    assert "mavservo.servos.odrive.profile" not in modules


def test_a_table_line_that_names_another_class_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(registry.BUILT_IN, "lk", registry.BuiltIn("rmdx.profile:RmdX"))
    registry._built_in.cache_clear()  # noqa: SLF001
    try:
        with pytest.raises(TypeError, match="does not name a ServoProfile called 'lk'"):
            get_profile("lk")
    finally:
        registry._built_in.cache_clear()  # noqa: SLF001


def test_a_subclass_of_a_built_in_gets_its_base_device() -> None:
    class Renamed(PROFILES["rmd-x"]):  # type: ignore[misc, valid-type]
        name = "renamed-rmd"

    device = simulated_device(Renamed, SimServo("rmd-x", 1), 1, Renamed.Options())
    assert type(device).__name__ == "RmdXV4Device"
