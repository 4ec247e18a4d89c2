"""The LED model's error learnt from measured lights (processing.model_error) and the α rule it sits beside."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from msflash.processing.accumulate import accumulate_statistics
from msflash.processing.ambient import (
    ALPHA_GRID,
    DISCREPANCY_SIGMAS,
    AmbientModel,
    _solve_penalised,
    discrepancy_alpha,
    estimate_ambient,
)
from msflash.processing.light_library import lights_of
from msflash.processing.model_error import (
    EXPECTED_RATIO_WARNING,
    MISS_RATIO,
    light_reference,
    model_error,
    reference_for,
    with_model_error,
)
from tests.helpers import ambient, camera, leds_photons, linear_frames, spectrum_rmse


def test_a_light_in_the_leds_span_is_estimated_exactly_and_lights_outside_it_are_not() -> None:
    leds, cam = leds_photons(), camera().to_unit("photons")
    mixes = leds.replace(
        values=leds.values @ np.array([[1, 0.2], [0.5, 0.1], [0, 1], [0.3, 0], [1, 0.4], [0.2, 0.9], [0.1, 0.1]]),
        names=("mix1", "mix2"),
    )
    reference = light_reference(leds, cam, lights=mixes)
    np.testing.assert_allclose(reference.rmse, 0.0, atol=1e-6)
    np.testing.assert_allclose(reference.bounds, 0.0, atol=1e-6)
    held = light_reference(leds, cam, lights=lights_of("held_out"))
    assert np.all(held.bounds > 0) and np.median(held.rmse) > np.median(held.bounds) * 0.8
    # the error is the estimate minus the truth scaled onto it, in the paper's normalisation
    assert np.allclose(np.max(np.abs(held.estimates), axis=0), 1.0)


def test_the_model_band_scales_with_the_estimate_and_grows_with_its_noise() -> None:
    reference = reference_for(leds_photons(), camera().to_unit("photons"))
    spectrum = reference.estimates[:, 3] * 40.0
    quiet = model_error(reference, spectrum, np.zeros_like(spectrum))
    loud = model_error(reference, spectrum, np.full_like(spectrum, 40.0))
    again = model_error(reference, spectrum / 40.0, np.zeros_like(spectrum))
    np.testing.assert_allclose(quiet.spectrum_std, 40.0 * again.spectrum_std)
    assert loud.expected_ratio > quiet.expected_ratio and loud.miss_risk >= quiet.miss_risk
    assert loud.expected_ratio > MISS_RATIO


def test_with_model_error_widens_the_band_says_what_it_means_and_warns_on_a_likely_miss() -> None:
    leds = leds_photons()
    a, f, spec = linear_frames(ambient("tungsten"))
    estimate = estimate_ambient(accumulate_statistics(a, f, spec), leds)
    reference = reference_for(leds, camera().to_unit("photons"))
    widened = with_model_error(estimate, reference)
    np.testing.assert_array_equal(widened.noise_std, estimate.spectrum_std)
    assert np.all(widened.spectrum_std >= estimate.spectrum_std) and np.any(
        widened.spectrum_std > estimate.spectrum_std
    )
    assert "model's error" in widened.band_meaning and "pixel noise only" in estimate.band_meaning
    swinging = replace(
        estimate, spectrum_std=np.full_like(estimate.spectrum_std, np.max(estimate.spectrum.values)), noise_std=None
    )
    noisy = with_model_error(swinging, reference)
    assert noisy.expected_ratio >= EXPECTED_RATIO_WARNING
    assert any("may be off by more than" in warning for warning in noisy.warnings)


def test_discrepancy_alpha_regularises_up_to_the_noise_and_no_further() -> None:
    model = AmbientModel(leds_photons())
    terms = model.terms
    a, f, spec = linear_frames(ambient("tungsten"))
    clean = accumulate_statistics(a, f, spec)
    chosen = discrepancy_alpha(clean, clean, terms)
    scale = terms.penalty_scale(clean)
    # The residual's rise with α, from its weight-dependent part (the ambient's energy cancels in it).
    residuals = [clean.fit_energy(_solve_penalised(clean, terms, alpha * scale, True, "t")) for alpha in ALPHA_GRID]
    least = residuals[0]
    allowed = least + DISCREPANCY_SIGMAS * clean.n_leds * clean.residual_energy(
        _solve_penalised(clean, terms, ALPHA_GRID[0] * scale, True, "t")
    ) / (clean.n_samples - clean.n_leds)
    index = int(np.flatnonzero(ALPHA_GRID == chosen)[0])
    assert residuals[index] <= allowed + 1e-9 * abs(allowed)
    if index + 1 < ALPHA_GRID.size:
        assert residuals[index + 1] > allowed
    weights, used = model.weights(clean)
    assert used == chosen
    estimate = estimate_ambient(clean, leds_photons())
    assert spectrum_rmse(estimate.spectrum.values[:, 0], ambient("tungsten").values[:, 0]) < 0.25


def test_discrepancy_alpha_does_not_depend_on_the_denoised_ambient_energy() -> None:
    """The rise r(α) − r(α₀) holds no ambient energy: denoised statistics whose ambient energy less its noise
    falls below the fit's (the noise's sampling error, most often with the few samples of a Bayer frame) must
    choose the α they choose otherwise. Compared as residuals clipped at 0, every rise was hidden there and α
    ran to the top of the grid (the Bayer demo's misses, docs/raw-frames.md)."""
    model = AmbientModel(leds_photons())
    terms = model.terms
    a, f, spec = linear_frames(ambient("tungsten"))
    observed = accumulate_statistics(a, f, spec)
    least = _solve_penalised(observed, terms, ALPHA_GRID[0] * terms.penalty_scale(observed), True, "t")
    reference = discrepancy_alpha(observed, observed, terms)
    below = replace(observed, ambient_energy=observed.ambient_energy - observed.residual_energy(least) * 1.5)
    assert below.residual_energy(least) == 0.0  # the denoised residual reads 0 at α₀
    assert discrepancy_alpha(below, observed, terms) == reference
    assert reference < 1e-3
