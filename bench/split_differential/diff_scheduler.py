"""Differential driver of the threaded Scheduler without its threads: the runner's and the
receiver's steps called in turn on a fake clock, a recording bus that sometimes refuses, the
simulated servos answering; every observer, subscriber, event, notice and the metrics printed."""

import math
import random

import can
from lives import print_lives

from mavservo.scheduling.runner import Scheduler, ServoSpec, TimingConfig
from mavservo.servos import get_profile
from mavservo.servos.dronecan.node import NodeOptions
from mavservo.sim.servo import SimServo

NEW = hasattr(Scheduler, "_run") and not hasattr(Scheduler, "_step")


class Clock:
    t = 100.0

    def __call__(self):
        return self.t


class RecBus(can.BusABC):
    def __init__(self, rng):
        self.rng = rng
        self.fail = 0.0
        self.sent = []
        self.channel_info = "rec"
        super().__init__(channel="rec")

    def send(self, msg, timeout=None):
        if self.rng.random() < self.fail:
            raise can.CanError("refused")
        self.sent.append(msg)

    def _recv_internal(self, timeout):
        return None, False


def m(msg):
    return (msg.arbitration_id, bytes(msg.data).hex(), msg.is_extended_id)


def st(state):
    if state is None:
        return None
    return (round(state.position_deg, 6), state.faults.value)


class Rec:
    def __init__(self, out, clock):
        self.out = out

    def on_setpoint(self, servo, seq, angle_deg, source, t):
        self.out.append(("setpoint", servo, seq, angle_deg, source, round(t, 9)))

    def on_tx(self, bus, msg, t, kind, servo, seq):
        self.out.append(("tx", bus, m(msg), round(t, 9), kind, servo, seq))

    def on_written(self, bus, t, kind, servo, seq):
        self.out.append(("written", bus, round(t, 9), kind, servo, seq))

    def on_rx(self, bus, msg, t, servo, state):
        self.out.append(("rx", bus, m(msg), round(t, 9), servo, st(state)))

    def on_lost(self, bus, servo, t):
        self.out.append(("lost", bus, servo, round(t, 9)))

    def on_reject(self, bus, reason, raw, t):
        self.out.append(("reject", bus, reason, raw.hex(), round(t, 9)))


def life(seed):
    rng = random.Random(seed)
    out = []
    clock = Clock()
    bus = RecBus(rng)
    import os

    family = os.environ.get("FAM") or rng.choice(
        ["rmd-x", "lk", "cubemars-ak", "damiao-dm", "odrive", "robstride", "dronecan"]
    )
    n = rng.randint(1, 3)
    specs, sims = [], []
    for i in range(n):
        cls = get_profile(family)
        opts = cls.Options() if family != "dronecan" else cls.Options(actuator_id=i + 1)
        can_id = i + 1 if family != "dronecan" else 10 + i
        specs.append(ServoSpec(f"s{i}", cls(can_id, opts), telemetry_hz=rng.choice([None, 5.0])))
        sims.append(SimServo(family, can_id, seed=seed, options=opts))
    if family == "dronecan":
        link = get_profile(family).link_sim_devices
        link([s._device for s in sims])
    node_options = {}
    if family == "dronecan":
        node_options = {
            "dronecan": NodeOptions(
                safety_state=rng.choice(["none", "safety_off"]),
                safety_on=rng.choice(["stop", "failsafe_and_stop", "never"]),
            )
        }
    timing = TimingConfig(command_period_s=0.02, telemetry_period_s=0.05, reply_timeout_s=0.03)
    rec = Rec(out, clock)
    sched = Scheduler(
        bus, specs, timing, clock=clock, observer=rec, name="b", node_options=node_options
    )
    sched.on_event = lambda text: out.append(("event", text))
    sched.subscribe(lambda servo, state: out.append(("state", servo, st(state))))
    with sched._lock:
        sched._core.anchor(clock.t)
    inbox = []  # (due, msg)
    for _ in range(300):
        clock.t += rng.choice([0.001, 0.005, 0.02, 0.02, 0.05])
        bus.fail = rng.choice([0.0, 0.0, 0.0, 0.3, 1.0]) if rng.random() < 0.1 else bus.fail
        a = rng.random()
        if a < 0.15:
            servo = f"s{rng.randrange(n)}"
            r = sched.set_setpoint(
                servo, rng.choice([0.0, 20.0, -15.0, math.nan]), rng.choice(["mav", "failsafe"])
            )
            out.append(("set", servo, r.accepted, r.seq))
        elif a < 0.18:
            servo = f"s{rng.randrange(n)}"
            sched.release(servo)
        elif a < 0.2:
            sched.mark_failsafe(f"s{rng.randrange(n)}")
        elif a < 0.22:
            out.append(("notices", sched.take_notices()))
        elif a < 0.23:
            sched.report_reject("bad_x", b"\xaa\x55")
        # the runner's turn
        before = len(bus.sent)
        if NEW:
            d = sched._writer.step()
            sched._writer.send_all(d)
            if sched._nodes:
                sched._writer.send_node_frames()
        else:
            d = sched._step()
            sched._send_all(d)
            if sched._nodes:
                sched._send_node_frames()
        silent = rng.random() < 0.1
        for msg in bus.sent[before:]:
            for sim in sims:
                if not silent:
                    for ready, reply in sim.receive(msg, clock.t):
                        inbox.append((ready + rng.choice([0.0, 0.002, 0.04]), reply))
        for sim in sims:
            if not silent:
                for ready, reply in sim.poll(clock.t):
                    inbox.append((ready, reply))
        if rng.random() < 0.05:  # a stranger's frame
            inbox.append(
                (
                    clock.t,
                    can.Message(
                        arbitration_id=rng.randrange(0x800),
                        data=bytes(rng.randrange(256) for _ in range(8)),
                        is_extended_id=False,
                    ),
                )
            )
        if family == "dronecan" and rng.random() < 0.25:
            from mavservo.servos.dronecan import wire

            kind = rng.randrange(4)
            src = rng.choice([5, 20, 100, 30, 31, 32, 33, 34, 35, 36, 37, 38, 39])
            tid = rng.randrange(32)
            if kind == 0:
                req = wire.lib().uavcan.protocol.GetNodeInfo.Request()
                frames = wire.encode_service(
                    req,
                    source=src,
                    destination=100,
                    transfer_id=tid,
                    request=True,
                    priority=rng.choice([wire.PRIORITY_LOW, wire.PRIORITY_HIGH]),
                )
            elif kind == 1:
                frames = wire.encode_message(
                    wire.array_command([(rng.choice([1, 2, 7]), 0, 0.25)]),
                    src,
                    tid,
                    wire.PRIORITY_HIGH,
                )
            elif kind == 2:
                frames = wire.encode_message(
                    wire.safety_state(rng.random() < 0.5), src, tid, wire.PRIORITY_LOW
                )
            else:
                frames = wire.encode_message(
                    wire.node_status(5.0, wire.HEALTH_OK, wire.MODE_OPERATIONAL),
                    src,
                    tid,
                    wire.PRIORITY_LOW,
                )
            for f in frames:
                inbox.append((clock.t, f))
        inbox.sort(key=lambda x: x[0])
        keep = []
        for due, msg in inbox:
            if due <= clock.t + 0.02:
                saved = clock.t
                clock.t = max(clock.t, due)
                sched.handle_frame(msg, clock.t)
                clock.t = saved if saved > clock.t else clock.t
            else:
                keep.append((due, msg))
        inbox = keep
        out.append(
            (
                "online",
                [sched.is_online(f"s{i}") for i in range(n)],
                [st(sched.state(f"s{i}")) for i in range(n)],
            )
        )
    if NEW:
        sched._writer.send_final_frames()
    else:
        sched._send_final_frames()
    met = sched.metrics()
    met["info"].pop("cpu", None)
    met["info"].pop("uptime_s", None)
    out.append(("metrics", repr(met)))
    out.append(("notices", sched.take_notices()))
    out.append(("node_states", repr(sched.node_states())))
    for node in sched.nodes:
        out.append(("node_stats", sorted(node.stats().items())))
    return out


if __name__ == "__main__":
    print_lives(life)
