"""A throw-away virtual environment that reuses this one's packages, for install tests.

Installing a project "as a user would" must not need the network nor minutes: the environment
gets this interpreter's site directories through a ``.pth`` file (so pip, setuptools and the
dependencies are there), and the project goes in with ``--no-deps --no-build-isolation
--no-index`` from a copy (a build leaves files behind in its source folder).
"""

from __future__ import annotations

import os
import site
import subprocess
import venv
from pathlib import Path

TIMEOUT_S = 180


def child_env(env_dir: Path) -> Path:
    """Create the environment in ``env_dir``; returns its python."""
    venv.EnvBuilder(system_site_packages=True, with_pip=False).create(env_dir)
    python = env_dir / "bin" / "python"
    purelib = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        capture_output=True,
        text=True,
        check=True,
        timeout=TIMEOUT_S,
    ).stdout.strip()
    ours = [p for p in site.getsitepackages() if Path(p).is_dir()]
    lines = "".join(f"import site; site.addsitedir({p!r})\n" for p in ours)
    (Path(purelib) / "zz_parent_env.pth").write_text(lines)
    return python


def pip_install(python: Path, source: Path, cwd: Path) -> None:
    """``pip install`` the project at ``source`` into ``python``'s environment, offline."""
    subprocess.run(
        [
            str(python),
            "-m",
            "pip",
            "install",
            "--quiet",
            "--no-deps",
            "--no-build-isolation",
            "--no-index",
            str(source),
        ],
        check=True,
        timeout=TIMEOUT_S,
        cwd=cwd,
        env={**os.environ, "PIP_NO_INPUT": "1"},
    )
