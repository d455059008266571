"""What a ground station learns about servo problems, whenever it connects, and how long texts
and the ESC_TELEMETRY groups behave: fault/offline on the first state, the periodic reminders,
``s<n>_flt``, chunked STATUSTEXT (read back by the monitor over real UDP), and each
ESC_TELEMETRY message id as its own stream."""

from __future__ import annotations

import os

os.environ.setdefault("MAVLINK20", "1")

from dataclasses import replace  # noqa: E402

from hypothesis import given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from mavservo.app.monitor import MonitorState  # noqa: E402
from mavservo.mavlink.settings import MavlinkSettings, TelemetryRates  # noqa: E402
from tests.mavlink.test_udp_peers import peer  # noqa: E402
from tests.support.mavlink_doubles import (  # noqa: E402
    RecordingBackend,
    command_long,
    make_mavlink_core,
    state,
    wire,
)
from tests.support.waiting import free_udp_port, wait_for_message  # noqa: E402

#: servo n is ESC n here: these tests are about the grouping of servos into ESC messages
ESC_FROM_1 = TelemetryRates(esc_first_index=1)
from mavservo.mavlink.side import MavlinkSide  # noqa: E402
from mavservo.mavlink.telemetry import REMINDER_S, STATUSTEXT_LENGTH  # noqa: E402
from mavservo.servos.base import Fault  # noqa: E402

GCS = (255, 190)
SERVO = (1, 140)
ACCEPTED, UNSUPPORTED = 0, 3


class WideBackend(RecordingBackend):
    """The three-servo double, plus a fifth servo (config position 4) once ``wide`` is set."""

    wide = False

    def servo_statuses(self):
        statuses = super().servo_statuses()
        if self.wide:
            statuses.append(replace(statuses[0], name="tail", index=4, servo_channel=None))
        return statuses


def make_core(backend=None):
    return make_mavlink_core(backend, telemetry=ESC_FROM_1)


def texts(out) -> list[str]:
    return [m.text for _, m in out if m.get_type() == "STATUSTEXT"]


def run(core, start: float, stop: float, step: float = 0.5) -> list:
    out = []
    for i in range(int((stop - start) / step) + 1):
        out += core.tick(start + i * step)
    return out


def test_fault_and_offline_present_from_the_first_state_are_announced():
    core, backend = make_core()
    backend.states["aileron"] = state(0.0, faults=Fault.OVER_CURRENT)
    backend.offline.add("drop")
    first = texts(core.tick(0.0))
    assert "servo aileron fault over_current" in first
    assert "servo drop offline" in first
    assert not any("flap" in t for t in first)


def test_active_problems_are_repeated_for_late_listeners_and_stop_once_cleared():
    core, backend = make_core()
    backend.states["aileron"] = state(0.0, faults=Fault.OVER_CURRENT)
    backend.offline.add("drop")
    run(core, 0.0, 1.0)
    repeated = texts(run(core, 1.5, 2 * REMINDER_S + 0.5))
    assert repeated.count("servo aileron fault over_current") == 2
    assert repeated.count("servo drop offline") == 2
    backend.states["aileron"] = state(0.0)
    backend.offline.clear()
    later = texts(run(core, 2 * REMINDER_S + 1.0, 4 * REMINDER_S))
    assert "servo aileron cleared over_current" in later
    assert "servo drop back online" in later
    assert not any("fault" in t or "offline" in t for t in later)


def test_fault_bits_published_periodically_and_read_by_the_monitor():
    core, backend = make_core()
    backend.states["aileron"] = state(0.0, faults=Fault.OVER_CURRENT | Fault.STALL)
    backend.states["flap"] = state(0.0)
    backend.offline.add("drop")
    named = {m.name: m.value for _, m in core.tick(0.0) if m.get_type() == "NAMED_VALUE_FLOAT"}
    assert named["s1_flt"] == (Fault.OVER_CURRENT | Fault.STALL).value
    assert named["s2_flt"] == Fault.NO_REPLY.value
    assert named["s3_flt"] == 0
    monitor = MonitorState(["aileron", "drop", "flap"])  # a late monitor: no STATUSTEXT seen
    for _, msg in core.tick(1.0):
        if msg.get_type() == "NAMED_VALUE_FLOAT":
            monitor.update(msg, 1.0)
    rows = {row["name"]: row for row in monitor.servo_rows(1.0)}
    assert rows["aileron"]["faults"] == "over_current|stall"
    assert rows["aileron"]["status"] == "FAULT"
    assert rows["drop"]["status"] == "NO REPLY"
    assert rows["flap"]["status"] == "ok"


def test_long_statustext_is_chunked_and_the_monitor_joins_it_over_udp():
    text = (
        "bus0: CAN adapter lost (aa55: the adapter on /tmp/trial/ttyV0 stopped answering;"
        " reconnecting)"
    )
    exact = "x" * (2 * STATUSTEXT_LENGTH)  # fills its chunks: an empty last chunk ends it
    port = free_udp_port()
    side = MavlinkSide(
        MavlinkSettings(url=f"udpin:127.0.0.1:{port}", system_id=1, telemetry=ESC_FROM_1),
        RecordingBackend(),
    )
    gcs = peer(port, 255, 190)
    side.start()
    try:
        gcs.mav.heartbeat_send(6, 8, 0, 0, 4)
        assert wait_for_message(gcs, lambda m: m.get_type() == "HEARTBEAT") is not None
        side.announce(text)
        side.announce("short one")
        side.announce(exact)
        monitor = MonitorState()
        chunks: list = []

        def seen(msg) -> bool:
            if msg.get_type() == "STATUSTEXT":
                chunks.append(msg)
                monitor.update(msg, 0.0)
            return len(monitor.texts) >= 3

        assert wait_for_message(gcs, seen) is not None
    finally:
        side.stop()
        gcs.close()
    assert [t for _, _, t in monitor.texts] == [text, "short one", exact]
    first = [m for m in chunks if m.id == chunks[0].id]
    assert chunks[0].id != 0 and [m.chunk_seq for m in first] == [0, 1]
    assert [m.id for m in chunks if m.text == "short one"] == [0]
    assert len([m for m in chunks if m.id == chunks[-1].id]) == 3


def test_monitor_joins_chunks_arriving_out_of_order_and_keeps_texts_apart():
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=140)

    def chunk(text_id, seq, text):
        msg = mavlink2.MAVLink_statustext_message(4, text.encode(), text_id, seq)
        return mav.decode(bytearray(msg.pack(mav)))

    monitor = MonitorState()
    a0, a1 = "a" * STATUSTEXT_LENGTH, "end of a"
    b0, b1 = "b" * STATUSTEXT_LENGTH, "end of b"
    for msg in (chunk(7, 1, a1), chunk(8, 0, b0), chunk(7, 0, a0), chunk(8, 1, b1)):
        monitor.update(msg, 0.0)
    assert [t for _, _, t in monitor.texts] == [a0 + a1, b0 + b1]


def test_every_published_esc_group_can_be_requested_and_switched_off_alone():
    backend = WideBackend()
    backend.states["aileron"] = state(1.0)
    core, _ = make_core(backend)
    group2 = 11031  # ESC_TELEMETRY_5_TO_8: servos 5..8; the double has 3 servos
    out = core.on_message(wire(command_long(SERVO, 512, group2), GCS), 0.0)
    assert [(m.get_type(), getattr(m, "result", None)) for _, m in out] == [
        ("COMMAND_ACK", UNSUPPORTED)
    ]
    # with a fifth servo, 5_TO_8 is published: requestable and with its own interval
    backend.wide = True
    out = core.on_message(wire(command_long(SERVO, 512, 11030), GCS), 0.0)
    assert [m.get_type() for _, m in out] == ["COMMAND_ACK", "ESC_TELEMETRY_1_TO_4"]
    out = core.on_message(wire(command_long(SERVO, 512, group2), GCS), 60.0)  # not a retry
    assert [m.get_type() for _, m in out] == ["COMMAND_ACK", "ESC_TELEMETRY_5_TO_8"]
    assert out[0][1].result == ACCEPTED
    ack = core.on_message(wire(command_long(SERVO, 511, 11030, -1), GCS), 60.0)
    assert ack[0][1].result == ACCEPTED
    kinds = [m.get_type() for step in range(1, 200) for _, m in core.tick(60.0 + step * 0.01)]
    assert "ESC_TELEMETRY_5_TO_8" in kinds and "ESC_TELEMETRY_1_TO_4" not in kinds


def test_an_offline_servo_publishes_no_old_values_as_current():
    """While a servo (or its whole adapter) is offline, its last state is old news: its ESC
    slot reads empty (count 0) and it sends no s<n>_pos/vel/cur/tmp, only s<n>_flt = NO_REPLY."""
    core, backend = make_core()
    for name in ("aileron", "drop", "flap"):
        backend.states[name] = state(10.0)
    backend.offline.add("drop")  # config position 2: ESC slot 1, NAMED_VALUE_FLOAT s2_*
    out = [m for _, m in core.tick(0.0)]
    [esc] = [m for m in out if m.get_type() == "ESC_TELEMETRY_1_TO_4"]
    assert esc.count[0] > 0 and esc.count[2] > 0
    assert esc.count[1] == 0 and esc.temperature[1] == 0 and esc.rpm[1] == 0
    names = {m.name for m in out if m.get_type() == "NAMED_VALUE_FLOAT"}
    assert {"s1_pos", "s3_pos", "s2_flt"} <= names
    assert not names & {"s2_pos", "s2_vel", "s2_cur", "s2_tmp"}


def test_a_flapping_servo_gets_a_bounded_number_of_texts_with_a_count_and_its_state_now():
    """Issue 37: two servos flapping "not responding" / "responding again" sent 57
    STATUSTEXTs in 22 s. Flapping every tick for a minute, one servo's texts stay within
    three per 10 s plus the reminders, and its last text says what is true at the end."""
    core, backend = make_core()
    out = []
    for i in range(600):  # 60 s at 10 Hz, offline every other tick
        if i % 2:
            backend.offline.add("drop")
        else:
            backend.offline.discard("drop")
        out += core.tick(i * 0.1)
    said = [t for t in texts(out) if t.startswith("servo drop")]
    assert len(said) <= 3 * 6 + 60 / REMINDER_S + 1
    assert any("(x" in t and " in 10 s)" in t for t in said)  # the repeats are counted
    backend.offline.discard("drop")
    last = [t for t in texts(run(core, 60.0, 75.0)) if t.startswith("servo drop")]
    assert last[-1].startswith("servo drop back online")


def test_long_texts_break_between_words_and_keep_their_end():
    """Issue 37: chunks cut mid-word ("...on fresh comma" + "nds"), and four chunks cut the
    237-character AP_Periph warning before the setting that fixes it. Every chunk but the last
    is full (QGroundControl and MAVProxy take a shorter one as the last) and ends at a space."""
    from mavservo.mavlink import join_statustext_chunks
    from mavservo.mavlink.telemetry import statustext_chunks, statustext_messages

    warning = (
        "DroneCAN nodes 10, 11, 12 run ArduPilot firmware, which keeps its outputs off until "
        "it hears SafetyState SAFETY_OFF, and the bridge sends none (safety_state: none): "
        "their servos will not move; set node.dronecan.safety_state: safety_off"
    )
    chunks = statustext_chunks(warning)
    assert all(len(c) == STATUSTEXT_LENGTH and c.endswith(b" ") for c in chunks[:-1])
    assert len(chunks[-1]) < STATUSTEXT_LENGTH
    assert chunks[-1].endswith(b"set node.dronecan.safety_state: safety_off")
    assert join_statustext_chunks([c.decode() for c in chunks]) == warning
    messages = statustext_messages(4, warning, 7)
    assert [(m.id, m.chunk_seq) for m in messages] == [(7, k) for k in range(len(chunks))]
    assert [len(c) for c in statustext_chunks("a" * 120)] == [50, 50, 20]  # one long word


@given(st.lists(st.text("abcdefghij", min_size=1, max_size=12), min_size=1, max_size=40))
def test_chunks_of_any_text_of_words(words):
    from mavservo.mavlink import join_statustext_chunks
    from mavservo.mavlink.telemetry import STATUSTEXT_MAX_CHUNKS, statustext_chunks

    text = " ".join(words)
    chunks = statustext_chunks(text)
    assert len(chunks) <= STATUSTEXT_MAX_CHUNKS
    if len(text) <= STATUSTEXT_LENGTH:
        assert chunks == [text.encode()]
        return
    assert all(len(c) == STATUSTEXT_LENGTH and c.endswith(b" ") for c in chunks[:-1])
    assert len(chunks[-1]) < STATUSTEXT_LENGTH
    if not chunks[-1].endswith(b"..."):  # fits: said whole, broken only between words
        assert join_statustext_chunks([c.decode() for c in chunks]) == text
    else:  # six chunks of words of up to 12 letters hold 200 characters at least
        assert len(text) > 200
