"""Anti-flicker exposures (acquisition/session/anti_flicker.py): whole flicker periods where the exposure allows."""

from __future__ import annotations

import math

import numpy as np
import pytest

from msflash.acquisition.session.anti_flicker import flicker_period_us, whole_periods, with_anti_flicker
from msflash.acquisition.session.exposure import ExposurePlan, ExposurePolicy


def _plan(ambient_us: float, leds_us: tuple[float, ...]) -> ExposurePlan:
    nan = (math.nan,) * len(leds_us)
    return ExposurePlan(ambient_us, leds_us, nan, "photon+read noise", (20.0, 1e6), ExposurePolicy())


@pytest.mark.parametrize("choice, period", [("50", 10_000.0), ("60", 1e6 / 120), ("auto", 50_000.0)])
def test_exposures_become_whole_periods_never_much_longer(choice: str, period: float) -> None:
    planned = _plan(63_000.0, (120_000.0, 51_000.0, 99_000.0))
    plan = with_anti_flicker(planned, choice)
    for before, after in zip(
        (planned.ambient_exposure_us, *planned.led_exposures_us), (plan.ambient_exposure_us, *plan.led_exposures_us)
    ):
        periods = after / period
        assert periods >= 1 and abs(periods - round(periods)) < 1e-9
        assert after <= before * 1.05 + 1e-6
    assert plan.warnings == []


def test_exposures_shorter_than_a_period_are_kept_and_named() -> None:
    plan = with_anti_flicker(_plan(25_000.0, (2_000.0, 12_000.0)), "50")
    assert (plan.ambient_exposure_us, plan.led_exposures_us) == (20_000.0, (2_000.0, 10_000.0))
    (warning,) = plan.warnings
    assert "LED 1 2000 µs" in warning and "ambient 2" not in warning and "10.00 ms" in warning


def test_off_leaves_the_plan_alone_and_a_bad_choice_is_refused() -> None:
    planned = _plan(3_000.0, (2_000.0,))
    assert with_anti_flicker(planned, "off") is planned
    assert flicker_period_us("off") is None and whole_periods(9_600.0, 10_000.0) == 10_000.0
    with pytest.raises(ValueError, match="anti_flicker"):
        ExposurePolicy(anti_flicker="55")


def test_the_flash_recapture_is_whole_periods_on_the_sim_rig() -> None:
    """The flash frame's predicted exposure (run's re-capture) is rounded like the sequence's, on the sim rig's booth
    (an emulator on a pty, PWM-dimmed when the host paces it): whole flicker periods win over whole PWM periods, and
    the PWM's energy error is then what is warned about; too short an exposure is kept and named."""
    import warnings

    from msflash.acquisition.session.anti_flicker import FlashFlickerWarning
    from msflash.acquisition.session.exposure import FlashEnergyWarning
    from msflash.acquisition.session.rig import open_rig
    from msflash.acquisition.session.run_exposure import flash_exposure_for

    def auto(choice: str) -> ExposurePlan:
        policy = ExposurePolicy(anti_flicker=choice)
        return ExposurePlan(9_000.0, (9_000.0,) * 7, (math.nan,) * 7, "photon+read noise", (20.0, 1e6), policy)

    full, dimmed = np.eye(7)[1], np.full(7, 0.5)
    with open_rig("sim") as rig, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert flash_exposure_for(rig, auto("50"), full, lambda _: 23_000.0) == 20_000.0
        assert flash_exposure_for(rig, auto("60"), full, lambda _: 17_000.0) == pytest.approx(2e6 / 120)
        assert not caught
        assert flash_exposure_for(rig, auto("50"), dimmed, lambda _: 31_000.0) == 30_000.0
        (pwm,) = caught
        assert issubclass(pwm.category, FlashEnergyWarning) and "PWM" in str(pwm.message)
        caught.clear()
        short = flash_exposure_for(rig, auto("50"), full, lambda _: 4_000.0)
        (warning,) = caught
        assert short == 4_000.0 and issubclass(warning.category, FlashFlickerWarning)
        assert "flash exposure 4000 µs: shorter than one flicker period (10.00 ms, --anti-flicker 50)" in str(
            warning.message
        )
        caught.clear()
        assert flash_exposure_for(rig, auto("off"), full, lambda _: 23_000.0) == 23_000.0 and not caught
