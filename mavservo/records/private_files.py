"""Files only the run's owner can read: the run directory's modes and its atomic JSON writes.

CAN frames and MAVLink traffic are nobody else's business (docs/engineering/reliability.md): the run
directory is 0700 and every file in it 0600, whatever the umask. Every writer of the run
directory (the buffered sinks, python-can's CAN log writers, ``run.json``/``metrics.json``)
creates its file through here, so the rule lives in one place.
"""

from __future__ import annotations

import contextlib
import json
import os
import stat
from collections.abc import Mapping
from pathlib import Path
from typing import Any

DIR_MODE = 0o700
FILE_MODE = 0o600


def create_private(path: str | os.PathLike[str]) -> None:
    """Create (or truncate) ``path`` as an empty file only its owner can read (0600).

    python-can's writers open their files by name; creating them first fixes the mode
    (``open`` keeps an existing file's mode). Only a regular file is chmod-ed: a test's
    symlink to ``/dev/full`` must not change the device.
    """
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, FILE_MODE)
    try:
        if stat.S_ISREG(os.fstat(fd).st_mode):
            os.fchmod(fd, FILE_MODE)
    finally:
        os.close(fd)


def write_json_atomic(path: Path, data: Mapping[str, Any]) -> None:
    """Write ``path`` (0600) through a temporary file that never outlives a failure."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    text = json.dumps(data, indent=2, default=str) + "\n"
    try:
        create_private(tmp)
        with open(tmp, "w", encoding="utf-8") as handle:
            handle.write(text)
            handle.flush()
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
