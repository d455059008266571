"""Differential driver (compare.py): seeded random lives of a ScheduleCore, one line per step,
wire feedback, reply, setpoint, release and query."""

import math
import random

from lives import print_lives

from mavservo.scheduling.schedule_core import ScheduleCore, ScheduleError, ServoSpec, TimingConfig
from mavservo.servos import get_profile

NAMES = ["rmd-x", "lk", "cubemars-ak", "cubemars-ak-mit", "damiao-dm", "odrive", "robstride"]


def fr(out):
    m = out.msg
    return (
        out.servo,
        out.kind,
        out.seq,
        getattr(out, "lifecycle", None),
        m.arbitration_id,
        bytes(m.data).hex(),
        len(out.expectations),
    )


def r6(x):
    if x is None:
        return None
    if isinstance(x, float) and not math.isfinite(x):
        return str(x)
    return round(x, 9)


def life(seed):
    rng = random.Random(seed)
    n = rng.randint(1, 4)
    specs = []
    for i in range(n):
        name = rng.choice(NAMES)
        cls = get_profile(name)
        prof = cls(i + 1, cls.Options())
        specs.append(
            ServoSpec(
                f"s{i}",
                prof,
                command_mode=rng.choice(["periodic", "immediate"]),
                telemetry_hz=rng.choice([None, 0, 5.0, 10.0, 50.0]),
            )
        )
    timing = TimingConfig(offline_after_missed=rng.choice([1, 2, 3]))
    out = []
    try:
        core = ScheduleCore(specs, timing, start=0.0)
    except ScheduleError as exc:
        return [("refused", str(exc))]
    now = 0.0
    core.anchor(now)
    keys = [None]
    pending = []
    for _ in range(400):
        now += rng.choice([0.0, 0.001, 0.005, 0.02, 0.05, 0.3])
        a = rng.random()
        name = f"s{rng.randrange(n)}"
        if a < 0.35:
            d = core.step(now)
            out.append(
                (
                    "step",
                    r6(now),
                    [fr(o) for o in d.frames],
                    r6(d.next_deadline),
                    r6(d.command_slot),
                    r6(d.telemetry_tick),
                    d.missed_slots,
                    d.lost,
                    d.went_offline,
                    [(s, p.seq) for s, p in d.dropped],
                    d.late_polls,
                    d.deferred_polls,
                )
            )
            pending.extend(d.frames)
        elif a < 0.55 and pending:
            o = pending.pop(0)
            for e in o.expectations:
                keys.append(e.key)
            if rng.random() < 0.85:
                out.append(("sent", fr(o), core.sent(o, now)))
            else:
                f = core.send_failed(o)
                out.append(
                    ("failed", fr(o), f.went_offline, None if f.dropped is None else f.dropped.seq)
                )
        elif a < 0.72:
            key = rng.choice(keys[-6:])
            m = core.on_reply(name, now, key, answer=rng.random() < 0.9)
            out.append(
                (
                    "reply",
                    name,
                    r6(now),
                    m.kind,
                    r6(m.t_tx),
                    r6(m.latency_s),
                    m.back_online,
                    r6(m.late_latency_s),
                )
            )
        elif a < 0.88:
            angle = rng.choice([0.0, 10.0, -5.5, 90.0, math.nan, 1e9])
            r = core.submit(
                name, angle, rng.choice(["mav", "failsafe"]), now - rng.choice([0, 0, 0.5])
            )
            out.append(("submit", name, r.accepted, r.seq, r.reason))
        elif a < 0.92:
            core.release(name)
            out.append(("release", name, core.wants_lifecycle_wake()))
        elif a < 0.94:
            core.mark_failsafe(name)
            lt = core.latest(name)
            out.append(("failsafe", name, None if lt is None else (lt.seq, lt.source)))
        else:
            out.append(
                (
                    "query",
                    [core.is_online(f"s{i}") for i in range(n)],
                    [core.wants_immediate_wake(f"s{i}") for i in range(n)],
                    r6(core.next_deadline(now)),
                    [r6(core.push_silence_limit_s(f"s{i}")) for i in range(n)],
                )
            )
    out.append(("final", [fr(o) for o in core.final_frames(now)]))
    return out


if __name__ == "__main__":
    print_lives(life)
