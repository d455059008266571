"""docs/engineering/sitl.md's ArduPilot SITL section, followed literally from a fresh pip install.

A fresh virtual environment gets the project by ``pip install`` (no repository on any path), a
stand-in ArduPilot tree takes the place of a real one (what ArduPilot's docs leave a user with:
``Tools/autotest`` on PATH, the plane built in ``build/sitl/bin``), and the doc's command blocks
run as written, in its network namespace. The stand-ins that must never run (sim_vehicle.py,
waf, git) leave a mark if they do; the stand-in ``arduplane`` plays the autopilot (the project's
own simulated ArduPlane stream on the SERIAL1 address it is given). Needs ``unshare -rn``
(user and network namespaces); skipped where they are not allowed.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from tests.support.paths import REPO
from tests.support.venv import child_env, pip_install

DOC = REPO / "docs" / "engineering" / "sitl.md"

FAKE_ARDUPLANE = """#!/usr/bin/env python3
# stand-in SITL: record the command line, then play ArduPlane on the SERIAL1 address
import signal, sys
from pathlib import Path
here = Path(__file__).resolve().parents[3]
(here / "arduplane-args.txt").write_text(" ".join(sys.argv[1:]))
signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
serial1 = sys.argv[sys.argv.index("--serial1") + 1]
_, host, port = serial1.split(":")
from mavservo.sim.autopilot.sitl_command import main
main(["stream", "--url", f"udpout:{host}:{port}", "--profile", "sweep", "--servo-rate", "1"])
"""


def _marker_tool(path: Path, marker: Path) -> None:
    path.write_text(f'#!/bin/sh\necho "$0 $*" >> {marker}\nexit 1\n')
    path.chmod(0o755)


def _doc_blocks() -> list[str]:
    """The two ``sh`` blocks of "Run (works from a pip install ...)": set-up, then session."""
    text = DOC.read_text()
    section = text[text.index("### Run (works from a pip install") :]
    blocks = re.findall(r"```sh\n(.*?)```", section, re.S)
    return blocks[:2]


def _unshare_works() -> bool:
    if shutil.which("unshare") is None or shutil.which("ip") is None:
        return False
    done = subprocess.run(
        ["unshare", "-rn", "sh", "-c", "ip link set lo up"], capture_output=True, timeout=10
    )
    return done.returncode == 0


@pytest.mark.skipif(not _unshare_works(), reason="unshare -rn (network namespace) not allowed")
@pytest.mark.timeout(180)
def test_docs_sitl_from_a_pip_install_never_rebuilds_or_fetches_and_runs(tmp_path: Path) -> None:
    setup, session = _doc_blocks()
    assert "mavservo examples ~/mavservo" in setup and "unshare -rn" in session

    # the project as pip gets it: a copy of the source tree, installed into a fresh venv
    source = tmp_path / "source"
    source.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(REPO / name, source / name)
    for folder in ("mavservo", "config"):
        shutil.copytree(
            REPO / folder,
            source / folder,
            symlinks=True,
            ignore=shutil.ignore_patterns("__pycache__"),
        )
    python = child_env(tmp_path / "venv")
    pip_install(python, source, tmp_path)
    venv_bin = python.parent

    # a stand-in ArduPilot tree, as ArduPilot's docs leave it: Tools/autotest on PATH, built
    tree = tmp_path / "ardupilot"
    autotest = tree / "Tools" / "autotest"
    (autotest / "models").mkdir(parents=True)
    (autotest / "models" / "plane.parm").write_text("ARSPD_USE 1\n")
    marks = tmp_path / "must-not-run.log"
    _marker_tool(autotest / "sim_vehicle.py", marks)
    _marker_tool(tree / "waf", marks)
    fakebin = tmp_path / "fakebin"
    fakebin.mkdir()
    _marker_tool(fakebin / "git", marks)  # a fetch of submodules would go through git
    binary = tree / "build" / "sitl" / "bin" / "arduplane"
    binary.parent.mkdir(parents=True)
    binary.write_text(FAKE_ARDUPLANE)
    binary.chmod(0o755)

    home, work = tmp_path / "home", tmp_path / "work"
    home.mkdir()
    work.mkdir()
    env = {
        "HOME": str(home),
        "PATH": os.pathsep.join(
            [
                str(venv_bin),
                str(autotest),
                str(fakebin),
                "/usr/sbin",
                "/usr/bin",
                "/sbin",
                "/bin",
            ]
        ),
        "LANG": "C.UTF-8",
    }
    first = subprocess.run(
        ["sh", "-c", setup], env=env, cwd=work, capture_output=True, text=True, timeout=60
    )
    assert first.returncode == 0, first.stdout + first.stderr
    assert (home / "mavservo" / "ardupilot-sitl.yaml").is_file()
    assert str(binary) in first.stdout  # the dry run shows the tree's built binary
    assert "sim_vehicle.py" not in first.stdout

    second = subprocess.run(
        ["sh", "-c", session], env=env, cwd=work, capture_output=True, text=True, timeout=120
    )
    output = second.stdout + second.stderr
    assert second.returncode == 0, output
    assert not marks.exists(), marks.read_text()  # nothing rebuilt, configured or fetched
    args = (tree / "arduplane-args.txt").read_text()
    assert "--serial1 udpclient:127.0.0.1:14551" in args and "--serial0 tcp:0" in args
    assert str(autotest / "models" / "plane.parm") in args
    assert str(source) not in args and str(REPO) not in args  # the installed package's files
    # the bridge ran against it: it heard the autopilot and got its stream at the rate it asked
    assert "autopilot stream SERVO_OUTPUT_RAW: asked 20 Hz (accepted)" in output, output
    sitl_log = (work / "sitl.log").read_text()
    assert "SERIAL1 -> udpclient:127.0.0.1:14551" in sitl_log


def test_examples_are_the_repositorys_configs_and_are_never_written_over(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from mavservo.app.examples import example_names, main

    assert example_names() == sorted(p.name for p in (REPO / "config").glob("*.yaml"))
    assert main([str(tmp_path)]) == 0
    for name in example_names():
        assert (tmp_path / name).read_bytes() == (REPO / "config" / name).read_bytes()
    (tmp_path / "sim.yaml").write_text("# mine\n")
    assert main([str(tmp_path)]) == 2
    assert "already in" in capsys.readouterr().err
    assert (tmp_path / "sim.yaml").read_text() == "# mine\n"
    assert main([str(tmp_path), "--force"]) == 0
    assert (tmp_path / "sim.yaml").read_bytes() == (REPO / "config" / "sim.yaml").read_bytes()
