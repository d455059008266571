"""``mavservo examples DIR``: write the example configs to a folder.

After ``pip install`` the repository's ``config/`` folder is not on the machine, yet the docs
start from those files (``config/ardupilot-sitl.yaml`` for ArduPilot SITL, ``config/gimbal.yaml``,
...). They ship inside the package (``mavservo/data/examples``, the same files); this command
copies them where the user wants to edit them, never over an existing file unless ``--force``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from importlib import resources
from pathlib import Path

EXIT_OK = 0
EXIT_REFUSED = 2


def example_names() -> list[str]:
    """The shipped example configs, by file name."""
    folder = resources.files("mavservo") / "data" / "examples"
    return sorted(item.name for item in folder.iterdir() if item.name.endswith(".yaml"))


def main(argv: Sequence[str] | None = None, prog: str = "mavservo examples") -> int:
    parser = argparse.ArgumentParser(
        prog=prog,
        description="Write the example configs (ArduPilot SITL, gimbal, each servo family...) "
        "to a folder, to edit and run: mavservo run --config DIR/NAME.yaml",
    )
    parser.add_argument("dir", metavar="DIR", help="folder to write them to (created if needed)")
    parser.add_argument("--force", action="store_true", help="overwrite files already there")
    args = parser.parse_args(list(sys.argv[1:] if argv is None else argv))
    target = Path(args.dir)
    names = example_names()
    clashes = [name for name in names if (target / name).exists()]
    if clashes and not args.force:
        print(
            f"mavservo examples: {', '.join(clashes)} already in {target}: nothing written "
            "(--force overwrites)",
            file=sys.stderr,
        )
        return EXIT_REFUSED
    try:
        target.mkdir(parents=True, exist_ok=True)
        folder = resources.files("mavservo") / "data" / "examples"
        for name in names:
            (target / name).write_bytes((folder / name).read_bytes())
    except OSError as exc:
        print(f"mavservo examples: cannot write to {target}: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    print(f"wrote {len(names)} example configs to {target}: {', '.join(names)}")
    print(f"  ArduPilot SITL: mavservo run --config {target / 'ardupilot-sitl.yaml'}")
    print(
        "  gimbal.yaml and plane-surfaces.yaml sign: put their signing.key next to them "
        "(their first lines say how)"
    )
    return EXIT_OK
