"""QGroundControl's ESC view: ESC_INFO and ESC_STATUS on the ESC numbers of ESC_TELEMETRY.

A running bridge with six servos (ESC 17..22 with ``esc_first_index: auto``) and a pymavlink
peer on UDP: every ESC_TELEMETRY group the bridge sends has its ESC_INFO and ESC_STATUS with
``index`` = first ESC - 1, carrying the same servos' values, decoded by a dialect pymavlink's
generator builds from MAVLink's common.xml (tests/support/wip_dialect.py); and the link budget,
which now plans for the two new streams, still holds.
"""

from __future__ import annotations

import time
from typing import Any

from mavservo.mavlink.bandwidth import EVENT_RESERVE
from mavservo.mavlink.esc_status import failure_flags
from mavservo.servos.base import Fault
from tests.support.bridge import Peer, running
from tests.support.waiting import wait_until
from tests.support.wip_dialect import decode

SIX = "\n".join(
    ["servos:"]
    + [f"  - {{name: s{i}, profile: rmd-x, can_id: {i}}}" for i in range(1, 7)]
    + ["channels:"]
    + [f"  - {{source: servo_output, channel: {i}, servo: s{i}}}" for i in range(1, 7)]
)


#: The peer plays the ground station and an ArduPilot on one link, as a router delivers both:
#: ArduPilot's own port would drop 290/291 (mavlink/link_carriage.py, issue 38 item 5).
ROUTER = "  autopilot: {link: router}\n"


def decoded(peer: Peer, kind: str, start: int = 0) -> list[Any]:
    out = []
    for m in peer.since(start, f"UNKNOWN_{kind}"):
        out.extend(x for x in decode(m.get_msgbuf()) if x.get_srcComponent() == 140)
    return out


def test_esc_info_and_status_cover_the_esc_telemetry_groups_with_the_same_values() -> None:
    with running(SIX, extra_mavlink="  link_budget_bytes_s: null\n" + ROUTER) as (_bridge, port):
        peer = Peer(port)
        try:
            peer.start_heartbeats()
            assert wait_until(
                lambda: (
                    {m.index for m in decoded(peer, "290")} == {16, 20}
                    and {m.index for m in decoded(peer, "291")} == {16, 20}
                ),
                15.0,
            )
            telemetry = {
                m.get_type(): m
                for m in peer.messages()
                if m.get_type().startswith("ESC_TELEMETRY_") and m.get_srcComponent() == 140
            }
            info = {m.index: m for m in decoded(peer, "290")}
            status = {m.index: m for m in decoded(peer, "291")}
        finally:
            peer.close()
    # the same ESC numbers: ESC_TELEMETRY_17_TO_20 <-> index 16, 21_TO_24 <-> index 20
    assert set(telemetry) == {"ESC_TELEMETRY_17_TO_20", "ESC_TELEMETRY_21_TO_24"}
    assert {m.count for m in info.values()} == {22}  # ESC numbers up to 22 are ours
    assert (info[16].info, info[20].info) == (0b1111, 0b0011)  # servos 5, 6 fill 21, 22
    assert {m.connection_type for m in info.values()} == {2}  # ESC_CONNECTION_TYPE_CAN
    for index, name in ((16, "ESC_TELEMETRY_17_TO_20"), (20, "ESC_TELEMETRY_21_TO_24")):
        esc = telemetry[name]
        filled = 4 if index == 16 else 2
        for slot in range(filled):
            # simulated servos report a voltage and a temperature: both views agree
            assert abs(status[index].voltage[slot] - esc.voltage[slot] / 100) <= 0.5
            assert abs(info[index].temperature[slot] / 100 - esc.temperature[slot]) <= 2
        for slot in range(filled, 4):
            assert info[index].temperature[slot] == 32767  # INT16_MAX: no ESC there
            assert esc.count[slot] == 0


def test_the_default_budget_still_holds_with_the_esc_view() -> None:
    with running(SIX, extra_mavlink=ROUTER) as (bridge, port):
        plan = bridge.mavlink.core.budget.plan
        assert plan.budget_bytes_s is not None
        assert {"ESC_STATUS", "ESC_INFO"} <= set(plan.ratios)
        assert plan.link_bytes_s <= plan.budget_bytes_s * (1 - EVENT_RESERVE) + 1e-6
        peer = Peer(port)
        try:
            peer.start_heartbeats()
            assert wait_until(lambda: len(peer.messages("UNKNOWN_291")) >= 1, 15.0)
            mark, started = peer.count(), time.monotonic()
            time.sleep(5.0)
            window = [m for m in peer.since(mark) if m.get_srcComponent() in (0, 140)]
            elapsed = time.monotonic() - started
        finally:
            peer.close()
    sent = sum(len(m.get_msgbuf()) for m in window)
    # ESC_STATUS (291) gets its turn in the window although it is larger than the many
    # NAMED_VALUE_FLOATs; ESC_INFO (290) is planned (its 1 Hz decimated to a few seconds per
    # group on this budget) and decoded in the test above
    assert any(m.get_type() == "UNKNOWN_291" for m in window)
    assert plan.ratios["ESC_INFO"] > 0
    assert sent / elapsed <= plan.budget_bytes_s


def test_servo_faults_map_to_esc_failure_flags() -> None:
    assert failure_flags(Fault(0)) == 0
    assert failure_flags(Fault.OVER_CURRENT | Fault.STALL) == 1 | 32
    assert failure_flags(Fault.OVER_TEMPERATURE) == 4
    assert failure_flags(Fault.ENCODER) == 64  # no bit of its own: generic
    assert failure_flags(Fault.NO_REPLY) == 0  # offline is ESC_INFO.info, not a failure
