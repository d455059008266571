"""``check`` warns when a servo's own communication timeout or watchdog is not longer than the
longest gap between the commands that keep it alive (the profile's ``comm_timeout_s``).

A Damiao motor disables itself after its TIMEOUT register's time without a frame, an ODrive
axis disarms when its watchdog expires, a CubeMars driver stops past its R-Link timeout: a
bridge that refreshes a held setpoint less often than that stops the servo while it holds.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from mavservo.config.loader import load_config_with_warnings
from mavservo.config.semantic import longest_command_gap_s
from mavservo.servos import comm_timeout_of, get_profile
from tests.app.test_run_cli import run_mavservo as mavservo

WARNING = "stops by itself after"


def _config(tmp_path: Path, servo: str, refresh_s: float, period_s: float = 0.05) -> Path:
    path = tmp_path / "rig.yaml"
    path.write_text(
        "servos:\n"
        f"  - {servo}\n"
        "channels:\n"
        "  - {servo: s, source: servo_output, channel: 1}\n"
        "scheduler:\n"
        f"  command_period_s: {period_s}\n"
        f"  refresh_interval_s: {refresh_s}\n"
    )
    return path


def _warnings(path: Path) -> list[str]:
    _, problems = load_config_with_warnings(path)
    return [p.format(str(path)) for p in problems if WARNING in p.message]


@pytest.mark.parametrize(
    ("servo", "refresh_s", "warned"),
    [
        # Damiao: TIMEOUT 200 ms (the default)
        ("{name: s, profile: damiao-dm, can_id: 1, options: {comm_timeout_ms: 200}}", 0.3, True),
        ("{name: s, profile: damiao-dm, can_id: 1, options: {comm_timeout_ms: 200}}", 0.2, True),
        ("{name: s, profile: damiao-dm, can_id: 1, options: {comm_timeout_ms: 200}}", 0.1, False),
        ("{name: s, profile: damiao-dm, can_id: 1, options: {comm_timeout_ms: 1000}}", 0.3, False),
        # ODrive: the watchdog (0.5 s by default; 0: off)
        ("{name: s, profile: odrive, can_id: 1}", 0.6, True),
        ("{name: s, profile: odrive, can_id: 1, options: {watchdog_timeout_s: 0}}", 0.6, False),
        # CubeMars MIT: the R-Link timeout (0: none, the default)
        (
            "{name: s, profile: cubemars-ak-mit, can_id: 1, options: {comm_timeout_ms: 100}}",
            0.2,
            True,
        ),
        ("{name: s, profile: cubemars-ak-mit, can_id: 1}", 0.2, False),
        # a profile that declares none
        ("{name: s, profile: rmd-x, can_id: 1}", 5.0, False),
    ],
)
def test_keep_alive_not_shorter_than_the_servos_timeout_warns_at_its_line(
    tmp_path: Path, servo: str, refresh_s: float, warned: bool
) -> None:
    path = _config(tmp_path, servo, refresh_s)
    warnings = _warnings(path)
    if not warned:
        assert warnings == []
        return
    assert len(warnings) == 1
    assert warnings[0].startswith(f"{path}:2: servos[0]"), warnings
    assert f"every {longest_command_gap_s(refresh_s, 0.05) * 1000:g} ms" in warnings[0]


def test_the_shipped_configs_keep_their_servos_alive() -> None:
    for name in ("damiao", "cubemars-mit", "odrive", "dronecan"):
        path = Path("config") / f"{name}.yaml"
        if path.exists():
            assert _warnings(path) == [], name


@pytest.mark.parametrize(
    ("refresh_s", "period_s"), [(0.2, 0.05), (0.22, 0.05), (0.24, 0.05), (0.5, 0.2), (0.05, 0.05)]
)
def test_the_longest_gap_is_what_the_scheduler_does(refresh_s: float, period_s: float) -> None:
    """The figure ``check`` uses against the scheduler's core driven slot by slot (no clock):
    the refresh is due from ``refresh - period / 2``, so it goes on that slot or the next."""
    from mavservo.scheduling.schedule_core import ScheduleCore, ServoSpec, TimingConfig

    timing = TimingConfig(command_period_s=period_s, refresh_interval_s=refresh_s)
    core = ScheduleCore([ServoSpec("s", get_profile("rmd-x")(1), telemetry_hz=0)], timing, 0.0)
    assert core.submit("s", 10.0, "test", 0.0).accepted
    written: list[float] = []
    now = 0.0
    for _ in range(400):  # bounded: 400 steps
        decision = core.step(now)
        for out in decision.frames:
            core.sent(out, now)
            if out.kind in ("command", "refresh"):
                written.append(now)
        now = core.next_deadline(now)
    gaps = [b - a for a, b in zip(written, written[1:], strict=False)]
    assert len(gaps) > 3
    assert max(gaps) == pytest.approx(longest_command_gap_s(refresh_s, period_s))


def test_profiles_without_a_timeout_declare_none() -> None:
    assert comm_timeout_of(get_profile("rmd-x")(1)) is None
    assert comm_timeout_of(get_profile("dronecan")(1)) is None


def test_check_prints_the_warning(tmp_path: Path) -> None:
    path = _config(
        tmp_path, "{name: s, profile: damiao-dm, can_id: 1, options: {comm_timeout_ms: 150}}", 0.2
    )
    proc = mavservo("check", str(path))
    assert proc.returncode == 0, proc.stderr
    lines = [line for line in proc.stdout.splitlines() if WARNING in line]
    assert len(lines) == 1 and "150 ms" in lines[0] and f"{path}:2:" in lines[0], proc.stdout
