"""Retry detection is per output: a change back is a change, never a retry (finding 6).

The MAVLink spec makes confirmation 0 a first transmission. A command is a retry only when it
is identical (sender, message type, target, parameters) to the last command for every output
it drives, and comes inside the retry window or carries confirmation > 0. Any other command
for one of those outputs in between, from anyone, ends the window.

The first test is the finding as reported, over real pymavlink UDP sockets; the rest drive the
sans-I/O core with a fake time.
"""

from __future__ import annotations

import os
import time

os.environ.setdefault("MAVLINK20", "1")

from mavservo.mavlink.mavlink_core import MavlinkCore  # noqa: E402
from mavservo.mavlink.origin import tag  # noqa: E402
from tests.mavlink.test_udp_peers import bridge, introduce, is_ack  # noqa: E402, F401, F811
from tests.support.mavlink_doubles import (
    # noqa: E402
    NAN,
    RecordingBackend,
    command_int,
    command_long,
    make_mavlink_core,
    wire,
)
from tests.support.waiting import wait_for_message as wait_for  # noqa: E402, F401, F811
from tests.support.waiting import wait_until

GCS = (255, 190)
OTHER_GCS = (254, 190)
SERVO = (1, 140)
ACCEPTED = 0


def make_core() -> tuple[MavlinkCore, RecordingBackend]:
    return make_mavlink_core(channel_trims_us={9: 1500.0})


def send(core: MavlinkCore, msg, now: float, src=GCS) -> list[int]:
    """The COMMAND_ACK results the core answers ``msg`` with."""
    out = core.on_message(wire(msg, src), now)
    return [m.result for _, m in out if m.get_type() == "COMMAND_ACK"]


def send_from(core: MavlinkCore, msg, now: float, origin) -> list[int]:
    """As :func:`send`, as 255/190 from ``origin`` (a UDP address; the ids pin nothing here)."""
    received = wire(msg, GCS)
    tag(received, origin, pinned=True)
    out = core.on_message(received, now)
    return [m.result for _, m in out if m.get_type() == "COMMAND_ACK"]


STATION_ADDRESS = ("127.0.0.1", 14550)
STRANGER_ADDRESS = ("127.0.0.66", 14550)


def pwms(backend: RecordingBackend, channel: int = 1) -> list[float]:
    return [c[2] for c in backend.servo_calls() if c[1] == channel]


def test_change_back_over_udp_is_applied_not_taken_for_a_retry(bridge):  # noqa: F811
    """The finding: 1100, 1900, 1100 us, 0.5 s apart, confirmation 0: all three applied."""
    side, backend, autopilot, gcs = bridge
    introduce(autopilot, gcs)
    assert wait_until(lambda: side.stats()["system_id"] == 1)
    for k, pwm in enumerate((1100, 1900, 1100)):
        if k:
            time.sleep(0.5)
        gcs.mav.command_long_send(1, 140, 183, 0, 9, pwm, 0, 0, 0, 0, 0)
        ack = wait_for(gcs, is_ack(183))
        assert ack is not None and ack.result == ACCEPTED
    assert wait_until(lambda: len(backend.servo_calls()) >= 3)
    assert [c[2] for c in backend.servo_calls() if c[1] == 9] == [1100.0, 1900.0, 1100.0]
    assert side.stats()["commands"].get("retry_not_reapplied", 0) == 0


def test_identical_repeat_inside_the_window_is_still_a_retry():
    core, backend = make_core()
    assert send(core, command_long(SERVO, 183, 1, 1100), 0.0) == [ACCEPTED]
    assert send(core, command_long(SERVO, 183, 1, 1100), 0.5) == [ACCEPTED]
    assert pwms(backend) == [1100.0]
    assert core.commands.counters["retry_not_reapplied"] == 1


def test_another_senders_command_for_the_output_ends_the_window():
    core, backend = make_core()
    send(core, command_long(SERVO, 183, 1, 1100), 0.0)
    send(core, command_long(SERVO, 183, 1, 1900), 0.2, src=OTHER_GCS)
    assert send(core, command_long(SERVO, 183, 1, 1100), 0.4) == [ACCEPTED]
    assert pwms(backend) == [1100.0, 1900.0, 1100.0]
    assert core.commands.counters["retry_not_reapplied"] == 0


def test_a_denied_command_for_the_output_also_ends_the_window():
    """Whatever was asked of the output since, the sender's repeat is what it wants now."""
    core, backend = make_core()
    send(core, command_long(SERVO, 183, 1, 1100), 0.0)
    assert send(core, command_long(SERVO, 184, 1, 1900, 0, 1), 0.2) == [2]  # count 0: denied
    assert send(core, command_long(SERVO, 183, 1, 1100), 0.4) == [ACCEPTED]
    assert pwms(backend) == [1100.0, 1100.0]


def test_a_command_for_another_output_does_not_end_the_window():
    core, backend = make_core()
    send(core, command_long(SERVO, 183, 1, 1100), 0.0)
    send(core, command_long(SERVO, 183, 9, 1900), 0.2, src=OTHER_GCS)
    assert send(core, command_long(SERVO, 183, 1, 1100), 0.4) == [ACCEPTED]
    assert pwms(backend) == [1100.0]
    assert core.commands.counters["retry_not_reapplied"] == 1


def test_confirmation_repeat_after_a_change_is_applied():
    """confirmation > 0 makes a repeat of the LAST command a retry, not of an older one."""
    core, backend = make_core()
    send(core, command_long(SERVO, 183, 1, 1100), 0.0)
    send(core, command_long(SERVO, 183, 1, 1900), 0.5)
    assert send(core, command_long(SERVO, 183, 1, 1100, confirmation=1), 1.0) == [ACCEPTED]
    assert pwms(backend) == [1100.0, 1900.0, 1100.0]


def test_confirmation_repeat_of_the_last_command_is_a_retry_even_after_the_window():
    core, backend = make_core()
    send(core, command_long(SERVO, 183, 1, 1100), 0.0)
    assert send(core, command_long(SERVO, 183, 1, 1100, confirmation=2), 3.0) == [ACCEPTED]
    assert pwms(backend) == [1100.0]
    assert send(core, command_long(SERVO, 183, 1, 1100), 6.5) == [ACCEPTED]  # first again
    assert pwms(backend) == [1100.0, 1100.0]


def test_command_int_and_command_long_are_different_commands():
    core, backend = make_core()
    send(core, command_long(SERVO, 183, 1, 1100), 0.0)
    send(core, command_int(SERVO, 183, 1, 1900), 0.2)
    assert send(core, command_long(SERVO, 183, 1, 1100), 0.4) == [ACCEPTED]
    assert pwms(backend) == [1100.0, 1900.0, 1100.0]


def test_do_set_actuator_window_ends_when_any_of_its_outputs_is_commanded():
    """Actuators 1 and 5 (set 0) in one command; another command for 5 alone in between."""
    core, backend = make_core()
    both = command_long(SERVO, 187, 0.5, NAN, NAN, NAN, 0.25, NAN, 0)
    only_5 = command_long(SERVO, 187, NAN, NAN, NAN, NAN, -0.25, NAN, 0)
    send(core, both, 0.0)
    assert send(core, both, 0.2) == [ACCEPTED]  # identical, nothing in between: a retry
    assert len(backend.servo_calls("actuator")) == 2
    send(core, only_5, 0.4, src=OTHER_GCS)
    assert send(core, both, 0.6) == [ACCEPTED]  # actuator 5 was moved since: applied
    values = [(c[1], c[2]) for c in backend.servo_calls("actuator")]
    assert values == [(1, 0.5), (5, 0.25), (5, -0.25), (1, 0.5), (5, 0.25)]


def test_repeat_servo_after_a_set_servo_on_its_channel_restarts():
    core, backend = make_core()
    repeat = command_long(SERVO, 184, 9, 1900, 3, 2)
    send(core, repeat, 0.0)
    send(core, command_long(SERVO, 183, 9, 1200), 0.3)  # stops the repeat
    assert core.commands.repeating_channels() == set()
    assert send(core, repeat, 0.6) == [ACCEPTED]
    assert core.commands.repeating_channels() == {9}
    assert pwms(backend, 9) == [1900.0, 1200.0, 1900.0]


def test_retry_of_a_temporarily_rejected_command_is_a_fresh_attempt():
    core, backend = make_core()
    backend.offline.add("aileron")
    assert send(core, command_long(SERVO, 183, 1, 1100), 0.0) == [1]
    backend.offline.clear()
    assert send(core, command_long(SERVO, 183, 1, 1100), 0.5) == [ACCEPTED]
    assert pwms(backend) == [1100.0, 1100.0]  # the refused attempt, then the one applied
    assert core.commands.counters["retry_not_reapplied"] == 0


def test_the_stations_ids_from_another_address_are_another_sender_for_retries():
    """Issue 40 on the retry table: keyed by ids only, a stranger claiming 255/190 from another
    address made the station's identical command a "retry" of its own (ACKed, not applied),
    and the stranger's copy of the station's command a retry of the station's. Keyed by ids
    and origin, each is a command of its own; the station's own repeat is still a retry."""
    core, backend = make_core()
    set_1100 = command_long(SERVO, 183, 1, 1100)
    assert send_from(core, set_1100, 0.0, STRANGER_ADDRESS) == [ACCEPTED]
    assert send_from(core, set_1100, 0.3, STATION_ADDRESS) == [ACCEPTED]
    assert pwms(backend) == [1100.0, 1100.0]  # the station's command applied, not a retry
    assert core.commands.counters["retry_not_reapplied"] == 0
    assert send_from(core, set_1100, 0.6, STATION_ADDRESS) == [ACCEPTED]  # its own repeat
    assert pwms(backend) == [1100.0, 1100.0]
    assert core.commands.counters["retry_not_reapplied"] == 1


def test_a_stranger_repeating_the_stations_repeat_servo_is_not_its_retry():
    """The other way round: the station's DO_REPEAT_SERVO, then a stranger's identical copy as
    255/190 from another address, is the stranger's command (it restarts the repeat, as anyone's
    new command would with ``allowed_sources`` empty), not the station's retry ACKed again."""
    core, backend = make_core()
    repeat = command_long(SERVO, 184, 9, 1900, 3, 2)
    assert send_from(core, repeat, 0.0, STATION_ADDRESS) == [ACCEPTED]
    assert send_from(core, repeat, 0.3, STRANGER_ADDRESS) == [ACCEPTED]
    assert core.commands.counters["retry_not_reapplied"] == 0
    assert pwms(backend, 9) == [1900.0, 1900.0]  # applied twice: two senders' commands
