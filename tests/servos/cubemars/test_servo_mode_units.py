"""CubeMars AK servo mode: speeds are electrical RPM of the rotor, positions degrees of the
output, so the conversion needs the module's reduction as well as its pole pairs (issue 27
finding 4; the manual's servo-mode tables and product parameters)."""

from __future__ import annotations

import pytest

from mavservo.servos import CubeMarsAK
from mavservo.servos.cubemars.profile import MODEL_GEAR_RATIO, MODEL_POLE_PAIRS
from mavservo.sim.servo import SimServo


@pytest.mark.parametrize("model", sorted(MODEL_GEAR_RATIO))
def test_the_gear_ratio_is_the_models(model: str) -> None:
    profile = CubeMarsAK(1, model=model)
    expected = MODEL_POLE_PAIRS[model] * float(model.split("-")[1]) / 6
    assert profile.erpm_per_dps == pytest.approx(expected)


def test_the_gear_ratio_option_overrides_the_model() -> None:
    assert CubeMarsAK(1, gear_ratio=1.0).erpm_per_dps == pytest.approx(21 / 6)
    with pytest.raises(ValueError):
        CubeMarsAK(1, gear_ratio=0.5)


def test_a_speed_limit_moves_the_output_at_that_speed() -> None:
    """Through the simulated module (which converts with its own reading of the manual): a
    100 deg/s limit takes about 0.9 s for 90 output degrees, not 0.1 s."""
    profile = CubeMarsAK(1)
    servo = SimServo("cubemars-ak", 1, options=profile.options)
    servo.receive(profile.position_command(90.0, 100.0), 0.0)
    assert servo.speed_limit_dps == pytest.approx(100.0, rel=0.01)
    servo.poll(0.0)  # arms the push timer
    reports = [profile.decode(frame, t) for t, frame in servo.poll(0.45)]
    state = next(s for s in reversed(reports) if s is not None)
    assert 20.0 < state.position_deg < 70.0  # halfway, not there yet
    assert state.velocity_dps == pytest.approx(100.0, rel=0.05)
