"""A query is a query: asking a profile for its poll frames consumes no poll.

RMD-X interleaves a fault read (9A) every ``fault_poll_every``-th poll. The budget and the
scheduler's start-up checks ask the profile for its frames several times; when asking counted
as polling, the first fault read went out early (after 10 minus the questions asked), and a
budget built before the run shifted the interleaving of the running scheduler.
"""

from __future__ import annotations

from mavservo.scheduling.busload import servo_traffic
from mavservo.scheduling.schedule_core import ScheduleCore, ServoSpec, TimingConfig
from mavservo.servos import RmdX

STATUS_2, STATUS_1 = 0x9C, 0x9A


def test_asking_for_the_poll_frames_does_not_advance_the_interleaving() -> None:
    profile = RmdX(1, fault_poll_every=2)
    asked = [profile.telemetry_requests()[0].data[0] for _ in range(5)]
    assert asked == [STATUS_2] * 5
    profile.poll_sent()
    assert profile.telemetry_requests()[0].data[0] == STATUS_1


def test_building_a_budget_consumes_no_poll() -> None:
    profile = RmdX(1, fault_poll_every=2)
    servo_traffic(profile, command_hz=20.0, poll_hz=10.0, status_hz=0.0, max_speed_dps=None)
    assert profile.polls == 0


def _sent_commands(core: ScheduleCore, until: float) -> list[int]:
    """The command bytes of the requests the core sends up to ``until``, in order; every reply
    arrives at once, so no poll is held back by an outstanding one."""
    commands = []
    now = 0.0
    for _ in range(1000):  # bounded: the loop ends on the time limit long before
        if now > until:
            break
        decision = core.step(now)
        for out in decision.frames:
            core.sent(out, now)
            if out.kind == "request":
                commands.append(out.msg.data[0])
            core.on_reply(out.servo, now, out.msg.data[0])
        now = max(decision.next_deadline, now + 1e-6)
    return commands


def test_the_scheduler_counts_the_polls_it_sends_from_the_first() -> None:
    """Every 3rd poll reads faults, counted from the first poll the scheduler sends: the
    start-up checks in ``ScheduleCore.__init__`` ask for the frames but send nothing."""
    profile = RmdX(1, fault_poll_every=3)
    core = ScheduleCore([ServoSpec("s1", profile)], TimingConfig(), start=0.0)
    commands = _sent_commands(core, until=0.09 * 6 + 0.05)
    assert len(commands) >= 6
    assert commands[:6] == [STATUS_2, STATUS_2, STATUS_1, STATUS_2, STATUS_2, STATUS_1]
    assert profile.polls == len(commands)
