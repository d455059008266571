"""Every servo profile through the whole bridge and back.

A GCS-side pymavlink peer sends DO_SET_SERVO (RMD-X, LK) and DO_SET_ACTUATOR (CubeMars) to the
bridge over UDP; the bridge drives the aa55 interface on the adapter emulator's pty; simulated
servos move and answer; their telemetry comes back over MAVLink as NAMED_VALUE_FLOAT and
ACTUATOR_OUTPUT_STATUS. Checked: every command ACKed ACCEPTED, the settled telemetry matches both
the target and the simulated servo's true position within the profile's resolution (RMD/LK
replies carry whole degrees: at most 0.5 deg; CubeMars 0.1 deg: at most 0.05 deg), and nothing
lost or rejected on the clean line.
"""

from __future__ import annotations

import math
import statistics
import time

import pytest

from tests.support.bridge import (
    MAV_CMD_DO_SET_ACTUATOR,
    MAV_CMD_DO_SET_SERVO,
    MAV_RESULT_ACCEPTED,
    Peer,
    named_values,
    pwm_to_angle,
    running,
    sim_servo,
)
from tests.support.waiting import wait_until

# a bridge thread dying (an exception nobody catches) fails the test, not just warns
pytestmark = pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")

CONFIG = """
  telemetry: {actuator_output_status_hz: 20, named_value_float_hz: 20, esc_telemetry_hz: 0}
  # no autopilot-link budget: telemetry at the configured rates, not thinned to 1000 B/s, so
  # the samples judged here come in a fraction of a second (the budget has its own tests)
  link_budget_bytes_s: null
servos:
  - {name: rmd, profile: rmd-x, can_id: 1, limits_deg: [-90, 90], telemetry_hz: 10}
  - {name: lk, profile: lk, can_id: 2, limits_deg: [-90, 90], telemetry_hz: 10}
  - {name: ak, profile: cubemars-ak, can_id: 3, limits_deg: [-90, 90], telemetry_hz: 20}
# a reply counts as lost only when it never comes: a loaded shared machine can delay one
# past the usual 50 ms, and that is timing, which these tests do not judge
scheduler: {reply_timeout_s: 0.5}
channels:
  - {servo: rmd, source: servo_output, channel: 1, input: {min: 1000, max: 2000},
     output_deg: [-90, 90]}
  - {servo: lk, source: servo_output, channel: 2, input: {min: 1000, max: 2000},
     output_deg: [-90, 90]}
  - {servo: ak, source: actuator, index: 1, output_deg: [-90, 90]}
"""

#: servo -> (config position + 1 = NAMED_VALUE_FLOAT n, telemetry resolution in degrees)
SERVOS = {"rmd": (1, 1.0), "lk": (2, 1.0), "ak": (3, 0.1)}
#: (PWM ch1, PWM ch2, actuator 1): fractional angles so rounding shows up in the error
STEPS = [(1568, 1233, -0.2461), (1811, 1402, 0.4437), (1127, 1950, -0.8123)]
SAMPLES = 4  # telemetry samples per servo and step, after settling


def all_replied_since(bridge, t: float) -> bool:
    """Every servo's latest decoded state is stamped after ``t`` (the scheduler's monotonic
    clock)."""
    states = [bridge.schedulers["bus0"].state(name) for name in SERVOS]
    return all(state is not None and state.timestamp > t for state in states)


def test_every_profile_round_trip_with_acks_and_telemetry_resolution() -> None:
    errors: dict[str, list[float]] = {name: [] for name in SERVOS}
    normalized_checked = 0
    with running(CONFIG) as (bridge, port):
        peer = Peer(port)
        try:
            for pwm1, pwm2, actuator in STEPS:
                targets = {
                    "rmd": pwm_to_angle(pwm1, 1000, 2000, (-90, 90)),
                    "lk": pwm_to_angle(pwm2, 1000, 2000, (-90, 90)),
                    "ak": pwm_to_angle(actuator, -1, 1, (-90, 90)),
                }
                assert peer.command(MAV_CMD_DO_SET_SERVO, [1, pwm1]) == MAV_RESULT_ACCEPTED
                assert peer.command(MAV_CMD_DO_SET_SERVO, [2, pwm2]) == MAV_RESULT_ACCEPTED
                values = [actuator] + [math.nan] * 5 + [0]
                assert peer.command(MAV_CMD_DO_SET_ACTUATOR, values) == MAV_RESULT_ACCEPTED
                servos = {name: sim_servo(bridge, name) for name in SERVOS}
                assert wait_until(
                    lambda t=targets, s=servos: all(
                        abs(s[n].position_deg - t[n]) < 0.01 and abs(s[n].velocity_dps) < 0.1
                        for n in SERVOS
                    ),
                    5.0,
                ), {n: s.position_deg for n, s in servos.items()}
                # a reply of every servo decoded after settling (an event, not a fixed sleep),
                # so no telemetry sent from here on carries a state that predates it
                settled_at = time.monotonic()
                assert wait_until(lambda t=settled_at: all_replied_since(bridge, t), 5.0)
                mark = peer.count()
                wait_until(
                    lambda m=mark: all(
                        len(named_values(peer.since(m), f"s{n}_pos")) >= SAMPLES
                        for n, _ in SERVOS.values()
                    ),
                    5.0,
                )
                fresh = peer.since(mark)
                for name, (n, resolution) in SERVOS.items():
                    reported = named_values(fresh, f"s{n}_pos")
                    assert len(reported) >= SAMPLES, f"{name}: too little telemetry"
                    true = servos[name].position_deg
                    for value in reported:
                        # telemetry matches the simulated servo within the reply's resolution
                        assert abs(value - true) <= resolution / 2 + 1e-6, (name, value, true)
                        errors[name].append(abs(value - targets[name]))
                for status in [m for m in fresh if m.get_type() == "ACTUATOR_OUTPUT_STATUS"]:
                    for name, (n, resolution) in SERVOS.items():
                        assert status.active >> (n - 1) & 1, name
                        angle = pwm_to_angle(status.actuator[n - 1], -1, 1, (-90, 90))
                        assert angle == pytest.approx(
                            servos[name].position_deg, abs=resolution / 2 + 1e-3
                        )
                        normalized_checked += 1
        finally:
            peer.close()
        summary = bridge.stop()

    assert normalized_checked > 0
    for name, (_, resolution) in SERVOS.items():
        assert statistics.mean(errors[name]) <= resolution / 2, name
        assert max(errors[name]) <= resolution / 2 + 1e-6, name
    # the whole-degree profiles do show their rounding (the comparison is not vacuous)
    assert max(errors["rmd"]) > 0.1
    for name in SERVOS:
        frames = summary["servos"][name]["frames"]
        assert frames["sent"] > 0 and frames["received"] > 0, name
        assert frames["lost"] == 0 and frames["rejected"] == 0, (name, frames)
    assert summary["buses"]["bus0"]["bus_rejected"] == 0
    commands = summary["mavlink"]["commands"]
    assert summary["backend"]["accepted"] >= 3 * len(STEPS), commands
