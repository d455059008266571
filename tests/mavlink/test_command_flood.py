"""A command flood must not stall the command loop, and a stall must show (finding 10).

* The retry table is bounded: 100,000 distinct commands (many senders, every command id, every
  PWM) leave at most ``MAX_RETRY_ENTRIES`` entries, so a lookup never scans the flood.
* The scheduler's stall figures see a stall between the loop's wake-up and the write: a bus
  whose ``send`` takes 125.6 ms (a fake clock, moved by the bus) left the bus silent for two
  slots while ``missed_command_slots`` stayed 0 and the lateness, taken at wake-up, stayed 0.

No timing thresholds: the clock is fake, the bound is a count.
"""

from __future__ import annotations

import logging

import can

from mavservo.mavlink.commands import MAX_RETRY_ENTRIES, Command, CommandHandler
from mavservo.mavlink.mavlink_core import MavlinkCore
from mavservo.mavlink.settings import MavlinkSettings
from mavservo.scheduling.runner import Scheduler, ServoSpec, TimingConfig
from mavservo.servos import RmdX
from tests.support.mavlink_doubles import RecordingBackend

SERVO_COMPONENT = 140
DISTINCT_COMMANDS = 100_000


def retained_commands(handler: CommandHandler) -> int:
    """How many commands the retry detector keeps (on 4a52fda: one per distinct command)."""
    table = getattr(handler, "retry_table", None)
    return len(table) if table is not None else len(handler._recent)


def test_retry_table_stays_bounded_under_100k_distinct_commands():
    core = MavlinkCore(MavlinkSettings(system_id=1), RecordingBackend(), boot_time=0.0)
    handler = core.commands
    acks = 0
    for k in range(DISTINCT_COMMANDS):
        # every command distinct: sender, command id (mapped servo, unknown), channel and PWM
        source = (1 + k % 250, 1 + (k // 250) % 250)
        command = 183 if k % 2 else 1000 + k % 5000
        params = (float(1 + 8 * (k % 2)), 1000.0 + (k % 1000), 0.0, 0.0, 0.0, 0.0, 0.0)
        cmd = Command(source, 1, SERVO_COMPONENT, command, params)
        out = handler.handle(cmd, k * 1e-5)  # all inside one retry window: nothing expires
        acks += sum(1 for _, m in out if m.get_type() == "COMMAND_ACK")
    assert acks == DISTINCT_COMMANDS
    assert handler.counters.get("retry_not_reapplied", 0) == 0
    assert retained_commands(handler) <= MAX_RETRY_ENTRIES
    assert handler.counters["retry_entries_dropped"] > 0  # the operator sees the table was full


class FakeClock:
    def __init__(self, start: float = 100.0) -> None:
        self.now = start

    def __call__(self) -> float:
        return self.now


class StallingBus(can.BusABC):
    """A bus whose next ``send`` takes ``stall_s`` of (fake) time, as a starved writer did."""

    def __init__(self, clock: FakeClock) -> None:
        self._clock = clock
        self.stall_s = 0.0
        self.sent: list[tuple[float, can.Message]] = []
        self.channel_info = "stalling"
        super().__init__(channel="stalling")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._clock.now += self.stall_s
        self.stall_s = 0.0
        self.sent.append((self._clock.now, msg))

    def _recv_internal(self, timeout: float | None):
        return None, False


def run_slot(scheduler: Scheduler, clock: FakeClock, at: float) -> None:
    """One pass of the command loop at ``at``: what ``Scheduler._run`` does between waits."""
    clock.now = max(clock.now, at)
    scheduler._writer.send_all(scheduler._writer.step())


def test_a_stall_between_wake_up_and_write_shows_in_the_slot_metrics():
    clock = FakeClock()
    bus = StallingBus(clock)
    timing = TimingConfig(command_period_s=0.05, telemetry_period_s=0.1)
    scheduler = Scheduler(bus, [ServoSpec("s1", RmdX(1), telemetry_hz=0)], timing, clock=clock)
    start = clock.now
    scheduler._core.anchor(start)
    scheduler.set_setpoint("s1", 10.0, "test", t=start)
    for k in range(4):  # on time: one write per slot
        run_slot(scheduler, clock, start + k * 0.05)
    before = scheduler.metrics()
    assert before["missed_command_slots"] == 0
    bus.stall_s = 0.1256  # the loop wakes on time for slot 4, the bus takes its frame late
    run_slot(scheduler, clock, start + 4 * 0.05)
    run_slot(scheduler, clock, clock.now)  # the loop gets round again right after the stall
    after = scheduler.metrics()
    assert after["command_lateness_s"]["max"] >= 0.1256 - 1e-9
    assert after["late_command_slots"] == 1
    assert after["longest_command_gap_s"] >= 0.05 + 0.1256 - 1e-9
    scheduler._bus.shutdown()


def test_a_flood_of_bad_commands_is_one_warning_line_per_kind_not_one_per_command(caplog):
    handler = MavlinkCore(MavlinkSettings(system_id=1), RecordingBackend()).commands
    with caplog.at_level(logging.WARNING, logger="mavservo.mavlink.commands"):
        for k in range(1000):  # PWM out of range, each a distinct command, within 0.5 s
            cmd = Command((255, 190), 1, SERVO_COMPONENT, 183, (1.0, 3000.0 + k) + (0.0,) * 5)
            assert handler.handle(cmd, 10.0 + k * 0.0005)[0][1].result == 2  # DENIED
        first = [r.getMessage() for r in caplog.records]
        handler.handle(
            Command((255, 190), 1, SERVO_COMPONENT, 183, (1.0, 9999.0) + (0.0,) * 5), 11.0
        )
    assert handler.counters["reason_bad_param"] == 1001
    assert len(first) == 1
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 2 and "999 more refused for bad_param" in lines[1]
