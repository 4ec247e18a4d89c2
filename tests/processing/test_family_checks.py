"""The miss checks (processing/family_checks.py, issue 30 item 4): the LEDs' split-half reading."""

from __future__ import annotations

import numpy as np

from msflash.processing.channel_statistics import ChannelStatistics, Moments
from msflash.processing.family_checks import LED_HALF_WARNING, LED_WARNING, predicted_ratio, split_half_ratio
from msflash.processing.light_families import SPLIT_HALVES, family_model
from msflash.processing.light_forms import planck
from tests.processing.test_light_families import GRID, _leds_and_camera, _statistics


def _checked(statistics: ChannelStatistics) -> tuple[float, bool]:
    """The LEDs' split-half ratio and whether their check warns, the LEDs' own span fit standing for their estimate."""
    leds, camera = _leds_and_camera()
    estimate = family_model(statistics.channels, leds, camera).estimate(statistics)
    assert len(estimate.led_halves) == len(SPLIT_HALVES)
    led_estimate = estimate.led.fit.spectrum
    family = estimate.spectrum.values[:, 0]
    check = predicted_ratio(led_estimate, family, leds.values, LED_WARNING, "LEDs'", estimate.led_halves)
    return split_half_ratio(led_estimate, estimate.led_halves, family, leds.values), check.warned


def test_a_light_the_pixels_pin_reads_the_same_from_either_half() -> None:
    light = planck(GRID.wavelengths_nm, 4000.0) * GRID.wavelengths_nm
    ratio, _ = _checked(_statistics(light, seed=3))
    assert ratio < 0.1 * LED_HALF_WARNING


def test_halves_that_read_different_lights_warn() -> None:
    """Folds 0, 2, 4 under a warm blackbody, 1 and 3 under a cool one: no single light explains the frame, and the
    halves say so even where the estimate's distance from the family's does not."""
    nm = GRID.wavelengths_nm
    warm, cool = (_statistics(planck(nm, kelvin) * nm, seed=5) for kelvin in (2200.0, 9000.0))
    pick = [warm if fold in SPLIT_HALVES[0] else cool for fold in range(warm.n_folds)]
    moments = Moments(
        *(np.array([getattr(s.moments, name)[fold] for fold, s in enumerate(pick)]) for name in ("ff", "fa", "aa"))
    )
    mixed = ChannelStatistics(
        moments, None, warm.counts, warm.led_sums, warm.ambient_sums, warm.n_blocks_total, warm.n_leds, warm.channels
    )
    ratio, warned = _checked(mixed)
    assert ratio >= LED_HALF_WARNING and warned


def test_without_halves_the_check_is_the_distance_alone() -> None:
    leds, _ = _leds_and_camera()
    family = planck(GRID.wavelengths_nm, 3000.0)
    estimate = leds.values @ np.ones(leds.count)
    alone = predicted_ratio(estimate, family, leds.values, LED_WARNING, "LEDs'")
    same = predicted_ratio(estimate, family, leds.values, LED_WARNING, "LEDs'", (estimate, estimate))
    assert split_half_ratio(estimate, (), family, leds.values) == 0.0
    assert same.predicted_ratio == alone.predicted_ratio
