"""Live figures of the bridge against PX4 SITL (SIH airplane 10041): docs/engineering/px4-sitl.md.

Run by hand, never in CI, one PX4 at a time, in a network namespace with only ``lo`` (PX4's
listeners bind every address)::

    ip netns add px4t; ip netns exec px4t ip link set lo up
    ip netns exec px4t env PX4_HOME=/path/to/PX4-Autopilot python bench/bench_px4_sitl.py

It starts PX4 with ``mavservo sitl px4`` (the companion's parameters), the bridge's MAVLink side
with ``config/px4-sitl.yaml``'s settings on a timing backend (every output channel and actuator
mapped, a gimbal on component 154), and a ground station on PX4's GCS link (UDP 14550), then:

1. mirror: the GCS moves outputs 1-3 with MANUAL_CONTROL (manual mode, prearmed) and outputs 5
   and 6 with DO_SET_ACTUATOR to PX4 (Peripheral via Actuator Set 1/2); for each output and each
   stream (SERVO_OUTPUT_RAW, ACTUATOR_OUTPUT_STATUS) every value change that reached the bridge
   must reach the backend, in order (mismatches), and the lag from PX4's sample time (time_usec,
   aligned on the fastest sample) to the setpoint; plus DO_SET_ACTUATOR command to setpoint;
2. gimbal: the GCS takes the gimbal manager's control and sends DO_GIMBAL_MANAGER_PITCHYAW at
   the bridge's command rate (20 Hz); command to servo setpoint p50/p95, pitch -90 exact; and the
   rate of GIMBAL_DEVICE_SET_ATTITUDE PX4 sends (asked 20 Hz; 5 Hz by default);
3. failsafe: PX4 frozen (SIGSTOP) for 5 s: time to the bridge's failsafe, then SIGCONT: time to
   recovery;
4. PX4's own count of messages it lost on the bridge's link (``px4-mavlink status``: rx loss),
   with the bridge as configured (flavour px4) and, for contrast, told the autopilot is an
   ArduPilot (then it sends ESC_TELEMETRY_x_TO_y, which PX4 drops).

Prints the figures and writes them as JSON (``--out``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from mavservo.config.loader import load_config  # noqa: E402
from mavservo.config.views import mavlink_settings  # noqa: E402
from mavservo.mavlink import mavlink2 as mav  # noqa: E402
from mavservo.mavlink import open_connection  # noqa: E402
from mavservo.mavlink.backend import ACCEPTED  # noqa: E402
from mavservo.mavlink.gimbal import GimbalDevice  # noqa: E402
from mavservo.mavlink.gimbal_settings import GimbalSettings  # noqa: E402
from mavservo.mavlink.quaternion import quaternion_to_euler  # noqa: E402
from mavservo.mavlink.side import MavlinkSide  # noqa: E402
from mavservo.sim.autopilot.px4_sitl import find_px4, telemetry_status  # noqa: E402
from tests.support.mavlink_doubles import RecordingBackend  # noqa: E402

CONFIG = REPO / "config" / "px4-sitl.yaml"
#: a gimbal setpoint later than this after its command belongs to a later command
FOLLOW_S = 0.5
#: GimbalSettings.apply_deadband_deg (0.05) plus float32 rounding
DEADBAND_DEG = 0.06
GCS = (255, 190)


class TimedBackend(RecordingBackend):
    """Maps every servo output channel and actuator; records (t, kind, key, value). Its three
    servos (RecordingBackend's) make the bridge publish its telemetry, ESC_* included."""

    def __init__(self) -> None:
        super().__init__()
        self.timed: list[tuple[float, str, Any, Any]] = []
        self.failsafe: list[tuple[float, str]] = []

    def mapped_servo_channels(self) -> set[int]:
        return set(range(1, 17))

    def mapped_actuator_indices(self) -> set[int]:
        return set(range(1, 17))

    def apply_servo_output(self, channel: int, pwm_us: float, source: str, now: float) -> Any:
        with self.lock:
            self.timed.append((time.monotonic(), "servo", channel, pwm_us))
        return ACCEPTED

    def apply_actuator(self, index: int, value: float, source: str, now: float) -> Any:
        with self.lock:
            self.timed.append((time.monotonic(), "actuator", index, value))
        return ACCEPTED

    def apply_gimbal(self, gimbal: str, roll: Any, pitch: Any, yaw: Any, source: str, now: float):
        with self.lock:
            self.timed.append((time.monotonic(), "gimbal", 0, (roll, pitch, yaw)))
        return ACCEPTED

    def enter_failsafe(self, reason: str, now: float) -> None:
        self.failsafe.append((time.monotonic(), "enter"))

    def leave_failsafe(self, now: float) -> None:
        self.failsafe.append((time.monotonic(), "leave"))

    def of(self, kind: str) -> list[tuple[float, Any, Any]]:
        with self.lock:
            return [(t, k, v) for t, c, k, v in self.timed if c == kind]


def pct(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(round(q * (len(ordered) - 1))))]


def ms(values: list[float]) -> dict[str, float]:
    if not values:
        return {"n": 0}
    return {
        "n": len(values),
        "p50_ms": round(1000 * statistics.median(values), 1),
        "p95_ms": round(1000 * pct(values, 0.95), 1),
        "max_ms": round(1000 * max(values), 1),
    }


class Px4:
    """PX4 SITL through the launcher; its own session so SIGSTOP/SIGTERM reach PX4."""

    def __init__(self, work: Path) -> None:
        self.work = work
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "mavservo", "sitl", "px4", "--workdir", str(work)],
            stdin=subprocess.DEVNULL,
            stdout=open(work / "px4-console.log", "wb"),  # noqa: SIM115 - lives with PX4
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )

    def signal(self, signum: int) -> None:
        os.killpg(self.proc.pid, signum)

    def stop(self) -> int | None:
        if self.proc.poll() is None:
            self.signal(signal.SIGTERM)
            try:
                return self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.signal(signal.SIGKILL)
                self.proc.wait(5)
                return None
        return self.proc.returncode


def rx_loss(bin_dir: Path) -> dict[str, Any]:
    """PX4's received / lost / parse errors per MAVLink instance (:func:`telemetry_status`)."""
    keys = ("mode", "data_rate", "rx_message_count", "rx_message_lost_count", "rx_parse_errors")
    return {
        f"instance {n}": {key: fields.get(key) for key in keys}
        for n, fields in telemetry_status(bin_dir).items()
    }


def gimbal_device(backend: TimedBackend) -> GimbalDevice:
    settings = GimbalSettings(
        name="camera",
        component_id=154,
        axis_servos={"pitch": "gimbal_pitch", "yaw": "gimbal_yaw"},
        limits_deg={"pitch": (-90.0, 30.0), "yaw": (-160.0, 160.0)},
        system_id=1,
    )
    return GimbalDevice(settings, backend)


def run(args: argparse.Namespace) -> dict[str, Any]:
    found = find_px4(os.environ.get("PX4_HOME"))
    if found is None:
        raise SystemExit("no PX4 SITL binary: set PX4_HOME")
    bin_dir = found[0].parent
    results: dict[str, Any] = {"px4": str(found[0]), "command_period_s": None}
    settings = dataclasses.replace(mavlink_settings(load_config(CONFIG)), signing=None)
    if not args.stream_requests:  # PX4's own onboard rates: 10 Hz, none, 5 Hz
        settings = dataclasses.replace(
            settings,
            stream_request=dataclasses.replace(settings.stream_request, enabled=False),
        )
    results["stream_requests"] = args.stream_requests
    if args.flavour != "px4":
        settings = dataclasses.replace(settings, autopilot_flavour=args.flavour)
    results["flavour"] = settings.autopilot_flavour
    results["command_period_s"] = settings.command_period_s
    backend = TimedBackend()
    arrivals: dict[str, list[tuple[float, Any]]] = defaultdict(list)
    work = Path(tempfile.mkdtemp(prefix="bench-px4-"))
    started = time.monotonic()
    px4 = Px4(work)
    gcs = open_connection("udpin:127.0.0.1:14550", source_system=GCS[0], source_component=GCS[1])
    side = MavlinkSide(settings, backend, gimbals=[gimbal_device(backend)])
    handle = side.core.mirror.handle

    def recording(msg: Any, now: float) -> None:
        arrivals[msg.get_type()].append((time.monotonic(), msg))
        handle(msg, now)

    side.core.mirror.handle = recording  # type: ignore[method-assign]
    setpoints: list[tuple[float, Any]] = []
    gimbal_handle = side.core.gimbals[154].handle_message

    def gimbal_recording(msg: Any, now: float) -> None:
        if msg.get_type() == "GIMBAL_DEVICE_SET_ATTITUDE":
            setpoints.append((time.monotonic(), msg))
        gimbal_handle(msg, now)

    side.core.gimbals[154].handle_message = gimbal_recording  # type: ignore[method-assign]
    stop_gcs = threading.Event()
    gcs_seen: dict[str, int] = defaultdict(int)

    def gcs_loop() -> None:
        next_hb = 0.0
        while not stop_gcs.is_set():
            now = time.monotonic()
            if now >= next_hb:
                gcs.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 4)
                next_hb = now + 1.0
            msg = gcs.recv_match(blocking=True, timeout=0.05)
            if msg is not None:
                gcs_seen[msg.get_type()] += 1

    threading.Thread(target=gcs_loop, daemon=True).start()
    try:
        with side:

            def stream(name: str) -> dict[str, Any]:
                return side.stats()["stream"]["streams"].get(name, {})

            def wait(cond: Any, timeout: float) -> bool:
                end = time.monotonic() + timeout
                while time.monotonic() < end:
                    if cond():
                        return True
                    time.sleep(0.1)
                return False

            assert wait(lambda: side.stats()["autopilot_flavour"]["heard"] == "px4", 120)
            results["boot_to_heartbeat_s"] = round(time.monotonic() - started, 1)
            assert wait(lambda: gcs_seen["HEARTBEAT"] > 0, 30), "no GCS link"
            assert not args.stream_requests or wait(
                lambda: stream("ACTUATOR_OUTPUT_STATUS").get("answer") == "accepted", 30
            )
            wait(lambda: 154 in side.stats()["gimbal_discovery"]["found"], 20)
            wait(lambda: stream("GIMBAL_DEVICE_SET_ATTITUDE").get("received_hz") is not None, 20)
            time.sleep(6.0)
            results["streams"] = side.stats()["stream"]["streams"]
            results["gimbal_found"] = side.stats()["gimbal_discovery"]

            # ---------------------------------------------------------------- 1. mirror
            mark = time.monotonic()
            commands: list[tuple[float, int, float]] = []
            t_end = mark + args.mirror_s
            i = 0
            while time.monotonic() < t_end:
                now = time.monotonic()
                phase = 2 * math.pi * (now - mark) / 4.0
                gcs.mav.manual_control_send(
                    1,
                    int(600 * math.sin(phase)),
                    int(600 * math.cos(phase)),
                    500,
                    int(500 * math.sin(2 * phase)),
                    0,
                )
                if i % 2 == 0:  # DO_SET_ACTUATOR at 10 Hz: a new value each time
                    value = round(0.8 * math.sin(phase * 1.7), 3)
                    gcs.mav.command_long_send(
                        1,
                        1,
                        mav.MAV_CMD_DO_SET_ACTUATOR,
                        0,
                        value,
                        -value,
                        math.nan,
                        math.nan,
                        math.nan,
                        math.nan,
                        0,
                    )
                    commands.append((time.monotonic(), 5, value))
                i += 1
                time.sleep(0.05)
            time.sleep(1.0)
            results["mirror"] = mirror_figures(
                arrivals, backend, (mark, time.monotonic()), commands
            )

            # ---------------------------------------------------------------- 2. gimbal
            gcs.mav.command_long_send(
                1, 1, mav.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, 0, GCS[0], GCS[1], -1, -1, 0, 0, 0
            )
            time.sleep(1.0)
            sent: list[tuple[float, float]] = []
            pitches = [-90.0] + [round(-80 + 70 * math.sin(k / 7.0), 2) for k in range(1, 200)]
            gimbal_mark = time.monotonic()
            for k, pitch in enumerate(pitches[: int(args.gimbal_s / settings.command_period_s)]):
                if k and k % 40 == 0:
                    pitch = -90.0
                gcs.mav.command_long_send(
                    1,
                    1,
                    mav.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
                    0,
                    pitch,
                    0.0,
                    math.nan,
                    math.nan,
                    0,
                    0,
                    0,
                )
                sent.append((time.monotonic(), pitch))
                time.sleep(settings.command_period_s)
            time.sleep(1.0)
            results["gimbal"] = gimbal_figures(sent, backend, setpoints, gimbal_mark)

            # ---------------------------------------------------------------- 4. rx loss
            results["px4_rx_loss"] = rx_loss(bin_dir)

            # ---------------------------------------------------------------- 3. failsafe
            px4.signal(signal.SIGSTOP)
            frozen = time.monotonic()
            wait(lambda: any(e == "enter" for _, e in backend.failsafe), 15)
            time.sleep(max(0.0, 5.0 - (time.monotonic() - frozen)))
            px4.signal(signal.SIGCONT)
            resumed = time.monotonic()
            wait(lambda: any(e == "leave" for _, e in backend.failsafe), 15)
            enter = next((t for t, e in backend.failsafe if e == "enter"), None)
            leave = next((t for t, e in backend.failsafe if e == "leave"), None)
            results["failsafe"] = {
                "heartbeat_timeout_s": settings.heartbeat_timeout_s,
                "freeze_to_failsafe_s": None if enter is None else round(enter - frozen, 2),
                "resume_to_recovery_s": None if leave is None else round(leave - resumed, 2),
            }
            time.sleep(2.0)
            results["bridge_stats"] = {
                k: side.stats()[k] for k in ("core", "mirror", "gimbals", "autopilot_flavour")
            }
    finally:
        stop_gcs.set()
        results["px4_exit"] = px4.stop()
        gcs.close()
    results["gcs_received"] = dict(gcs_seen)
    return results


def mirror_figures(
    arrivals: dict[str, list[tuple[float, Any]]],
    backend: TimedBackend,
    window: tuple[float, float],
    commands: list[tuple[float, int, float]],
) -> dict[str, Any]:
    """Per stream and output: changes that arrived, setpoints, mismatches, lag."""
    out: dict[str, Any] = {}
    applied = {
        "SERVO_OUTPUT_RAW": backend.of("servo"),
        "ACTUATOR_OUTPUT_STATUS": backend.of("actuator"),
    }
    for name, kind_calls in applied.items():
        mark, end = window
        msgs = [(t, m) for t, m in arrivals[name] if mark <= t <= end]
        if not msgs:
            out[name] = {"messages": 0}
            continue
        # PX4's clock and this machine's drift apart (SIH time is not wall time): the transit
        # is taken from the fastest sample within a second either side, not over the whole run
        offsets = _local_offsets([(t, m.time_usec / 1e6) for t, m in msgs])
        per_output: dict[int, Any] = {}
        for output in range(1, 7):
            changes: list[tuple[float, float]] = []
            last = None
            for (_t, m), offset in zip(msgs, offsets, strict=True):
                value = (
                    float(getattr(m, f"servo{output}_raw"))
                    if name == "SERVO_OUTPUT_RAW"
                    else float(m.actuator[output - 1])
                )
                if value != last:
                    changes.append((m.time_usec / 1e6 + offset, value))
                    last = value
            sets = [(t, v) for t, k, v in kind_calls if k == output and mark <= t <= end + 1]
            if name == "ACTUATOR_OUTPUT_STATUS":
                expect = [(t, (v - 1500.0) / 500.0) for t, v in changes if v != 0]
            else:
                expect = [(t, v) for t, v in changes if v != 0]
            expect = [
                (t, max(-1.0, min(1.0, v)) if name == "ACTUATOR_OUTPUT_STATUS" else v)
                for t, v in expect
            ]
            mismatches = 0
            lags: list[float] = []
            j = 0
            for t_sample, value in expect[1:]:  # the first change may precede the mark
                k = j
                while k < len(sets) and not math.isclose(sets[k][1], value, abs_tol=1e-6):
                    k += 1
                if k == len(sets):  # this change never became a setpoint (in order)
                    mismatches += 1
                    continue
                lags.append(sets[k][0] - t_sample)
                j = k + 1
            per_output[output] = {
                "changes": len(expect),
                "setpoints": len(sets),
                "mismatches": mismatches,
                "lag": ms(lags),
            }
        arrival = [t_set - t_arr for t_arr, t_set in _arrival_to_setpoint(msgs, kind_calls, name)]
        out[name] = {
            "messages": len(msgs),
            "arrival_to_setpoint": ms(arrival),
            "outputs": per_output,
        }
    # DO_SET_ACTUATOR (to PX4) -> PX4's output 5 -> ACTUATOR_OUTPUT_STATUS -> servo setpoint
    sets5 = [(t, v) for t, k, v in backend.of("actuator") if k == 5 and window[0] <= t]
    cmd_lags = []
    for t_cmd, _output, value in commands:
        hit = next((t for t, v in sets5 if t >= t_cmd and abs(v - value) < 0.0021), None)
        if hit is not None:
            cmd_lags.append(hit - t_cmd)
    out["do_set_actuator_to_setpoint"] = {"commands": len(commands), **ms(cmd_lags)}
    return out


def _local_offsets(samples: list[tuple[float, float]], half_window_s: float = 1.0) -> list[float]:
    """For each (arrival, sample time): the smallest arrival - sample time within
    ``half_window_s`` of it (the transit of the fastest nearby sample, drift left out)."""
    out = []
    for t, _ in samples:
        out.append(min(a - b for a, b in samples if abs(a - t) <= half_window_s))
    return out


def _arrival_to_setpoint(
    msgs: list[tuple[float, Any]], calls: list[tuple[float, Any, Any]], name: str
) -> list[tuple[float, float]]:
    """(message arrival, setpoint) pairs: for each message that changed output 1's value, the
    first setpoint of that value after it arrived (the bridge's own part of the lag)."""
    pairs = []
    last = None
    for t, m in msgs:
        value = float(m.servo1_raw) if name == "SERVO_OUTPUT_RAW" else float(m.actuator[0])
        if name == "ACTUATOR_OUTPUT_STATUS":
            value = max(-1.0, min(1.0, (value - 1500.0) / 500.0))
        if value == last:
            continue
        last = value
        hit = next(
            (ts for ts, k, v in calls if k == 1 and ts >= t and math.isclose(v, value)), None
        )
        if hit is not None:
            pairs.append((t, hit))
    return pairs


def gimbal_figures(
    sent: list[tuple[float, float]],
    backend: TimedBackend,
    setpoints: list[tuple[float, Any]],
    mark: float,
) -> dict[str, Any]:
    calls = [(t, v) for t, _k, v in backend.of("gimbal") if t >= mark]
    lags, missing, exact_90 = [], 0, []
    for t_cmd, pitch in sent:
        # followed: a setpoint of this pitch within FOLLOW_S of the command (later ones are a
        # later command of the same pitch: the sine comes back); a command the next one
        # replaced before PX4's stream sent it is "not followed" (PX4 sends the latest)
        hit = next(
            (
                (t, v)
                for t, v in calls
                if t_cmd <= t <= t_cmd + FOLLOW_S and v[1] is not None and abs(v[1] - pitch) < 0.01
            ),
            None,
        )
        if hit is None:
            missing += 1
            continue
        lags.append(hit[0] - t_cmd)
        if pitch == -90.0:
            exact_90.append(hit[1][1])
    received = [t for t, _m in setpoints if t >= mark]
    span = (received[-1] - received[0]) if len(received) > 1 else 0.0
    # every distinct pitch PX4 sent the gimbal must become a servo setpoint (in order)
    pitches: list[float] = []
    for t, m in setpoints:
        if t < mark or any(math.isnan(x) for x in m.q):
            continue
        pitch = round(quaternion_to_euler(m.q)[1], 2)
        if not pitches or pitches[-1] != pitch:
            pitches.append(pitch)
    applied = [round(v[1], 2) for _t, v in calls if v[1] is not None]
    missed, j = 0, 0
    for pitch in pitches:
        k = j
        # a setpoint within the gimbal's apply deadband (0.05 deg) of the last is not re-sent
        while k < len(applied) and abs(applied[k] - pitch) > DEADBAND_DEG:
            k += 1
        if k == len(applied):
            missed += 1
            continue
        j = k + 1
    return {
        "commands": len(sent),
        "followed": len(lags),
        "not_followed": missing,
        "command_to_servo": ms(lags),
        "pitch_at_minus_90": sorted(set(round(p, 4) for p in exact_90)),
        "set_attitude_hz": round((len(received) - 1) / span, 1) if span else None,
        "px4_setpoints_distinct": len(pitches),
        "px4_setpoints_not_applied": missed,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--mirror-s", type=float, default=30.0)
    parser.add_argument("--gimbal-s", type=float, default=15.0)
    parser.add_argument("--flavour", default="px4", choices=("px4", "ardupilot", "auto"))
    parser.add_argument(
        "--no-stream-requests",
        dest="stream_requests",
        action="store_false",
        help="do not ask PX4 for rates (its onboard defaults: SERVO_OUTPUT_RAW 10 Hz, "
        "ACTUATOR_OUTPUT_STATUS none, GIMBAL_DEVICE_SET_ATTITUDE 5 Hz)",
    )
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    results = run(args)
    text = json.dumps(results, indent=1, default=str)
    print(text)
    if args.out is not None:
        args.out.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
