"""The link plan of a ``mavlink-can`` bus: frames per second and their bytes on the MAVLink
link, refused with what would fit when a serial link cannot carry them."""

from __future__ import annotations

import io
from pathlib import Path

import pytest

from mavservo.app.check import check_main
from mavservo.config import ConfigError, load_config_text
from mavservo.config.tunnel_plan import tunnel_filter_ids, tunnel_keeps_extended, tunnel_plans
from mavservo.mavlink import tunnel_wire_bytes


def config_text(
    *, url: str = "/dev/ttyAMA0", baud: int = 57_600, servos: int = 4, period: float = 0.02
) -> str:
    rows = "\n".join(
        f"  - {{name: s{i}, profile: rmd-x, can_id: {i}, telemetry_hz: 10}}"
        for i in range(1, servos + 1)
    )
    return (
        f"mavlink: {{url: {url}, baud: {baud}}}\n"
        "can:\n  buses: [{name: fc, interface: mavlink-can, channel: 1}]\n"
        f"scheduler: {{command_period_s: {period}}}\n"
        f"servos:\n{rows}\n"
    )


def test_4_servos_at_50_hz_do_not_fit_a_57600_baud_link_and_it_says_what_would() -> None:
    with pytest.raises(ConfigError) as caught:
        load_config_text(config_text(), "fc.yaml")
    text = str(caught.value)
    assert "does not fit" in text and "57,600-baud" in text
    assert "at most 2 servo(s)" in text  # fewer servos
    assert "rates lowered to" in text  # lower rates
    assert "mavlink.baud 115,200" in text  # a faster baud
    assert "fc.yaml:3" in text  # the bus's line


def test_the_same_servos_fit_at_921600_and_the_plan_counts_both_directions() -> None:
    config = load_config_text(config_text(baud=921_600), "fc.yaml")
    (plan,) = tunnel_plans(config)
    wire = tunnel_wire_bytes()
    # 4 x (50 commands + 10 polls) out, as many replies back plus the autopilot's own 30/s
    assert plan.out_hz == pytest.approx(240) and plan.in_hz == pytest.approx(270)
    assert plan.out_bytes_s == pytest.approx(240 * wire.frame + 2 * wire.request)
    assert plan.in_bytes_s == pytest.approx(270 * wire.frame + 2 * wire.ack)
    assert plan.fits and plan.capacity_bytes_s == 92_160


def test_two_servos_at_10_hz_fit_57600_as_measured_through_sitl() -> None:
    text = config_text(servos=2, period=0.1).replace("telemetry_hz: 10", "telemetry_hz: 1")
    (plan,) = tunnel_plans(load_config_text(text, "fc.yaml"))
    assert plan.fits


def test_a_network_link_is_not_checked_against_a_baud() -> None:
    (plan,) = tunnel_plans(load_config_text(config_text(url="udpin:0.0.0.0:14550"), "fc.yaml"))
    assert plan.baud is None and plan.fits


def test_a_signed_link_costs_13_bytes_more_per_frame() -> None:
    assert tunnel_wire_bytes(True).frame == tunnel_wire_bytes().frame + 13 == 41


def test_one_mavlink_can_bus_per_autopilot() -> None:
    text = (
        config_text(baud=921_600)
        .replace(
            "[{name: fc, interface: mavlink-can, channel: 1}]",
            "[{name: fc, interface: mavlink-can, channel: 1}, "
            "{name: fc2, interface: mavlink-can, channel: 2}]",
        )
        .replace("telemetry_hz: 10}", "telemetry_hz: 10, bus: fc}")
    )
    with pytest.raises(ConfigError, match="only one mavlink-can bus per autopilot"):
        load_config_text(text, "fc.yaml")


@pytest.mark.parametrize("channel", [0, 4, "sim", "can0"])
def test_the_channel_is_the_autopilots_bus_number(channel: object) -> None:
    text = config_text(baud=921_600).replace("channel: 1", f"channel: {channel}")
    with pytest.raises(ConfigError, match="CAN_P1..CAN_P3"):
        load_config_text(text, "fc.yaml")


def test_dronecan_frames_are_kept_only_for_a_family_that_answers_with_29_bit_ids() -> None:
    config = load_config_text(config_text(baud=921_600), "fc.yaml")
    assert not tunnel_keeps_extended(config, config.can.buses[0])
    robstride = config_text(baud=921_600, servos=1).replace("rmd-x", "robstride")
    config = load_config_text(robstride, "fc.yaml")
    assert tunnel_keeps_extended(config, config.can.buses[0])


def test_check_prints_the_plan_and_refuses_what_does_not_fit(tmp_path: Path) -> None:
    good, bad = tmp_path / "good.yaml", tmp_path / "bad.yaml"
    good.write_text(config_text(baud=921_600))
    bad.write_text(config_text())
    out, err = io.StringIO(), io.StringIO()
    assert check_main([str(good)], out, err) == 0
    assert "link plan: bus 'fc' (mavlink-can)" in out.getvalue() and ": fits" in out.getvalue()
    out, err = io.StringIO(), io.StringIO()
    assert check_main([str(bad)], out, err) == 2
    assert "does not fit" in err.getvalue()


def test_filter_keys_are_those_of_the_servos_reply_ids() -> None:
    config = load_config_text(config_text(baud=921_600), "fc.yaml")
    assert tunnel_filter_ids(config, config.can.buses[0]) == [2]  # RMD-X replies 0x241..0x244
    robstride = config_text(baud=921_600, servos=1).replace("rmd-x", "robstride")
    config = load_config_text(robstride, "fc.yaml")
    assert tunnel_filter_ids(config, config.can.buses[0]) is None  # 29-bit: no filter


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ("{keepalive_s: 6.0}", "keepalive_s must be in"),  # past ArduPilot's 5 s: never kept
        ("{keepalive_s: 1.0, forward_timeout_s: 1.5}", "must exceed two keep-alives"),
        ("{rx_queue_frames: 1}", "rx_queue_frames must be in"),
    ],
)
def test_options_a_stranger_can_set_are_bounded(options: str, message: str) -> None:
    text = config_text(baud=921_600).replace("channel: 1}", f"channel: 1, options: {options}}}")
    with pytest.raises(ConfigError, match=message):
        load_config_text(text, "fc.yaml")
