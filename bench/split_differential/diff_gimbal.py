"""Differential driver of GimbalDevice: seeded random MAVLink inputs, commands, ticks and
PARAM_SET-style settings replacements; every result, backend call and message printed."""

import dataclasses
import math
import random

from lives import norm, print_lives
from pymavlink.dialects.v20 import ardupilotmega as mav

from mavservo.mavlink import mavlink2
from mavservo.mavlink.gimbal import GimbalDevice, GimbalSettings
from tests.support.mavlink_doubles import RecordingBackend, state, wire


def msgdict(msg):
    d = msg.to_dict()
    return {k: norm(v) for k, v in sorted(d.items())}


def rq(rng):
    c = rng.random()
    if c < 0.15:
        return [math.nan] * 4
    if c < 0.3:
        return [1.0, 0.0, 0.0, 0.0]
    q = [rng.uniform(-1, 1) for _ in range(4)]
    n = math.sqrt(sum(x * x for x in q)) or 1.0
    return [x / n for x in q]


def life(seed):
    rng = random.Random(seed)
    out = []
    backend = RecordingBackend()
    manager = rng.random() < 0.6
    settings = GimbalSettings(
        name="g",
        axis_servos={"pitch": "aileron", "yaw": "drop"}
        if rng.random() < 0.5
        else {"roll": "flap", "pitch": "aileron", "yaw": "drop"},
        limits_deg={"pitch": (-90.0, 30.0), "yaw": (-120.0, 120.0), "roll": (-20.0, 20.0)},
        act_as_manager=manager,
        system_id=rng.choice([None, 1]),
        retract_pose_deg=rng.choice([None, (0.0, -90.0, 0.0)]),
    )
    dev = GimbalDevice(settings, backend, boot_time=0.0)
    now = 0.0
    flags_choices = [0, 1, 2, 4, 8, 16, 32, 64, 16 | 32, 0x1000]
    for _ in range(250):
        now += rng.choice([0.0, 0.005, 0.02, 0.1, 0.3])
        a = rng.random()
        src = rng.choice([(1, 1), (255, 190), (2, 1), (1, 0)])
        if a < 0.25:
            m = mavlink2.MAVLink_gimbal_device_set_attitude_message(
                rng.choice([0, 1, 2]),
                rng.choice([0, 154, 155]),
                rng.choice(flags_choices),
                rq(rng),
                *(rng.choice([math.nan, 0.1, -0.5, math.inf]) for _ in range(3)),
            )
            dev.handle_message(wire(m, src), now)
        elif a < 0.4:
            m = mavlink2.MAVLink_gimbal_manager_set_attitude_message(
                rng.choice([0, 1]),
                rng.choice([0, 154]),
                rng.choice(flags_choices),
                rng.choice([0, 154, 1]),
                rq(rng),
                *(rng.choice([math.nan, 0.2]) for _ in range(3)),
            )
            dev.handle_message(wire(m, src), now)
        elif a < 0.48:
            m = mavlink2.MAVLink_attitude_message(
                0, 0.0, 0.0, rng.choice([0.5, -2.0, math.nan, 1e9]), 0, 0, 0
            )
            dev.handle_message(wire(m, src), now)
        elif a < 0.52:
            m = mavlink2.MAVLink_autopilot_state_for_gimbal_device_message(
                1, 154, 0, rq(rng), 0, 0, 0, 0, 0, 0.0, 0, 0, 0.0
            )
            dev.handle_message(wire(m, src), now)
        elif a < 0.7:
            cmd = rng.choice(
                [
                    mav.MAV_CMD_DO_MOUNT_CONTROL,
                    mav.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
                    mav.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE,
                    12345,
                ]
            )
            params = tuple(
                rng.choice(
                    [math.nan, 0.0, 10.0, -45.0, 200.0, 154.0, -1.0, -2.0, 2.0, 1.0, 3.0, 16.0]
                )
                for _ in range(7)
            )
            r = dev.handle_command(cmd, params, now, sender=rng.choice([None, src]))
            out.append(("cmd", cmd, norm(params), r))
        elif a < 0.75:
            new = dataclasses.replace(
                dev.settings,
                limits_deg={
                    "pitch": (rng.choice([-90.0, -30.0]), rng.choice([0.0, 30.0])),
                    "yaw": (rng.choice([-120.0, -10.0]), rng.choice([10.0, 120.0])),
                    "roll": (-20.0, 20.0),
                },
                status_rate_hz=rng.choice([10.0, 5.0, 50.0]),
            )
            dev.settings = new
            out.append(("settings", sorted(new.limits_deg.items()), new.status_rate_hz))
        elif a < 0.8:
            name = rng.choice(["aileron", "drop", "flap"])
            if rng.random() < 0.3:
                backend.offline ^= {name}
            else:
                backend.states[name] = state(rng.uniform(-30, 30))
        elif a < 0.85:
            mid = rng.choice([280, 285, 281, 283, 0])
            r = dev.requested_message(mid, now)
            out.append(
                (
                    "req",
                    mid,
                    dev.supports_message(mid),
                    None if r is None else (r.get_type(), msgdict(r)),
                )
            )
        msgs = dev.periodic(now)
        out.append(("tick", round(now, 6), [(x.get_type(), msgdict(x)) for x in msgs]))
        out.append(("calls", [norm(list(c)) for c in backend.calls]))
        backend.calls.clear()
        out.append(("counters", sorted(dev.counter_values().items())))
    return out


if __name__ == "__main__":
    print_lives(life)
