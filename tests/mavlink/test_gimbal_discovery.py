"""A gimbal the autopilot never looks for is said, with the fix, within seconds.

ArduPilot's MAVLink gimbal driver looks for a gimbal only from 10 s after boot until it is past
60 s and armed (AP_Mount_Gremsy.cpp, find_gimbal). The simulated autopilot does the same here
(``gimbal_search_s``): booted 75 s ago and armed, it never asks; the bridge must say so in its
log and by STATUSTEXT. Booted 15 s ago and looking, it asks at once: no warning.
"""

from __future__ import annotations

import logging
import time

import pytest

from mavservo.mavlink.connection import mavlink2
from mavservo.mavlink.gimbal_discovery import GRACE_S, GimbalDiscoveryWatch
from mavservo.sim.autopilot.stream import ARDUPILOT_GIMBAL_SEARCH_S, AutopilotStream
from tests.support.bridge import gimbal_config, running
from tests.support.waiting import wait_until

NOT_FOUND = "not found by the autopilot"


def attitude(boot_s: float) -> object:
    return mavlink2.MAVLink_attitude_message(int(boot_s * 1000), 0, 0, 0, 0, 0, 0)


def request_info(component: int = 154) -> object:
    return mavlink2.MAVLink_command_long_message(1, component, 512, 0, 283, 0, 0, 0, 0, 0, 0)


def ardupilot(autopilot: int = 3) -> object:
    return mavlink2.MAVLink_heartbeat_message(1, autopilot, 0, 0, 3, 3)


def test_the_watch_warns_once_past_the_search_window_and_not_before() -> None:
    late = GimbalDiscoveryWatch([154])
    late.on_autopilot_message(ardupilot(), 100.0)
    late.on_autopilot_message(attitude(75.0), 100.0)
    assert late.due(100.0 + GRACE_S - 0.1) == []
    ((gimbal, text),) = late.due(100.0 + GRACE_S)
    assert gimbal == 154 and "Reboot the autopilot with the bridge running" in text
    assert late.due(200.0) == []  # once
    assert late.on_autopilot_message(request_info(), 201.0) == [
        "gimbal 154 found by the autopilot after all"
    ]

    booting = GimbalDiscoveryWatch([154])  # powered up together: the autopilot is at 2 s
    booting.on_autopilot_message(ardupilot(), 0.0)
    booting.on_autopilot_message(attitude(2.0), 0.0)
    assert booting.due(GRACE_S) == [] and booting.due(12.9) == []
    assert booting.on_autopilot_message(request_info(), 9.0) == []  # it asks at its 10 s
    assert booting.due(60.0) == []

    other = GimbalDiscoveryWatch([154])  # a command to another component proves nothing
    other.on_autopilot_message(ardupilot(), 0.0)
    other.on_autopilot_message(attitude(75.0), 0.0)
    other.on_autopilot_message(request_info(171), 0.5)
    assert len(other.due(GRACE_S)) == 1

    px4 = GimbalDiscoveryWatch([154])  # ArduPilot's search window is no advice for PX4
    px4.on_autopilot_message(ardupilot(autopilot=12), 0.0)
    px4.on_autopilot_message(attitude(75.0), 0.0)
    assert px4.due(GRACE_S - 0.1) == []
    ((_gimbal, text),) = px4.due(GRACE_S)  # PX4 asks every second from boot: it is off
    assert "MNT_MODE_OUT 2" in text and "start the bridge first" not in text
    asking = GimbalDiscoveryWatch([154])  # PX4 asks every component at once (0/0)
    asking.on_autopilot_message(ardupilot(autopilot=12), 0.0)
    asking.on_autopilot_message(request_info(0), 0.5)
    assert asking.due(60.0) == [] and asking.stats()["found"] == [154]
    generic = GimbalDiscoveryWatch([154])  # another autopilot: no advice at all
    generic.on_autopilot_message(ardupilot(autopilot=0), 0.0)
    assert generic.due(60.0) == []


@pytest.mark.parametrize("looking", [False, True], ids=["stopped-looking", "looking"])
def test_a_bridge_started_late_is_told_why_its_gimbal_is_never_found(
    looking: bool, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, logger="mavservo.mavlink.mavlink_core")
    with running(gimbal_config("rmd-x", "rmd-x")) as (bridge, port):
        autopilot = AutopilotStream(
            f"udpout:127.0.0.1:{port}",
            "hold",
            gimbal=True,
            gimbal_search_s=ARDUPILOT_GIMBAL_SEARCH_S,
            # booted 15 s ago and disarmed (looking), or 75 s ago and armed (stopped)
            boot_offset_s=15.0 if looking else 75.0,
            armed=not looking,
        ).start()
        try:

            def texts() -> list[str]:
                return [m.text for _t, m in autopilot.received.messages("STATUSTEXT")]

            if looking:
                assert wait_until(lambda: autopilot.gimbal_device_info is not None, 5.0)
                time.sleep(GRACE_S + 2.0)  # past the moment the warning would come
                assert not any(NOT_FOUND in t for t in texts())
                assert bridge.mavlink.stats()["gimbal_discovery"]["found"] == [154]
            else:
                assert wait_until(lambda: any(NOT_FOUND in t for t in texts()), GRACE_S + 5.0)
                assert autopilot.gimbal_device_info is None
                assert bridge.mavlink.stats()["gimbal_discovery"]["warned"] == [154]
        finally:
            autopilot.stop()
    warnings = [r.getMessage() for r in caplog.records if NOT_FOUND in r.getMessage()]
    assert len(warnings) == (0 if looking else 1)
    if not looking:
        assert "start the bridge first" in warnings[0] and "MNT1_TYPE 6" in warnings[0]
