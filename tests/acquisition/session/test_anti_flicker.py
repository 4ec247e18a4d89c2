"""Anti-flicker exposures (acquisition/session/anti_flicker.py): whole flicker periods where the exposure allows."""

from __future__ import annotations

import math

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
