"""Minimal reproduction: a broadcast (target component 0) command that concerns nothing the
bridge maps, with one parameter at +inf, draws a COMMAND_ACK DENIED from the gimbal component
(154); the same command without the inf draws none (docs/engineering/security.md: a broadcast that
concerns nothing the bridge maps gets no ACK, "two answers would confuse the sender").

Usage: python attack/a9b_broadcast_inf.py  (uses the sim.yaml gimbal, act_as_manager false)
"""

from __future__ import annotations

from harness import BridgeProc, collect, peer

INF = float("inf")


def main() -> None:
    bridge = BridgeProc("cfg_open.yaml", duration=8)
    bridge.wait_ready()
    gcs = peer(bridge.port)
    gcs.mav.heartbeat_send(6, 8, 0, 0, 4)
    cases = [
        ("MAV_CMD 4242 (unknown), all params 0", 4242, [0.0] * 7),
        ("MAV_CMD 4242 (unknown), param1 = inf", 4242, [INF] + [0.0] * 6),
        ("DO_SET_SERVO channel 7 (unmapped) 1500", 183, [7, 1500, 0, 0, 0, 0, 0]),
        ("DO_SET_SERVO channel 7 (unmapped) 1500, param3 = inf", 183, [7, 1500, INF, 0, 0, 0, 0]),
        ("MAV_CMD_NAV_TAKEOFF (22) param7 alt = inf", 22, [0, 0, 0, 0, 0, 0, INF]),
    ]
    for label, command, params in cases:
        collect(gcs, 0.05)
        gcs.mav.command_long_send(1, 0, command, 0, *params)
        acks = [(a.get_srcComponent(), a.result) for a in collect(gcs, 0.5, "COMMAND_ACK")]
        print(f"broadcast {label}: ACKs (component, result) = {acks}")
    bridge.finish()


if __name__ == "__main__":
    main()
