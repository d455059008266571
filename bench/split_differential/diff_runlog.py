"""Differential driver of the RunLog: seeded random observer events, then close; the text files
(trace, latency, rejections), the counters and the outcome printed."""

import json
import random
import tempfile
from pathlib import Path

import can
from lives import print_lives

from mavservo.records.runlog import RunLog
from mavservo.servos.base import Fault, ServoState


def life(seed):
    rng = random.Random(seed)
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        log = RunLog(
            tmp,
            formats=("asc",),
            buses={"b0": {"bitrate": 1000000}},
            servos={"s0": {}, "s1": {}},
            queue_size=rng.choice([5, 50, 5000]),
            autostart=rng.random() < 0.5,
            can_frames=rng.choice(["all", "servos"]),
            tlog=rng.random() < 0.5,
            max_run_bytes=rng.choice([10**9, 4000]),
        )
        t = 10.0
        seqs = {"s0": 0, "s1": 0}
        for _ in range(300):
            t += rng.choice([0.0, 0.001, 0.01, 0.05])
            servo = rng.choice(["s0", "s1", None])
            bus = rng.choice(["b0", "b1"])
            msg = can.Message(
                arbitration_id=rng.randrange(0x800),
                data=bytes(rng.randrange(256) for _ in range(rng.randint(0, 8))),
                is_extended_id=False,
            )
            a = rng.random()
            if a < 0.15 and servo:
                seqs[servo] += 1
                log.mavlink_received(servo, t - 0.001)
                log.on_setpoint(servo, seqs[servo], rng.uniform(-30, 30), "mav", t)
            elif a < 0.35 and servo:
                log.on_tx(
                    bus, msg, t, rng.choice(["command", "refresh", "request"]), servo, seqs[servo]
                )
                if rng.random() < 0.5:
                    log.on_written(bus, t, "command", servo, seqs[servo])
            elif a < 0.55:
                state = (
                    None
                    if rng.random() < 0.2
                    else ServoState(
                        position_deg=rng.uniform(-30, 30),
                        velocity_dps=1.0,
                        current_a=0.5,
                        temperature_c=30.0,
                        faults=rng.choice([Fault(0), Fault.NO_REPLY]),
                        timestamp=t,
                    )
                )
                log.on_rx(bus, msg, t, servo, state)
            elif a < 0.6:
                log.on_bus_frame(bus, msg, t)
            elif a < 0.65:
                log.on_lost(bus, servo, t)
            elif a < 0.7:
                log.on_reject(bus, rng.choice(["bad_crc", "truncated"]), b"\xaa\x55\x01", t)
            elif a < 0.75:
                log.health_event(
                    rng.choice(["s0", "s1"]), "jammed", rng.random() < 0.5, {"err": 1.5}, t
                )
            elif a < 0.8 and servo:
                log.telemetry_sent(servo, t)
            elif a < 0.9:
                log.mavlink_in(bytes(rng.randrange(256) for _ in range(10)), t)
            else:
                log.mavlink_out(bytes(rng.randrange(256) for _ in range(10)), t)
        log.close({"x": 1})
        out.append(("counters", repr(log.counters())))
        outcome = log.outcome()
        out.append(
            ("outcome", outcome.get("complete"), outcome.get("problems"), outcome.get("capped"))
        )
        d = Path(tmp)
        for name in sorted(p.name for p in d.iterdir()):
            if name.endswith(".log"):
                lines = (d / name).read_text().splitlines()
                out.append((name, [line.split(" ", 1)[1] for line in lines]))
            elif name.endswith(".tlog"):
                raw = (d / name).read_bytes()
                out.append((name, [raw[i + 8 : i + 18] for i in range(0, len(raw), 18)]))
            elif name.endswith(".csv"):
                out.append((name, (d / name).read_bytes()))
            elif name == "metrics.json":
                data = json.loads((d / name).read_text())
                data.get("run", {}).pop("duration_s", None)
                out.append(
                    (name, sorted(data.keys()), repr(data.get("latency")), repr(data.get("runlog")))
                )
            else:
                out.append((name,))
    return out


if __name__ == "__main__":
    print_lives(life)
