"""Red-team harness: start `mavservo run` as a separate process on 127.0.0.1 and talk to it as an
outsider would (raw sockets, pymavlink peers). Evidence, not tests. Every loop is bounded."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mavlink2  # noqa: E402

HERE = Path(__file__).resolve().parent
KEY = bytes(range(1, 33))
MAVSERVO = str(Path(sys.executable).parent / "mavservo")


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class BridgeProc:
    def __init__(
        self,
        cfg: str,
        duration: float,
        url: str | None = None,
        verbose=False,
        extra: list[str] | None = None,
        log_dir: str | None = None,
    ) -> None:
        self.port = free_port()
        self.url = url or f"udpin:127.0.0.1:{self.port}"
        self.log_dir = log_dir or f"/tmp/atk_runs/{os.getpid()}_{time.time_ns()}"
        args = [
            MAVSERVO,
            "run",
            "--config",
            str(HERE / cfg),
            "--mavlink",
            self.url,
            "--duration",
            str(duration),
            "--log-dir",
            self.log_dir,
            "-q",
        ]
        if verbose:
            args.append("-v")
        args += extra or []
        self.proc = subprocess.Popen(
            args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        self.out = self.err = ""

    def wait_ready(self, timeout=15.0) -> None:
        """The bridge is ready once its tlog exists and it sends heartbeats (bounded)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"bridge exited: {self.proc.communicate()}")
            if any(Path(self.log_dir).glob("*/mavlink.tlog")):
                time.sleep(1.0)
                return
            time.sleep(0.1)
        raise RuntimeError("bridge not ready")

    def finish(self, timeout=60.0) -> int:
        self.out, self.err = self.proc.communicate(timeout=timeout)
        return self.proc.returncode

    def run_dir(self) -> Path:
        return next(Path(self.log_dir).glob("*/run.json")).parent

    def metrics(self) -> dict[str, Any]:
        return json.loads((self.run_dir() / "metrics.json").read_text())

    def mavlink_stats(self) -> dict[str, Any]:
        return self.metrics()["mavlink"]

    def log_lines(self) -> list[str]:
        return [ln for ln in (self.out + self.err).splitlines() if ln.strip()]


def peer(port: int, source=(255, 190), key: bytes | None = None, link_id=0, bind_ip=None):
    conn = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{port}",
        source_system=source[0],
        source_component=source[1],
        dialect="ardupilotmega",
    )
    if bind_ip:
        conn.port.bind((bind_ip, 0))
    if key is not None:
        conn.setup_signing(key, sign_outgoing=True, link_id=link_id)
    return conn


def collect(conn, seconds: float, kinds=None, limit=100_000) -> list[Any]:
    out = []
    deadline = time.monotonic() + seconds
    for _ in range(limit):
        rem = deadline - time.monotonic()
        if rem <= 0:
            break
        m = conn.recv_match(type=kinds, blocking=True, timeout=min(rem, 0.1))
        if m is not None:
            out.append(m)
    return out


def encoder(source=(255, 190), key: bytes | None = None, link_id=0, timestamp=None):
    enc = mavlink2.MAVLink(None, srcSystem=source[0], srcComponent=source[1])
    if key is not None:
        enc.signing.secret_key = key
        enc.signing.sign_outgoing = True
        enc.signing.link_id = link_id
        enc.signing.timestamp = (
            timestamp if timestamp is not None else int((time.time() - 1420070400) * 100_000)
        )
    return enc


def pack(enc, msg) -> bytes:
    return bytes(msg.pack(enc))
