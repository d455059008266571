"""Hostile parameter values in every command the command handler dispatches (finding 9, the
command handler's part): exactly one COMMAND_ACK per addressed command, never an exception, and
a bad value is DENIED and counted.

The property runs over the whole parameter space hypothesis can reach, with the values that
broke handlers before pinned in: NaN, +-inf, 3.4e38 (float32 max), 1e9, and values whose int
conversion overflows a message field. Gimbal commands go through the real gimbal device; what
the gimbal does with a value is its own module's business, but whatever it does (even raise),
the sender gets its one ACK from here.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mavservo.mavlink.gimbal import GimbalDevice, GimbalSettings
from mavservo.mavlink.mavlink_core import MavlinkCore
from mavservo.mavlink.settings import MavlinkSettings
from tests.support.mavlink_doubles import (
    RecordingBackend,
    command_int,
    command_long,
    make_mavlink_core,
    wire,
)

GCS = (255, 190)
SERVO = 140
DENIED = 2
INT32 = 2**31 - 1

HOSTILE = [math.nan, math.inf, -math.inf, 3.4e38, -3.4e38, 1e9, -1e9, 2.0**63, 2.0**24, -1.0]
#: What the handler dispatches itself, the gimbal's commands, and ids nobody handles.
COMMANDS = [183, 184, 187, 511, 512, 205, 1000, 1001, 204, 176, 0, 400, 65535]

params = st.one_of(
    st.sampled_from(HOSTILE + [0.0, 1.0, 9.0, 375.0, 1500.0, 0.5]),
    st.floats(width=32, allow_nan=True, allow_infinity=True),
)
int32s = st.one_of(st.sampled_from([INT32, -INT32 - 1, 0, 1]), st.integers(-INT32 - 1, INT32))


def make_core() -> tuple[MavlinkCore, int]:
    gimbal = GimbalDevice(
        GimbalSettings(name="g", axis_servos={"pitch": "aileron"}, limits_deg={"pitch": (-90, 30)}),
        RecordingBackend(),
    )
    core, _ = make_mavlink_core(gimbals=(gimbal,))
    return core, gimbal.component_id


def ack_results(out) -> list[int]:
    return [m.result for _, m in out if m.get_type() == "COMMAND_ACK"]


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    command=st.sampled_from(COMMANDS),
    values=st.lists(params, min_size=7, max_size=7),
    xy=st.tuples(int32s, int32s),
    as_int=st.booleans(),
    to_gimbal=st.booleans(),
    confirmation=st.integers(0, 255),
)
def test_every_addressed_command_gets_exactly_one_ack_whatever_its_values(
    command, values, xy, as_int, to_gimbal, confirmation
):
    core, gimbal_id = make_core()
    target = (1, gimbal_id if to_gimbal else SERVO)
    if as_int:
        p1, p2, p3, p4, _, _, z = values
        msg = command_int(target, command, p1, p2, p3, p4, xy[0], xy[1], z)
    else:
        msg = command_long(target, command, *values, confirmation=confirmation)
    for now in (10.0, 10.1):  # the first time, and again as a retry
        out = core.on_message(wire(msg, GCS), now)
        assert len(ack_results(out)) == 1, out
    if not to_gimbal:  # what the gimbal does with a finite value is the gimbal's own business
        assert core.commands.counters.get("handler_error", 0) == 0


@settings(max_examples=200, deadline=None)
@given(command=st.sampled_from(COMMANDS), values=st.lists(params, min_size=7, max_size=7))
def test_a_broadcast_gets_at_most_one_ack_whatever_its_values(command, values):
    core, _ = make_core()
    out = core.on_message(wire(command_long((1, 0), command, *values), GCS), 10.0)
    assert len(ack_results(out)) <= 1


@pytest.mark.parametrize(
    "command, values",
    [
        (183, (1, math.inf)),
        (183, (1, 3.4e38)),
        (183, (3.4e38, 1500)),
        (184, (9, 1900, 1e9, 1)),
        (184, (9, 1900, 3, math.inf)),
        (187, (math.inf, math.nan, math.nan, math.nan, math.nan, math.nan, 0)),
        (187, (0.5, 0, 0, 0, 0, 0, 3.4e38)),
        (512, (3.4e38,)),  # not a message id: MAVLink 2 ids are 24-bit
        (512, (2.0**24,)),
        (511, (2.0**24, 1000)),
        (511, (375, 3.4e38)),  # an interval MESSAGE_INTERVAL cannot carry (int32 us)
        (511, (375, math.inf)),
        (511, (375, -2)),
        (205, (0, 0, 0, 0, 0, 0, math.inf)),  # to the gimbal: the generic guard
        (1000, (-math.inf, 0)),
    ],
)
def test_bad_values_are_denied_and_counted(command, values):
    core, gimbal_id = make_core()
    target = (1, gimbal_id if command in (205, 1000) else SERVO)
    out = core.on_message(wire(command_long(target, command, *values), GCS), 10.0)
    assert ack_results(out) == [DENIED]
    assert (
        core.commands.counters["reason_bad_param"] + core.commands.counters["reason_unmapped"] == 1
    )


class RaisingGimbal:
    """A hosted component whose handlers raise (a bug, a value nobody foresaw)."""

    component_id = 154

    def handle_command(self, command, params, now, *, sender=None):
        raise OverflowError("cannot convert float infinity to integer")

    def handle_message(self, msg, now) -> None:
        return None

    def periodic(self, now):
        return []

    def requested_message(self, msg_id, now):
        raise ValueError("bad message id")


@pytest.mark.parametrize("command, values", [(1000, (10.0, 5.0)), (512, (285,))])
def test_a_handler_that_raises_costs_a_denied_ack_and_a_count_not_the_ack(command, values):
    core = MavlinkCore(MavlinkSettings(system_id=1), RecordingBackend(), gimbals=[RaisingGimbal()])
    for now in (10.0, 11.0):
        out = core.on_message(wire(command_long((1, 154), command, *values), GCS), now)
        assert [(cid, r) for cid, m in out for r in ack_results([(cid, m)])] == [(154, DENIED)]
    assert core.commands.counters["handler_error"] == 1  # the second one is a retry
