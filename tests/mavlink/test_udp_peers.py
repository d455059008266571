"""End to end over real pymavlink UDP connections on 127.0.0.1: a scripted autopilot and a GCS
talk to a running MavlinkSide backed by the recording backend double."""

from __future__ import annotations

import os

os.environ.setdefault("MAVLINK20", "1")

import pytest  # noqa: E402
from pymavlink import mavutil  # noqa: E402

from mavservo.mavlink.gimbal import GimbalDevice, GimbalSettings  # noqa: E402
from mavservo.mavlink.settings import MavlinkSettings, SigningSettings, TelemetryRates  # noqa: E402
from mavservo.mavlink.side import MavlinkSide  # noqa: E402
from tests.support.mavlink_doubles import RecordingBackend, state  # noqa: E402
from tests.support.waiting import free_udp_port, wait_for_message, wait_until  # noqa: E402

KEY = bytes(range(32))
WAIT_S = 3.0


def peer(port: int, system: int, component: int):
    conn = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{port}",
        source_system=system,
        source_component=component,
        dialect="ardupilotmega",
    )
    return conn


def is_ack(command):
    return lambda m: m.get_type() == "COMMAND_ACK" and m.command == command


@pytest.fixture
def bridge(request):
    overrides = getattr(request, "param", {})
    port = free_udp_port()
    backend = RecordingBackend()
    gimbal = GimbalDevice(
        GimbalSettings(
            name="gimbal", axis_servos={"pitch": "aileron"}, limits_deg={"pitch": (-90.0, 30.0)}
        ),
        backend,
    )
    settings = MavlinkSettings(
        url=f"udpin:127.0.0.1:{port}",
        system_id="follow",
        heartbeat_timeout_s=1.0,
        channel_trims_us={9: 1500.0},
        telemetry=TelemetryRates(esc_first_index=1),  # servo n is ESC n here
        **overrides,
    )
    side = MavlinkSide(settings, backend, gimbals=[gimbal])
    side.start()
    autopilot, gcs = peer(port, 1, 1), peer(port, 255, 190)
    yield side, backend, autopilot, gcs
    side.stop()
    autopilot.close()
    gcs.close()


def introduce(autopilot, gcs):
    """Make both peers known to the udpin side (it answers only to those that spoke)."""
    autopilot.mav.heartbeat_send(1, 3, 0, 0, 4)
    gcs.mav.heartbeat_send(6, 8, 0, 0, 4)


def test_commands_acks_retries_and_mirroring_over_udp(bridge):
    side, backend, autopilot, gcs = bridge
    introduce(autopilot, gcs)
    assert wait_until(lambda: side.stats()["system_id"] == 1)
    for pwm in (1500, 1500, 1600):
        autopilot.mav.servo_output_raw_send(0, 0, pwm, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)
    assert wait_until(lambda: len(backend.servo_calls()) == 2)
    assert [c[2] for c in backend.servo_calls()] == [1500.0, 1600.0]

    gcs.mav.command_long_send(1, 140, 183, 0, 9, 1100, 0, 0, 0, 0, 0)
    ack = wait_for_message(gcs, is_ack(183))
    assert ack is not None and ack.result == 0
    assert (ack.get_srcSystem(), ack.get_srcComponent()) == (1, 140)
    gcs.mav.command_long_send(1, 140, 183, 1, 9, 1100, 0, 0, 0, 0, 0)  # retry
    again = wait_for_message(gcs, is_ack(183))
    assert again is not None and again.result == 0
    assert [c for c in backend.servo_calls() if c[3] == "do_set_servo"] == [
        ("servo", 9, 1100.0, "do_set_servo")
    ]

    gcs.mav.command_long_send(
        1, 0, 187, 0, -0.5, float("nan"), float("nan"), float("nan"), float("nan"), float("nan"), 0
    )
    ack = wait_for_message(gcs, is_ack(187))
    assert ack is not None and ack.result == 0 and ack.get_srcComponent() == 140
    assert backend.servo_calls("actuator") == [("actuator", 1, -0.5, "do_set_actuator")]

    gcs.mav.command_int_send(1, 140, 0, 183, 0, 0, 3, 1500, 0, 0, 0, 0, 0)  # unmapped
    ack = wait_for_message(gcs, is_ack(183))
    assert ack is not None and ack.result == 2
    assert side.stats()["commands"]["reason_unmapped"] == 1


def test_telemetry_heartbeats_and_components_over_udp(bridge):
    side, backend, autopilot, gcs = bridge
    backend.states["aileron"] = state(12.0, velocity=60.0, current=0.5, temperature=35)
    introduce(autopilot, gcs)
    seen: list = []
    wait_for_message(gcs, lambda m: False, timeout=2.2, keep=seen)
    beats = {
        (m.get_srcComponent(), m.type)
        for m in seen
        if m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 1 and m.get_srcComponent() != 1
    }
    assert beats == {(140, 33), (154, 26)}
    aos = [m for m in seen if m.get_type() == "ACTUATOR_OUTPUT_STATUS"]
    # configured 10 Hz over ~2 s: generous bounds, not a timing threshold
    assert 5 <= len(aos) <= 40
    assert aos[-1].actuator[0] == pytest.approx(0.4)
    named = {m.name: m.value for m in seen if m.get_type() == "NAMED_VALUE_FLOAT"}
    assert named["s1_pos"] == pytest.approx(12.0)
    esc = [m for m in seen if m.get_type() == "ESC_TELEMETRY_1_TO_4"]
    assert esc and esc[-1].rpm[0] == 10 and esc[-1].temperature[0] == 35
    status = [m for m in seen if m.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS"]
    assert status and all(m.get_srcComponent() == 154 for m in status)
    # each component keeps its own sequence numbers: consecutive per component
    # (ESC_INFO/ESC_STATUS reach pymavlink's bundled dialect as UNKNOWN_29x with an empty
    # header: their sequence number and source are read from the frame, bytes 4..6)
    headers = [
        (m.get_msgbuf()[4], m.get_msgbuf()[5], m.get_msgbuf()[6])
        if m.get_type().startswith("UNKNOWN_")
        else (m.get_seq(), m.get_srcSystem(), m.get_srcComponent())
        for m in seen
    ]
    for cid in (140, 154):
        seqs = [seq for seq, system, comp in headers if comp == cid and system == 1]
        assert len(seqs) >= 2
        assert all((b - a) % 256 == 1 for a, b in zip(seqs, seqs[1:], strict=False))


def test_request_message_routed_to_gimbal_and_servo_components(bridge):
    side, backend, autopilot, gcs = bridge
    introduce(autopilot, gcs)
    assert wait_until(lambda: side.stats()["system_id"] == 1)
    gcs.mav.command_long_send(1, 154, 512, 0, 283, 0, 0, 0, 0, 0, 0)
    kept: list = []
    ack = wait_for_message(gcs, is_ack(512), keep=kept)
    assert ack is not None and ack.result == 0 and ack.get_srcComponent() == 154
    assert wait_for_message(gcs, lambda m: m.get_type() == "GIMBAL_DEVICE_INFORMATION", keep=kept)
    gcs.mav.command_long_send(1, 154, 512, 0, 280, 0, 0, 0, 0, 0, 0)  # manager info: not ours
    ack = wait_for_message(gcs, is_ack(512))
    assert ack is not None and ack.result == 3
    gcs.mav.command_long_send(1, 140, 511, 0, 11030, 1_000_000, 0, 0, 0, 0, 0)
    ack = wait_for_message(gcs, is_ack(511))
    assert ack is not None and ack.result == 0 and ack.get_srcComponent() == 140
    gcs.mav.command_long_send(1, 154, 512, 0, 0, 0, 0, 0, 0, 0, 0)  # HEARTBEAT, from the gimbal
    kept = []
    ack = wait_for_message(gcs, is_ack(512), keep=kept)
    assert ack is not None and ack.result == 0 and ack.get_srcComponent() == 154
    beat = wait_for_message(
        gcs, lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 154
    )
    assert beat is not None and beat.type == 26


def test_failsafe_on_autopilot_heartbeat_loss_and_recovery(bridge):
    side, backend, autopilot, gcs = bridge
    introduce(autopilot, gcs)
    texts: list = []
    lost = wait_for_message(
        gcs,
        lambda m: m.get_type() == "STATUSTEXT" and "failsafe" in m.text,
        timeout=4.0,
        keep=texts,
    )
    assert lost is not None and lost.get_srcComponent() == 140
    assert backend.failsafe_events == ["enter"]
    autopilot.mav.heartbeat_send(1, 3, 0, 0, 4)
    back = wait_for_message(gcs, lambda m: m.get_type() == "STATUSTEXT" and "back" in m.text)
    assert back is not None
    assert backend.failsafe_events == ["enter", "leave"]


@pytest.mark.parametrize("bridge", [{"signing": SigningSettings(KEY)}], indirect=True)
def test_signing_rejects_unsigned_and_accepts_signed(bridge):
    side, backend, autopilot, gcs = bridge
    autopilot.setup_signing(KEY, sign_outgoing=True)
    introduce(autopilot, gcs)
    gcs.mav.command_long_send(1, 140, 183, 0, 9, 1200, 0, 0, 0, 0, 0)
    assert wait_until(lambda: side.stats()["link"].get("signing_rejected", 0) >= 2)
    assert backend.calls == []
    gcs.setup_signing(KEY, sign_outgoing=True)
    gcs.mav.command_long_send(1, 140, 183, 0, 9, 1300, 0, 0, 0, 0, 0)
    ack = wait_for_message(gcs, is_ack(183))
    assert ack is not None and ack.result == 0 and ack.get_signed()
    assert backend.servo_calls() == [("servo", 9, 1300.0, "do_set_servo")]
    bad = bytes(reversed(KEY))
    gcs.setup_signing(bad, sign_outgoing=True)
    gcs.mav.command_long_send(1, 140, 183, 0, 9, 1400, 0, 0, 0, 0, 0)
    assert wait_until(lambda: side.stats()["link"]["bad_signatures"] >= 1)
    assert len(backend.servo_calls()) == 1
