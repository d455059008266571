"""Promise 6: DO_SET_SERVO 1100, 1900, 1100 us on one channel 0.5 s apart (confirmation 0): all
three applied; then attempts to confuse the retry detector.

Reads the bridge's own view from outside: COMMAND_ACKs, and ACTUATOR_OUTPUT_STATUS /
NAMED_VALUE_FLOAT s<n>_pos would be indirect, so the decisive evidence is the CAN log
(can.asc) of the run: the position commands the bridge sent to servo can_id 9 (payload_release,
an LK servo driven by DO_SET_SERVO channel 9 AND by actuator 1 in config/sim.yaml).

Usage: python attack/a6_retry.py
"""

from __future__ import annotations

import time

from harness import BridgeProc, collect, peer

DO_SET_SERVO = 183
DO_SET_ACTUATOR = 187


def setpoints(bridge: BridgeProc) -> list[tuple[float, str]]:
    """(time, setpoint) of payload_release from the run's trace.csv (the bridge's decisions)."""
    rows = (bridge.run_dir() / "trace.csv").read_text().splitlines()
    return rows


def ack_results(conn, seconds=0.4):
    return [(m.command, m.result) for m in collect(conn, seconds, "COMMAND_ACK")]


def main() -> None:
    bridge = BridgeProc("cfg_open.yaml", duration=16, verbose=True)
    bridge.wait_ready()
    gcs = peer(bridge.port)
    gcs.mav.heartbeat_send(6, 8, 0, 0, 4)
    time.sleep(0.3)
    t0 = time.monotonic()
    log = []

    def step(label, fn):
        collect(gcs, 0.05)  # drain what queued up (a full client buffer drops the ACK)
        fn()
        acks = ack_results(gcs, 0.5)
        log.append((round(time.monotonic() - t0, 2), label, acks))

    # 1: the promise as stated
    for pwm in (1100, 1900, 1100):
        step(
            f"DO_SET_SERVO ch9 {pwm} conf0",
            lambda pwm=pwm: gcs.mav.command_long_send(
                1, 140, DO_SET_SERVO, 0, 9, pwm, 0, 0, 0, 0, 0
            ),
        )
    time.sleep(2.5)
    # 2: same physical servo via DO_SET_ACTUATOR in between (actuator 1 = payload_release)
    step(
        "DO_SET_SERVO ch9 1100 conf0",
        lambda: gcs.mav.command_long_send(1, 140, DO_SET_SERVO, 0, 9, 1100, 0, 0, 0, 0, 0),
    )
    step(
        "DO_SET_ACTUATOR act1 +1.0",
        lambda: gcs.mav.command_long_send(
            1,
            140,
            DO_SET_ACTUATOR,
            0,
            1.0,
            float("nan"),
            float("nan"),
            float("nan"),
            float("nan"),
            float("nan"),
            0,
        ),
    )
    step(
        "DO_SET_SERVO ch9 1100 conf0 (change back after the actuator command)",
        lambda: gcs.mav.command_long_send(1, 140, DO_SET_SERVO, 0, 9, 1100, 0, 0, 0, 0, 0),
    )
    time.sleep(2.5)
    # 3: COMMAND_INT twin of a COMMAND_LONG (same command, other message type)
    step(
        "COMMAND_LONG ch10 1100",
        lambda: gcs.mav.command_long_send(1, 140, DO_SET_SERVO, 0, 10, 1100, 0, 0, 0, 0, 0),
    )
    step(
        "COMMAND_INT ch10 1900",
        lambda: gcs.mav.command_int_send(1, 140, 0, DO_SET_SERVO, 0, 0, 10, 1900, 0, 0, 0, 0, 0),
    )
    step(
        "COMMAND_LONG ch10 1100 (change back)",
        lambda: gcs.mav.command_long_send(1, 140, DO_SET_SERVO, 0, 10, 1100, 0, 0, 0, 0, 0),
    )
    time.sleep(2.5)
    # 4: other sender moves the channel in between
    other = peer(bridge.port, source=(254, 190))
    other.mav.heartbeat_send(6, 8, 0, 0, 4)
    step(
        "GCS ch10 1900",
        lambda: gcs.mav.command_long_send(1, 140, DO_SET_SERVO, 0, 10, 1900, 0, 0, 0, 0, 0),
    )
    step(
        "OTHER ch10 1100",
        lambda: other.mav.command_long_send(1, 140, DO_SET_SERVO, 0, 10, 1100, 0, 0, 0, 0, 0),
    )
    step(
        "GCS ch10 1900 (change back)",
        lambda: gcs.mav.command_long_send(1, 140, DO_SET_SERVO, 0, 10, 1900, 0, 0, 0, 0, 0),
    )
    # 5: confirmation games: a real retry (conf 1) must not be re-applied, conf 0 repeat within
    # window is a retry by design
    step(
        "GCS ch10 1900 conf1 (retry)",
        lambda: gcs.mav.command_long_send(1, 140, DO_SET_SERVO, 1, 10, 1900, 0, 0, 0, 0, 0),
    )
    rc = bridge.finish()
    for row in log:
        print(row)
    for ln in bridge.log_lines():
        if "retry" in ln or "command" in ln:
            print("LOG:", ln)
    stats = bridge.mavlink_stats()
    print("commands:", stats["commands"])
    print("exit", rc)
    # the bridge's decisions on payload_release / tow_hook from trace.csv
    rows = setpoints(bridge)
    print(rows[0])
    for r in rows[1:]:
        if ("payload_release" in r or "tow_hook" in r) and ",state," not in r:
            print(r)


if __name__ == "__main__":
    main()
