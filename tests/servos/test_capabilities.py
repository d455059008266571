"""The small ServoProfile core and its capabilities (issue 31 item 3): what only some families do
is a runtime-checkable Protocol met by defining its members, and the bridge asks with isinstance,
so a family never inherits a promise it does not keep."""

from __future__ import annotations

import can
import pytest

from mavservo.scheduling.schedule_core import ScheduleCore, ServoSpec, TimingConfig
from mavservo.servos import (
    PROFILES,
    Advising,
    BusNodeFamily,
    CommTimeout,
    ConfigWarnings,
    NodeReports,
    Releasing,
    ServoProfile,
    SplitStartup,
    UnsolicitedFrames,
    comm_timeout_of,
    node_family,
    node_reports_of,
    release_frames_of,
    unsolicited_hz_of,
)

INSTANCE_CAPABILITIES = (
    Releasing,
    CommTimeout,
    SplitStartup,
    UnsolicitedFrames,
    Advising,
    ConfigWarnings,
    NodeReports,
)
EXPECTED = {
    "rmd-x": {"Releasing"},
    "lk": {"Releasing"},
    "cubemars-ak": set(),
    "cubemars-ak-mit": {"Releasing", "CommTimeout"},
    "damiao-dm": {"Releasing", "CommTimeout"},
    "odrive": {"Releasing", "CommTimeout", "UnsolicitedFrames"},
    "dronecan": {"Releasing", "ConfigWarnings", "NodeReports", "BusNodeFamily"},
    "robstride": {"Releasing", "SplitStartup", "Advising"},
}
"""What each built-in family does beyond the core (docs/engineering/architecture.md, the capability
table): a method renamed by mistake would silently drop a capability, and this says so."""


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_each_family_has_the_capabilities_it_documents(name: str) -> None:
    cls = PROFILES[name]
    profile = cls(cls.min_id)
    have = {cap.__name__ for cap in INSTANCE_CAPABILITIES if isinstance(profile, cap)}
    have |= {"BusNodeFamily"} if isinstance(cls, BusNodeFamily) else set()
    assert have == EXPECTED[name]


def test_the_core_promises_none_of_the_capabilities() -> None:
    for cap in (
        "release_frames",
        "comm_timeout_s",
        "startup_continues",
        "unsolicited_hz",
        "diagnose",
        "silence_hint",
        "config_warnings",
        "is_liveness_only",
        "completes_report",
        "heartbeat_period_s",
        "frames_per_push",
        "NodeOptions",
        "bus_node",
        "link_sim_devices",
    ):
        assert cap not in vars(ServoProfile), cap


class _Bare(ServoProfile):
    """A plug-in with the core only: nothing beyond the six abstract methods."""

    name = "bare"

    def identifiers(self):  # type: ignore[no-untyped-def]
        return ()

    @classmethod
    def sim_device(cls, motor, can_id, options):  # type: ignore[no-untyped-def]
        raise NotImplementedError

    def position_command(self, angle_deg: float, max_speed_dps: float | None = None) -> can.Message:
        return can.Message(arbitration_id=0x300 + self.can_id, data=[1], is_extended_id=False)

    def telemetry_requests(self) -> list[can.Message]:
        return []

    def is_reply(self, msg: can.Message) -> bool:
        return False

    def decode(self, msg: can.Message, timestamp: float):  # type: ignore[no-untyped-def]
        return None


class _BareWithRelease(_Bare):
    """The same plug-in with a motor-off frame: structurally :class:`Releasing`, no base class
    or registration needed."""

    def release_frames(self) -> list[can.Message]:
        return [can.Message(arbitration_id=0x400 + self.can_id, data=[0], is_extended_id=False)]


def test_a_core_only_profile_gets_the_neutral_answers() -> None:
    bare = _Bare(1)
    assert release_frames_of(bare) == []
    assert comm_timeout_of(bare) is None
    assert unsolicited_hz_of(bare) == 0.0
    assert node_reports_of(bare) is None
    assert node_family(_Bare) is None
    assert "holds its last target" in bare.stop_behaviour()


def _released_frames(profile: ServoProfile) -> list[int]:
    core = ScheduleCore(
        [ServoSpec("s1", profile, telemetry_hz=0)], TimingConfig(telemetry_period_s=10.0), 100.0
    )
    core.release("s1")
    return [out.msg.arbitration_id for out in core.step(100.0).frames]


def test_the_schedule_core_releases_only_a_profile_that_can() -> None:
    assert isinstance(_BareWithRelease(1), Releasing) and not isinstance(_Bare(1), Releasing)
    assert _released_frames(_BareWithRelease(2)) == [0x402]
    assert _released_frames(_Bare(2)) == []
