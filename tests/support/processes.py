"""Stopping a SITL launched in its own session (ArduPlane, PX4): the tests' one way to do it."""

from __future__ import annotations

import os
import signal
import subprocess
from typing import Any


def stop_session(proc: subprocess.Popen[Any]) -> int | None:
    """SIGTERM to the process group, then (bounded) SIGKILL; the exit status SIGTERM gave
    (None: it had to be killed)."""
    if proc.poll() is not None:
        return proc.returncode
    os.killpg(proc.pid, signal.SIGTERM)
    try:
        return proc.wait(20)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(5)
        return None
