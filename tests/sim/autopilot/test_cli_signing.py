"""A user with a signed config can rehearse with the command-line autopilot stream too."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

from pymavlink import mavutil

from tests.support.paths import REPO
from tests.support.waiting import free_udp_port

KEY_HEX = "42" * 32


def _stream(*options: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "mavservo.sim.autopilot", "stream", *options],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def test_stream_signs_with_the_key_file_and_a_bad_file_is_one_clear_line(tmp_path: Path) -> None:
    key_file = tmp_path / "signing.key"
    key_file.write_text(KEY_HEX + "\n")
    bad = tmp_path / "bad.key"
    bad.write_text("not a key")
    # the bad key file's run goes alongside the good one (it ends at once, nothing to share)
    proc_bad = _stream("--duration", "1", "--signing-key-file", str(bad))
    port = free_udp_port()
    listener = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255)
    types: set[str] = set()
    try:
        listener.setup_signing(bytes.fromhex(KEY_HEX), sign_outgoing=False)
        listener.mav.signing.allow_unsigned_callback = lambda *_: False  # signed or dropped
        proc = _stream(
            "--url", f"udpout:127.0.0.1:{port}", "--duration", "2",
            "--signing-key-file", str(key_file),
        )  # fmt: skip
        deadline = time.monotonic() + 20
        for _ in range(2000):  # bounded: 20 s at most
            if time.monotonic() > deadline or proc.poll() is not None:
                break
            msg = listener.recv_match(blocking=True, timeout=0.05)
            if msg is not None and msg.get_type() != "BAD_DATA":
                types.add(msg.get_type())
        assert proc.wait(timeout=20) == 0
        signing = listener.mav.signing
    finally:
        listener.close()
    assert {"SERVO_OUTPUT_RAW", "HEARTBEAT"} <= types
    assert signing.sig_count > 0  # signed packets seen, every one verified:
    assert signing.badsig_count == 0 and signing.unsigned_count == 0

    _, err = proc_bad.communicate(timeout=20)
    assert proc_bad.returncode == 2
    expected = f"{bad} must hold 64 hex characters, found 9 bytes"
    assert err.strip() == f"sitl: --signing-key-file: {expected}"
