"""What a ground station gets from the bridge at the default link budget (issue 38).

The bridge runs config/sim.yaml (nine servos, a gimbal, the built-in CAN simulation, the
default budget of 1,000 B/s) with MAVLink on ``udpin:127.0.0.1``; a peer plays the autopilot
(HEARTBEAT every 0.5 s). Every byte the bridge writes on that link is timed (the link's ``tap``)
and the busiest 1-second window (sliding, from each write) is reported. Three scenarios:

* ``qgc``: a client that waits and retries as QGroundControl's FTPManager does (1,000 ms,
  3 retries, tests/support/qgc_ftp.py) downloads general.json and parameters.json.xz from the
  servo component: the time each took, the longest wait for a reply, the retries;
* ``qgc+64``: the same while 64 spoofed ids (systems 100-163) open sessions, each once a
  second, from another address;
* ``ack``: a ground station (not an allowed source, as by default) sends
  MAV_CMD_REQUEST_MESSAGE(ACTUATOR_OUTPUT_STATUS) to 1/140 five times a second for 20 s: the
  COMMAND_ACK latency of each (send to arrival), how many over 300 ms or missing.

Each scenario runs ``--runs`` times per tree and the medians are printed; ``--baseline PATH``
runs the same in another checkout (PYTHONPATH) for the ratio, e.g. the commit before issue 38::

    git worktree add /tmp/before 02b724c
    python bench/bench_ground_stations.py --runs 3 --baseline /tmp/before
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
SIM = REPO / "config" / "sim.yaml"
GCS = (255, 190)
SPOOFED = [(100 + n, 190) for n in range(64)]


def busiest_window(writes: list[tuple[float, int]]) -> int:
    """The most bytes written in any 1-second window starting at a write."""
    writes = sorted(writes)
    best, total, first = 0, 0, 0
    for t, size in writes:
        total += size
        while writes[first][0] <= t - 1.0:
            total -= writes[first][1]
            first += 1
        best = max(best, total)
    return best


def _drain(sock: socket.socket) -> None:
    """Read and drop what waits on a non-blocking socket (the bridge answers these peers)."""
    try:
        while sock.recv(65536):
            pass
    except OSError:
        pass


class Rig:
    """The bridge on sim.yaml, its link's writes timed, an autopilot peer beating."""

    def __init__(self) -> None:
        import yaml

        from mavservo.app.bridge import Bridge, free_udp_port
        from mavservo.config import load_config_text

        raw = yaml.safe_load(SIM.read_text())
        self.port = free_udp_port()
        raw["mavlink"]["url"] = f"udpin:127.0.0.1:{self.port}"
        raw["mavlink"]["monitor_outputs"] = []
        raw["mavlink"]["request_streams"] = {"enabled": False}  # the peer sends no streams
        self.bridge = Bridge(load_config_text(yaml.safe_dump(raw), "<bench>"), log_dir=False)
        self.writes: list[tuple[float, int]] = []
        self.by_type: dict[int, int] = {}
        self._stop = threading.Event()
        self.bridge.start()
        self.bridge.mavlink.link.tap = self._tap
        self._autopilot = threading.Thread(target=self._beat, daemon=True)
        self._autopilot.start()
        time.sleep(1.5)  # the bridge follows the autopilot; its telemetry flows

    def _tap(self, direction: str, data: bytes, _t: float) -> None:
        if direction == "out":
            self.writes.append((time.monotonic(), len(data)))
            if os.environ.get("BENCH_BY_TYPE"):
                msgid = int.from_bytes(data[7:10], "little") if data[:1] == b"\xfd" else -1
                self.by_type[msgid] = self.by_type.get(msgid, 0) + len(data)

    def _beat(self) -> None:
        from pymavlink.dialects.v20 import ardupilotmega as mavlink2

        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", 0))
        sock.setblocking(False)
        mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        # a generic autopilot: an ArduPilot that never looks for the gimbal draws the
        # (correct) "not found" warning, 4 STATUSTEXT chunks that go before any answer
        beat = mavlink2.MAVLink_heartbeat_message(1, 0, 0, 0, 4, 3)
        while not self._stop.wait(0.5):
            sock.sendto(beat.pack(mav), ("127.0.0.1", self.port))
            _drain(sock)
        sock.close()

    def window_since(self, start: float) -> int:
        return busiest_window([w for w in self.writes if w[0] >= start])

    def close(self) -> None:
        self._stop.set()
        self._autopilot.join(2.0)
        self.bridge.stop()


def spoofers(port: int, stop: threading.Event) -> threading.Thread:
    """64 spoofed ids, each opening general.json once a second, from one other address."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    def run() -> None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", 0))
        sock.setblocking(False)
        encoders = [mavlink2.MAVLink(None, srcSystem=s, srcComponent=c) for s, c in SPOOFED]
        seq = 0
        while not stop.is_set():
            for encoder in encoders:
                header = struct.pack("<HBBBBBBI", seq, 0, 4, 13, 0, 0, 0, 0)
                payload = list((header + b"/general.json").ljust(251, b"\x00"))
                msg = mavlink2.MAVLink_file_transfer_protocol_message(0, 1, 140, payload)
                sock.sendto(msg.pack(encoder), ("127.0.0.1", port))
                if stop.wait(1.0 / len(encoders)):
                    break
            seq = (seq + 2) & 0xFFFF
            _drain(sock)
        sock.close()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def qgc(rig: Rig, strangers: bool) -> dict[str, Any]:
    from mavservo.mavlink.connection import open_connection

    sys.path.insert(0, str(REPO))
    from tests.support.qgc_ftp import FtpGaveUp, QgcLikeFtp

    stop = threading.Event()
    attack = spoofers(rig.port, stop) if strangers else None
    if attack is not None:
        time.sleep(5.0)  # the attack under way: every session taken, every spoofed id seen
    conn = open_connection(
        f"udpout:127.0.0.1:{rig.port}", source_system=GCS[0], source_component=GCS[1]
    )
    start = time.monotonic()
    out: dict[str, Any] = {}
    try:
        conn.mav.heartbeat_send(6, 8, 0, 0, 0)
        client = QgcLikeFtp(conn, (1, 140))
        for name in ("general.json", "parameters.json.xz"):
            try:
                got = client.download(f"/{name}")
                out[name] = {"s": got.seconds, "max_wait_s": max(got.waits), "retries": got.retries}
            except (FtpGaveUp, RuntimeError) as exc:  # no reply in time, or a NAK
                out[name] = {"failed": str(exc)}
    finally:
        stop.set()
        if attack is not None:
            attack.join(3.0)
        conn.close()
    out["busiest_window_B"] = rig.window_since(start)
    out["ftp"] = rig.bridge.mavlink.stats()["ftp"]["140"]
    if rig.by_type:
        out["bytes_by_message_id"] = dict(sorted(rig.by_type.items(), key=lambda kv: -kv[1]))
    return out


def ack(rig: Rig, seconds: float = 20.0) -> dict[str, Any]:
    from mavservo.mavlink.connection import open_connection

    conn = open_connection(
        f"udpout:127.0.0.1:{rig.port}", source_system=GCS[0], source_component=GCS[1]
    )
    sent: list[float] = []
    acks: list[float] = []
    stop = threading.Event()

    def receive() -> None:
        while not stop.is_set():
            msg = conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.1)
            if msg is not None and msg.command == 512 and msg.get_srcComponent() == 140:
                acks.append(time.monotonic())

    reader = threading.Thread(target=receive, daemon=True)
    reader.start()
    start = time.monotonic()
    try:
        for n in range(int(seconds * 5)):
            at = start + n * 0.2
            time.sleep(max(0.0, at - time.monotonic()))
            sent.append(time.monotonic())
            conn.mav.command_long_send(1, 140, 512, 0, 375, 0, 0, 0, 0, 0, 0)
        time.sleep(2.0)
    finally:
        stop.set()
        reader.join(2.0)
        conn.close()
    # each request is acknowledged, as a ground station sees it, by the first ACK of its
    # command that arrives after it (QGroundControl and MAVSDK match an ACK by command id; a
    # request repeated before its ACK went is answered once)
    latencies = []
    for t in sent:
        got = next((a for a in acks if a >= t), None)
        if got is not None and got - t < 2.0:
            latencies.append(got - t)
    return {
        "requests": len(sent),
        "acks": len(acks),
        "acked": len(latencies),
        "median_ms": 1000 * statistics.median(latencies) if latencies else None,
        "max_ms": 1000 * max(latencies) if latencies else None,
        "over_300ms_or_missing": sum(x > 0.3 for x in latencies) + len(sent) - len(latencies),
        "p95_ms": 1000 * sorted(latencies)[int(0.95 * len(latencies))] if latencies else None,
        "late_at_s": [
            round(t - start, 1) for t, x in zip(sent, latencies, strict=False) if x > 0.3
        ],
        "busiest_window_B": rig.window_since(start),
    }


def child(scenario: str) -> None:
    rig = Rig()
    try:
        result = ack(rig) if scenario == "ack" else qgc(rig, strangers=scenario == "qgc+64")
    finally:
        rig.close()
    print(json.dumps(result))


def run_in(tree: Path, scenario: str) -> dict[str, Any]:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    done = subprocess.run(
        [sys.executable, str(Path(__file__).resolve()), "--child", scenario],
        env=env,
        cwd=tree,
        capture_output=True,
        text=True,
        timeout=300,
        check=True,
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def _median(values: list[Any]) -> Any:
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else None


def summarise(results: list[dict[str, Any]], scenario: str) -> dict[str, Any]:
    if scenario == "ack":
        keys = (
            "acks",
            "acked",
            "median_ms",
            "p95_ms",
            "max_ms",
            "over_300ms_or_missing",
            "busiest_window_B",
        )
        return {k: _median([r[k] for r in results]) for k in keys} | {
            "requests": results[0]["requests"]
        }
    out: dict[str, Any] = {"busiest_window_B": _median([r["busiest_window_B"] for r in results])}
    names = ("general.json", "parameters.json.xz")
    failures = {str(r[n]["failed"])[:60] for r in results for n in names if "failed" in r[n]}
    if failures:
        out["why_failed"] = sorted(failures)
    for name in ("general.json", "parameters.json.xz"):
        runs = [r[name] for r in results]
        failed = sum("failed" in r for r in runs)
        ok = [r for r in runs if "failed" not in r]
        out[name] = {
            "failed": f"{failed}/{len(runs)}",
            "s": _median([r["s"] for r in ok]),
            "max_wait_s": _median([r["max_wait_s"] for r in ok]),
            "retries": _median([r["retries"] for r in ok]),
        }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--child", help=argparse.SUPPRESS)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--baseline", type=Path, help="another checkout to compare with")
    parser.add_argument("--scenarios", default="qgc,qgc+64,ack")
    args = parser.parse_args()
    if args.child:
        child(args.child)
        return
    trees = {"this": REPO} | ({"baseline": args.baseline} if args.baseline else {})
    for scenario in args.scenarios.split(","):
        for label, tree in trees.items():
            results = [run_in(tree, scenario) for _ in range(args.runs)]
            print(scenario, label, json.dumps(summarise(results, scenario)), flush=True)


if __name__ == "__main__":
    main()
