"""The user-facing surface of a mavservo tree, printed so two trees can be diffed: every
subcommand's ``--help``, and what a 6-s ``mavservo run`` of the built-in simulation writes
(file names, JSON keys, CSV headers) and whether ``mavservo report`` reads it. Run by hand:

    git archive <old> | tar -x -C /tmp/old
    PYTHONPATH=/tmp/old python bench/user_surface.py > old.txt
    PYTHONPATH=. python bench/user_surface.py > new.txt && diff old.txt new.txt

Why: a refactor (issue 31) must leave the command line and the run directory as they were;
this shows it in one diff instead of by reading.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path


def mavservo(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "mavservo", *args], capture_output=True, text=True, timeout=120
    )


def describe(path: Path) -> str:
    line = path.name
    if path.suffix == ".json":
        data = json.loads(path.read_text())
        if isinstance(data, dict):
            line += "  keys: " + ",".join(sorted(data))
    elif path.suffix == ".csv" and path.stat().st_size:
        line += "  header: " + path.read_text().splitlines()[0]
    return line


def main() -> None:
    from mavservo.cli import COMMANDS

    out = ["## mavservo --help", mavservo("--help").stdout]
    for name in COMMANDS:
        shown = mavservo(name, "--help")
        out += [f"## mavservo {name} --help", shown.stdout + shown.stderr]
    with tempfile.TemporaryDirectory() as base:
        mavservo("run", "--duration", "6", "--quiet", "--log-dir", base)
        [run] = [p for p in Path(base).iterdir() if p.is_dir()]
        out.append("## run directory")
        out += [describe(p) for p in sorted(run.rglob("*"))]
        out.append(f"## mavservo report exit {mavservo('report', str(run)).returncode}")
    print("\n".join(out))


if __name__ == "__main__":
    main()
