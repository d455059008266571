"""Differential driver of the servo commands through the MAVLink core: random DO_SET_SERVO,
DO_REPEAT_SERVO, DO_SET_ACTUATOR (long and int, retries, broadcasts); ACKs and backend calls."""

import math
import random

from lives import norm, print_lives
from pymavlink.dialects.v20 import ardupilotmega as mav

from mavservo.mavlink import mavlink2
from tests.support.mavlink_doubles import make_mavlink_core, wire


def show(o):
    msg = o[-1] if isinstance(o, tuple) else getattr(o, "msg", o)
    try:
        d = msg.to_dict()
    except Exception:
        return repr(o)
    return (
        o[0] if isinstance(o, tuple) else None,
        msg.get_type(),
        {k: norm(v) for k, v in sorted(d.items())},
    )


def life(seed):
    rng = random.Random(seed)
    core, backend = make_mavlink_core(repeat_servo_cycle=rng.choice(["seconds", "milliseconds"]))
    out = []
    now = 0.0
    conf = 0
    for _ in range(200):
        now += rng.choice([0.0, 0.01, 0.05, 0.2, 1.0])
        cmd = rng.choice(
            [mav.MAV_CMD_DO_SET_SERVO, mav.MAV_CMD_DO_REPEAT_SERVO, mav.MAV_CMD_DO_SET_ACTUATOR]
        )
        vals = [
            0.0,
            1.0,
            2.0,
            3.0,
            5.0,
            1500.0,
            1900.0,
            400.0,
            0.5,
            -0.5,
            1.5,
            math.nan,
            math.inf,
            2.0**31 - 1,
            1e7,
            0.2,
            0.04,
        ]
        params = [rng.choice(vals) for _ in range(7)]
        target = rng.choice([(1, 1), (1, 0), (0, 0), (1, 154), (2, 1), (1, 191)])
        src = rng.choice([(255, 190), (1, 1), (3, 7)])
        if rng.random() < 0.3:
            conf += 1
        if rng.random() < 0.7:
            m = mavlink2.MAVLink_command_long_message(target[0], target[1], cmd, conf % 4, *params)
        else:
            ip = [
                max(-(2**31), min(2**31 - 1, int(p))) if math.isfinite(p) else 2**31 - 1
                for p in params[4:6]
            ]
            m = mavlink2.MAVLink_command_int_message(
                target[0],
                target[1],
                0,
                cmd,
                0,
                0,
                *(0.0 if not math.isfinite(p) else p for p in params[:4]),
                ip[0],
                ip[1],
                params[6] if math.isfinite(params[6]) else 0.0,
            )
        try:
            res = core.on_message(wire(m, src), now)
        except Exception as exc:
            res = [repr(exc)]
        out.append(("in", cmd, norm(params), target, src, [show(o) for o in res]))
        core.tick(now)
        out.append(("calls", [norm(list(c)) for c in backend.calls]))
        backend.calls.clear()
    out.append(
        (
            "stats",
            repr(
                sorted(core.stats().get("commands", {}).items())
                if isinstance(core.stats().get("commands"), dict)
                else core.stats().get("commands")
            ),
        )
    )
    return out


if __name__ == "__main__":
    print_lives(life)
