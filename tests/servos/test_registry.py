"""The profile registry and the self-describing contract (issue 18): names, plug-ins that fail to
load, per-servo options with FILE:LINE errors, lifecycle frames on the simulated devices."""

from __future__ import annotations

import struct
from collections.abc import Iterator
from importlib.metadata import EntryPoint

import can
import pytest

from mavservo.config import ConfigError, load_config_text
from mavservo.servos import CubeMarsAK, Releasing, RmdX, ServoProfile, registry, release_frames_of
from mavservo.servos.base import FrameId, ProfileOptions, SimDevice, SimMotor
from mavservo.sim.servo import SimServo


class _NotAProfile:
    """What a plug-in author might point the entry point at by mistake."""


class _CopyOfRmdX(RmdX):
    """A well-formed plug-in: an RMD-X under another name."""

    name = "copy-of-rmd-x"


@pytest.fixture
def plugins(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """The entry-point group holds one good plug-in and three broken ones."""
    group = registry.ENTRY_POINT_GROUP
    fake = [
        EntryPoint("copy-of-rmd-x", f"{__name__}:_CopyOfRmdX", group),
        EntryPoint("broken-import", "no_such_package_for_mavservo.servo:Servo", group),
        EntryPoint("not-a-profile", f"{__name__}:_NotAProfile", group),
        EntryPoint("rmd-x", f"{__name__}:_CopyOfRmdX", group),
    ]
    monkeypatch.setattr(registry, "entry_points", lambda group: fake)
    registry.reload()
    yield
    registry.reload()


def test_unknown_profile_lists_the_known_ones_and_where_plugins_come_from() -> None:
    with pytest.raises(registry.UnknownProfileError) as info:
        registry.get_profile("dynamixel-x")
    message = str(info.value)
    assert "'dynamixel-x'" in message
    assert ", ".join(sorted(registry.names())) in message
    assert "'mavservo.profiles' entry points" in message


@pytest.mark.usefixtures("plugins")
def test_a_broken_plugin_is_reported_by_name_without_hiding_the_others() -> None:
    assert registry.get_profile("copy-of-rmd-x") is _CopyOfRmdX
    assert registry.get_profile("rmd-x") is RmdX, "a plug-in never replaces a built-in"
    errors = {error.entry_point: error.reason for error in registry.load_errors()}
    assert set(errors) == {"broken-import", "not-a-profile", "rmd-x"}
    assert "ModuleNotFoundError" in errors["broken-import"]
    assert "not a mavservo.servos.ServoProfile" in errors["not-a-profile"]
    assert "already taken by built-in" in errors["rmd-x"]
    with pytest.raises(registry.UnknownProfileError, match="'broken-import'.*failed to load"):
        registry.get_profile("broken-import")


@pytest.mark.usefixtures("plugins")
def test_a_config_names_a_plugin_profile_and_a_broken_one_is_named_at_its_line() -> None:
    text = """\
servos:
  - {name: a, profile: copy-of-rmd-x, can_id: 1}
  - name: b
    profile: broken-import
    can_id: 2
"""
    with pytest.raises(ConfigError) as info:
        load_config_text(text, "bad.yaml")
    [line] = str(info.value).splitlines()
    assert line.startswith("bad.yaml:4: servos[1].profile: unknown servo profile")
    assert "plug-in profile 'broken-import'" in line and "ModuleNotFoundError" in line


OPTIONS_BASE = """\
servos:
  - name: pan
    profile: cubemars-ak
    can_id: 2
    options:
"""


@pytest.mark.parametrize(
    ("option", "expected"),
    [
        (
            "      pole_pairs: 99",
            "servos[0].options.pole_pairs: Input should be less than or equal",
        ),
        ("      pole_pairs: 99", "(allowed: 1..64, optional; default null)"),
        ("      polepairs: 14", "unknown option 'polepairs'; allowed options: model, pole_pairs"),
        ("      model: AK99", "allowed: one of: AK10-9, AK60-6"),
        ("      pole_pairs: yes", "Input should be a valid integer"),
    ],
)
def test_a_bad_option_gives_file_line_key_and_allowed_range(option: str, expected: str) -> None:
    with pytest.raises(ConfigError) as info:
        load_config_text(OPTIONS_BASE + option + "\n", "opts.yaml")
    [line] = str(info.value).splitlines()
    assert line.startswith("opts.yaml:6: servos[0].options.")
    assert expected in line


def test_an_id_outside_the_profiles_range_names_the_range() -> None:
    with pytest.raises(ConfigError, match=r"servos\[0\]\.can_id: rmd-x servo ids are 1\.\.32"):
        load_config_text("servos:\n  - {name: a, profile: rmd-x, can_id: 33}\n", "ids.yaml")


def test_options_reach_the_profile_the_budget_and_the_simulated_device() -> None:
    config = load_config_text(OPTIONS_BASE + "      model: AK60-6\n", "ok.yaml")
    [servo] = config.servos
    profile = servo.make_profile()
    assert isinstance(profile, CubeMarsAK)
    assert profile.erpm_per_dps == pytest.approx(14 * 6 / 6)  # AK60-6: 14 pole pairs, 6:1
    sim = SimServo("cubemars-ak", 2, options=servo.profile_options())
    sim.receive(profile.position_command(90.0, 100.0), 0.0)
    [(_, status)] = sim.poll(0.05) or sim.poll(0.2)
    state = profile.decode(status, 0.2)
    assert state is not None
    assert state.velocity_dps == pytest.approx(sim.velocity_dps, abs=10 / profile.erpm_per_dps)


def test_cubemars_velocity_decodes_with_the_models_pole_pairs() -> None:
    """One status frame, two models: 1000 rotor ERPM is 1000 / (pole pairs x gear / 6) output
    deg/s (item 5; issue 27 finding 4: the gear ratio)."""
    frame = can.Message(
        arbitration_id=0x2902, is_extended_id=True, data=struct.pack(">hhhbB", 0, 100, 0, 25, 0)
    )
    ak80 = CubeMarsAK(2).decode(frame, 0.0)
    ak60 = CubeMarsAK(2, model="AK60-6").decode(frame, 0.0)
    assert ak80 is not None and ak60 is not None
    assert ak80.velocity_dps == pytest.approx(1000 / (21 * 9 / 6))
    assert ak60.velocity_dps == pytest.approx(1000 / (14 * 6 / 6))
    assert CubeMarsAK(2, model="AK60-6", pole_pairs=7).erpm_per_dps == pytest.approx(7 * 6 / 6)


def test_rmdx_start_up_frame_sets_the_servos_own_communication_timeout() -> None:
    [frame] = RmdX(3, comm_timeout_ms=250).startup_frames()
    assert (frame.arbitration_id, frame.is_extended_id) == (0x143, False)
    assert bytes(frame.data) == bytes.fromhex("B3000000FA000000")  # 250 ms, little-endian u32
    lk_startup = [bytes(f.data) for f in registry.get_profile("lk")(3).startup_frames()]
    assert lk_startup == [bytes.fromhex("8800000000000000")], "LK-Tech: motor on, no 0xB3"


def test_rmdx_release_turns_the_simulated_motor_off_and_a_command_runs_it_again() -> None:
    profile, sim = RmdX(1), SimServo("rmd-x", 1)
    sim.receive(profile.position_command(90.0, 360.0), 0.0)
    [release] = profile.release_frames()
    assert bytes(release.data) == bytes([0x80, 0, 0, 0, 0, 0, 0, 0])
    [(_, echo)] = sim.receive(release, 0.1)
    assert bytes(echo.data) == bytes(release.data) and profile.is_reply(echo)
    assert not sim.enabled
    stopped_at = sim.position_deg
    sim.advance(1.0)
    assert sim.position_deg < 90.0 - 1.0 and sim.position_deg == pytest.approx(stopped_at, abs=20)
    sim.receive(profile.position_command(90.0, 360.0), 1.0)
    sim.advance(2.0)
    assert sim.enabled and sim.position_deg == pytest.approx(90.0, abs=0.5)


def test_rmdx_servo_turns_its_motor_off_when_its_own_timeout_expires() -> None:
    profile, sim = RmdX(1, comm_timeout_ms=200), SimServo("rmd-x", 1)
    for frame in profile.startup_frames():
        sim.receive(frame, 0.0)
    sim.receive(profile.position_command(10.0), 0.01)
    sim.poll(0.15)
    assert sim.enabled, "within its timeout"
    sim.poll(0.5)
    assert not sim.enabled, "silent for longer than its 0xB3 timeout"


def test_cubemars_servo_mode_cannot_release() -> None:
    assert not isinstance(CubeMarsAK(1), Releasing)
    assert release_frames_of(CubeMarsAK(1)) == []


def test_frame_id_overlap_follows_masks_and_first_byte() -> None:
    std = FrameId(0x141, False, "to_servo", "command")
    assert std.overlaps(FrameId(0x141, False, "from_servo", "reply"))
    assert not std.overlaps(FrameId(0x141, True, "from_servo", "reply"))
    masked = FrameId(0x02_00FD_05, True, "from_servo", "push", id_mask=0x1F00_00FF)
    assert masked.overlaps(FrameId(0x02_12FD_05, True, "to_servo", "command"))
    assert not masked.overlaps(FrameId(0x02_00FD_06, True, "to_servo", "command"))
    a = FrameId(0x11, False, "from_servo", "reply", first_byte=(0x01, 0x0F))
    assert not a.overlaps(FrameId(0x11, False, "from_servo", "reply", first_byte=(0x02, 0x0F)))
    assert a.overlaps(FrameId(0x11, False, "to_servo", "command"))


def test_a_profile_without_identifiers_or_device_is_refused_by_the_registry() -> None:
    class Incomplete(ServoProfile):
        name = "incomplete"

        def position_command(self, angle_deg: float, max_speed_dps: float | None = None):  # type: ignore[no-untyped-def]
            raise NotImplementedError

        def telemetry_requests(self) -> list[can.Message]:
            return []

        def is_reply(self, msg: can.Message) -> bool:
            return False

        def decode(self, msg, timestamp):  # type: ignore[no-untyped-def]
            return None

        @classmethod
        def sim_device(cls, motor: SimMotor, can_id: int, options: ProfileOptions) -> SimDevice:
            raise NotImplementedError

    reason = registry._problem("incomplete", Incomplete, {})
    assert reason is not None and "identifiers" in reason


@pytest.mark.usefixtures("plugins")
def test_check_names_a_broken_plugin_and_still_checks_and_lists_the_others(tmp_path) -> None:
    import io

    from mavservo.app.check import check_main

    config = tmp_path / "ok.yaml"
    config.write_text("servos:\n  - {name: a, profile: copy-of-rmd-x, can_id: 1}\n")
    out, err = io.StringIO(), io.StringIO()
    assert check_main(["--profiles", str(config)], out, err) == 0
    assert "plug-in profile 'broken-import'" in err.getvalue()
    assert "ModuleNotFoundError" in err.getvalue()
    listing = out.getvalue()
    assert "copy-of-rmd-x" in listing and "rmd-x  (built-in" in listing
    assert f"{config}: valid" in listing


@pytest.mark.usefixtures("plugins")
def test_run_names_a_broken_plugin_and_runs_with_the_others(tmp_path, capsys) -> None:
    from mavservo.app.run import main
    from tests.support.waiting import free_udp_port

    config = tmp_path / "ok.yaml"
    config.write_text("servos:\n  - {name: a, profile: copy-of-rmd-x, can_id: 1}\n")
    url = f"udpin:127.0.0.1:{free_udp_port()}"
    status = main(["--config", str(config), "--duration", "1", "--no-log", "-q", "--mavlink", url])
    err = capsys.readouterr().err
    assert status == 0, err
    assert "warning: plug-in profile 'broken-import'" in err
