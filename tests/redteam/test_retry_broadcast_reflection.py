"""Red-team findings A, B and H (attack/README.md), end to end over UDP on 127.0.0.1.

The whole Bridge on config/sim.yaml's mapping and gimbal (payload_release driven by servo
channel 9 AND actuator 1; a gimbal as component 154), reached over a ``udpin:`` link:

* A: a change back after DO_SET_ACTUATOR on the same servo was taken for a retry of the
  earlier DO_SET_SERVO: ACKed ACCEPTED, not applied (``attack/a6_retry.py``);
* B: a broadcast command with a +-inf parameter that nothing on the bridge handles drew a
  DENIED ACK from the gimbal (``attack/a9b_broadcast_inf.py``);
* H: a keyless stranger replaying one of the bridge's own signed frames became a UDP
  destination (``attack/a13_reflect_own.py``).
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from typing import Any

import pytest
import yaml
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mavservo.app.bridge import Bridge
from mavservo.config.loader import load_config_text
from tests.redteam.test_bridge_security import KEY, Rig, acks
from tests.redteam.test_link_attacks import QUIET_S, drain, stranger
from tests.support.paths import REPO
from tests.support.waiting import free_udp_port, wait_until

os.environ.setdefault("MAVLINK20", "1")

GCS = (255, 190)
DO_SET_SERVO = 183
DO_SET_ACTUATOR = 187
NAV_TAKEOFF = 22
UNKNOWN_COMMAND = 4242
ACCEPTED = 0
NAN = math.nan
INF = math.inf


def sim_config_text(port: int, signing: bool) -> str:
    """config/sim.yaml on a ``udpin:`` port, system id 1, no autopilot watchdog, no monitor
    copies, no run directory."""
    raw = yaml.safe_load((REPO / "config" / "sim.yaml").read_text())
    mavlink = raw["mavlink"]
    mavlink.update(
        url=f"udpin:127.0.0.1:{port}",
        system_id=1,
        heartbeat_timeout_s=3600,
        monitor_outputs=[],
        signing={"key": KEY.hex()} if signing else None,
    )
    raw.pop("logging", None)
    return yaml.safe_dump(raw)


class SimRig(Rig):
    """:class:`tests.redteam.test_bridge_security.Rig` on config/sim.yaml's servos, mapping and
    gimbal."""

    def __init__(self, signing: bool = False) -> None:
        self.port = free_udp_port()
        self.bridge = Bridge(load_config_text(sim_config_text(self.port, signing)), log_dir=False)
        self.bridge.start()
        self.peers: list[Any] = []


@pytest.fixture
def sim_rig() -> Iterator[SimRig]:
    rig = SimRig()
    yield rig
    rig.close()


@pytest.fixture
def signed_sim_rig() -> Iterator[SimRig]:
    rig = SimRig(signing=True)
    yield rig
    rig.close()


def command(conn: Any, target: tuple[int, int], cmd: int, *params: float) -> None:
    values = (list(params) + [0.0] * 7)[:7]
    conn.mav.command_long_send(target[0], target[1], cmd, 0, *values)


# ---------------------------------------------------------------------- A


def test_a_change_back_after_do_set_actuator_on_the_same_servo_is_applied(
    sim_rig: SimRig,
) -> None:
    """DO_SET_SERVO(9, 1100), DO_SET_ACTUATOR(actuator 1 = +1), DO_SET_SERVO(9, 1100): both
    outputs drive payload_release, so the third is a change back, not a retry of the first.
    Sent back to back, well inside the 2 s retry window. Before the fix the third was ACKed
    ACCEPTED, counted as a retry, and the servo stayed at +1 (90 deg)."""
    gcs = sim_rig.peer(GCS)
    command(gcs, (1, 140), DO_SET_SERVO, 9, 1100)
    command(gcs, (1, 140), DO_SET_ACTUATOR, 1.0, NAN, NAN, NAN, NAN, NAN, 0)
    command(gcs, (1, 140), DO_SET_SERVO, 9, 1100)
    got = acks(gcs, DO_SET_SERVO, 3.0, QUIET_S)
    # an ACK still queued when the same command's identical ACK comes is sent once (issue 38:
    # a MAVLink ACK names only the command; a client's retry must not double the queue)
    assert got and all(a.result == ACCEPTED for a in got)
    assert sim_rig.stats()["commands"].get("retry_not_reapplied", 0) == 0
    assert sim_rig.setpoint("payload_release") == pytest.approx(0.0)


def test_an_identical_repeat_with_nothing_in_between_is_still_a_retry(sim_rig: SimRig) -> None:
    """Retry detection itself still works for a servo mapped from two sources."""
    gcs = sim_rig.peer(GCS)
    command(gcs, (1, 140), DO_SET_SERVO, 9, 1900)
    command(gcs, (1, 140), DO_SET_SERVO, 9, 1900)
    got = acks(gcs, DO_SET_SERVO, 2.0, QUIET_S)
    assert got and all(a.result == ACCEPTED for a in got)  # answered (once, if still queued)
    assert sim_rig.stats()["commands"]["retry_not_reapplied"] == 1


# ---------------------------------------------------------------------- B


@pytest.mark.parametrize(
    "cmd, params",
    [
        (UNKNOWN_COMMAND, (INF,)),
        (DO_SET_SERVO, (15, 1500, INF)),  # channel 15 is not mapped
        (NAV_TAKEOFF, (0, 0, 0, 0, 0, 0, INF)),
        (DO_SET_ACTUATOR, (NAN, NAN, NAN, NAN, NAN, -INF, 3)),  # set 3: actuators 19..24
    ],
    ids=["unknown", "unmapped-servo", "takeoff", "unmapped-actuators"],
)
def test_a_broadcast_nothing_here_handles_draws_no_ack_even_with_inf(
    sim_rig: SimRig, cmd: int, params: tuple[float, ...]
) -> None:
    """docs/engineering/security.md: a broadcast that concerns nothing the bridge maps gets no ACK
    (the autopilot answers it). Before the fix the gimbal's infinite-parameter guard DENIED it."""
    gcs = sim_rig.peer(GCS)
    command(gcs, (1, 0), cmd, *params)
    command(gcs, (1, 140), DO_SET_SERVO, 10, 1500)  # a marker: once ACKed, the first was handled
    # every ACK for the command (for DO_SET_SERVO: the marker's only) within 2 s
    assert [a.result for a in acks(gcs, DO_SET_SERVO, 2.0, QUIET_S)] == [ACCEPTED]
    if cmd != DO_SET_SERVO:
        assert acks(gcs, cmd, 0.3) == []
    commands = sim_rig.stats()["commands"]
    assert commands["ignored_not_ours"] == 1
    assert commands.get("result_denied", 0) == 0


def test_a_broadcast_gimbal_command_with_inf_is_still_denied_by_the_gimbal(
    sim_rig: SimRig,
) -> None:
    """The guard stays for what the gimbal handles: DO_MOUNT_CONTROL broadcast with an
    infinite mode is DENIED by 154, never handed to it."""
    gcs = sim_rig.peer(GCS)
    command(gcs, (1, 0), 205, 0, 0, 0, 0, 0, 0, INF)
    got = acks(gcs, 205, 2.0, QUIET_S)
    assert [(a.result, a.get_srcComponent()) for a in got] == [(2, 154)]


# ---------------------------------------------------------------------- H


def captured_bridge_frames(rig: SimRig, components: tuple[int, ...]) -> list[bytes]:
    """Signed HEARTBEATs of the bridge's own components, as a legitimate peer received them."""
    gcs = rig.peer(GCS, key=KEY)
    frames: dict[int, bytes] = {}
    for _ in range(200):
        msg = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=0.1)
        if msg is not None and msg.get_srcComponent() in components:
            frames[msg.get_srcComponent()] = bytes(msg.get_msgbuf())
        if len(frames) == len(components):
            break
    return list(frames.values())


def test_a_replayed_own_frame_does_not_make_a_stranger_a_destination(
    signed_sim_rig: SimRig,
) -> None:
    """A stranger without the key sends one captured, correctly signed bridge HEARTBEAT (from
    140 and from 154) from its own address: nothing comes back, the frames are counted as
    claiming our identity. Before the fix each stranger got the whole output stream."""
    rig = signed_sim_rig
    frames = captured_bridge_frames(rig, (140, 154))
    assert len(frames) == 2
    strangers = [stranger() for _ in frames]
    try:
        for sock, frame in zip(strangers, frames, strict=True):
            sock.sendto(frame, ("127.0.0.1", rig.port))
        assert wait_until(lambda: rig.stats()["link"].get("own_identity", 0) >= 2)
        back = [drain(sock, 1.5 if i == 0 else 0.1) for i, sock in enumerate(strangers)]
    finally:
        for sock in strangers:
            sock.close()
    assert back == [0, 0]
    assert rig.stats()["link"]["own_identity"] == 2


def test_a_frame_claiming_our_identity_never_reaches_the_core(sim_rig: SimRig) -> None:
    """Signing off: a datagram claiming to come from 1/140 is dropped at the link, counted,
    and its sender is not answered."""
    impostor = stranger()
    try:
        encoder = mavlink2.MAVLink(None, srcSystem=1, srcComponent=140)
        frame = encoder.heartbeat_encode(33, 8, 0, 0, 4).pack(encoder)
        received_before = sim_rig.stats()["link"].get("received", 0)
        impostor.sendto(frame, ("127.0.0.1", sim_rig.port))
        assert wait_until(lambda: sim_rig.stats()["link"].get("own_identity", 0) == 1)
        assert drain(impostor, 1.0) == 0
    finally:
        impostor.close()
    assert sim_rig.stats()["link"].get("received", 0) == received_before
