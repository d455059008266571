"""Promises 7/8 (partial): adapter unplugged while a slew-limited servo (sim.yaml aileron,
channel 1, 200 deg/s) and the gimbal are being commanded over UDP. In-process Bridge (the
emulator's unplug() needs the object), real UDP peers on 127.0.0.1. Checks that the bridge
keeps sending heartbeats and ACKs through the outage and that a refused gimbal demand is not
carried out after the replug.

Usage: python attack/a7_unplug.py [rounds]
"""

from __future__ import annotations

import sys
import time

from harness import HERE, collect, free_port, peer

from mavservo.app.bridge import Bridge
from mavservo.config.loader import load_config_text


def main() -> None:
    rounds = int(sys.argv[1]) if len(sys.argv) > 1 else 5
    port = free_port()
    text = (
        (HERE / "cfg_open.yaml").read_text().replace("url: sim ", f"url: udpin:127.0.0.1:{port} ")
    )
    bridge = Bridge(load_config_text(text), log_dir=False)
    bridge.start()
    try:
        gcs = peer(port)
        gcs.mav.heartbeat_send(6, 8, 0, 0, 4)
        time.sleep(1.0)
        emulator = bridge.emulators["bus0"]
        for r in range(rounds):
            for i in range(20):
                gcs.mav.command_long_send(1, 140, 183, 0, 1, 1100 + (i % 2) * 800, 0, 0, 0, 0, 0)
                gcs.mav.command_long_send(1, 154, 205, 0, -40 + i, 0, 0, 0, 0, 0, 2)
                collect(gcs, 0.01)
            emulator.unplug()
            results = []
            for i in range(40):
                gcs.mav.command_long_send(1, 140, 183, 0, 1, 1100 + (i % 2) * 800, 0, 0, 0, 0, 0)
                gcs.mav.command_long_send(1, 154, 205, 0, -60 + i % 10, 0, 0, 0, 0, 0, 2)
                results += [(a.command, a.result) for a in collect(gcs, 0.05, "COMMAND_ACK")]
            hb = [m for m in collect(gcs, 1.5, "HEARTBEAT") if m.get_srcComponent() == 140]
            emulator.replug()
            time.sleep(2.0)
            hb2 = [m for m in collect(gcs, 1.5, "HEARTBEAT") if m.get_srcComponent() == 140]
            print(
                f"round {r}: ACKs during outage {len(results)} "
                f"(results {sorted(set(results))}); heartbeats from 140 in 1.5 s: during "
                f"outage {len(hb)}, after replug {len(hb2)}"
            )
            if not hb2:
                print("HANG: no heartbeat after replug")
                import faulthandler

                faulthandler.dump_traceback(all_threads=True)
                break
    finally:
        stop_deadline = time.monotonic()
        import threading

        t = threading.Thread(target=bridge.stop, daemon=True)
        t.start()
        t.join(10)
        print("bridge.stop returned:", not t.is_alive(), f"{time.monotonic() - stop_deadline:.1f}s")
        if t.is_alive():
            import os

            os._exit(3)


if __name__ == "__main__":
    main()
