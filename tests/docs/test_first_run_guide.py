"""docs/first-run.md, followed literally: a newcomer reaches a running bridge, emulated adapter.

Issue 37, "Must show": "a newcomer following only the guide reaches a running bridge on the
emulated adapter (a test runs the guide's commands literally)". The page's commands are the
``$ `` lines of its ```console blocks, its files the ```yaml blocks under a ``<!-- file: NAME -->``
marker; they run in that order in one bash shell, as a person types them in one terminal, with a
fresh HOME. Two things stand in for the person: after a command sent to the background with
``--link PATH`` the script waits (bounded) until PATH exists, as a person sees the path printed
before typing on; and the shell runs in its own network namespace when the machine allows one, so
the page's fixed UDP port 14551 cannot meet another test's.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support.paths import REPO

GUIDE = REPO / "docs" / "first-run.md"

_BLOCK = re.compile(
    r"(?:<!-- file: (?P<file>[^ ]+) -->\n)?```(?P<lang>\w+)\n(?P<body>.*?)```", re.S
)


def guide_script(text: str) -> str:
    """The guide as a bash script: its commands and files, in the page's order."""
    lines = ["set -eu"]
    for block in _BLOCK.finditer(text):
        if block["file"]:
            lines += [f"cat > {shlex.quote(block['file'])} <<'GUIDE_FILE'", block["body"]]
            lines.append("GUIDE_FILE")
        elif block["lang"] == "console":
            for line in block["body"].splitlines():
                if line.startswith("$ "):
                    lines += [line[2:], *_wait_for_link(line[2:])]
    return "\n".join(lines) + "\n"


def _wait_for_link(command: str) -> list[str]:
    """After ``... --link PATH &``: wait until PATH exists (at most 30 s), as a person would."""
    words = shlex.split(command.rstrip("& "))
    if not command.rstrip().endswith("&") or "--link" not in words:
        return []
    path = shlex.quote(words[words.index("--link") + 1])
    return [f"for _ in $(seq 300); do [ -e {path} ] && break; sleep 0.1; done; [ -e {path} ]"]


def _namespace_prefix() -> list[str]:
    """``unshare -rn`` (a network namespace with only ``lo``) where the machine allows it."""
    if shutil.which("unshare") is None or shutil.which("ip") is None:
        return []
    probe = ["unshare", "-rn", "sh", "-c", "ip link set lo up"]
    if subprocess.run(probe, capture_output=True, timeout=10).returncode != 0:
        return []
    return ["unshare", "-rn", "sh", "-c", 'ip link set lo up && exec bash "$0"']


def test_the_script_is_the_pages_commands_in_order() -> None:
    script = guide_script(GUIDE.read_text(encoding="utf-8"))
    commands = [
        line.split()[0:2] for line in script.splitlines()[1:] if line.startswith("mavservo ")
    ]
    assert commands == [
        ["mavservo", "sim"],
        ["mavservo", "sitl"],
        ["mavservo", "doctor"],
        ["mavservo", "check"],
        ["mavservo", "run"],
        ["mavservo", "report"],
    ]
    assert "cat > my-rig.yaml" in script and "kill %1 %2" in script


@pytest.mark.timeout(150)
def test_a_newcomer_following_the_page_reaches_a_running_bridge(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")  # the page's report step needs the report extra
    script = tmp_path / "guide.sh"
    script.write_text(guide_script(GUIDE.read_text(encoding="utf-8")))
    home = tmp_path / "home"
    home.mkdir()
    env = {
        **os.environ,
        "HOME": str(home),
        "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}",
    }
    namespace = _namespace_prefix()
    command = [*namespace, str(script)] if namespace else ["bash", str(script)]
    process = subprocess.Popen(
        command,
        cwd=home,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    try:
        output, _ = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    assert process.returncode == 0, output
    # the doctor found both servos, check accepted the file, the bridge ran and heard them
    assert re.search(r"aileron +rmd-x id 1: OK", output), output
    assert re.search(r"elevator +rmd-x id 2: OK", output), output
    assert "my-rig.yaml: valid" in output
    assert "heartbeat heard" in output
    for servo in ("aileron", "elevator"):
        # the summary row: sent, received (no timing bound: a loaded machine loses replies)
        row = re.search(rf"^  {servo} +(\d+) +(\d+) ", output, re.M)
        assert row, output
        sent, received = map(int, row.groups())
        assert sent > 10 and received > 10, row.group(0)
    runs = [path for path in (home / "mavservo-trial" / "runs").iterdir() if path.is_dir()]
    assert len(runs) == 1
    assert (runs[0] / "can.asc").stat().st_size > 0
    assert (runs[0] / "report" / "report.md").is_file()
