"""The ambient estimate's pixel-noise band (:mod:`processing.ambient_band`): the sandwich where ``I w ≥ 0`` cannot bind,
the projected draws where it may, and the weights' covariance from the Cholesky factor."""

from __future__ import annotations

import numpy as np
import pytest

from msflash.processing.ambient import AmbientModel, solved_statistics
from msflash.processing.ambient_band import (
    BAND_MARGIN_Z,
    constrained_band,
    sandwich_band,
    weights_covariance,
)
from msflash.processing.least_squares import minimise_quadratic
from msflash.processing.statistics import SequenceStatistics
from tests.helpers import leds_photons


def _statistics(seed: int, mix: np.ndarray, noise: float, samples: int = 400) -> SequenceStatistics:
    """Moments of ``samples`` random non-negative LED images and an ambient ``images · mix`` plus noise."""
    rng = np.random.default_rng(seed)
    k = mix.size
    images = np.abs(rng.normal(size=(samples, k))) * rng.uniform(0.5, 2.0, k)
    target = images @ mix + rng.normal(size=samples) * noise
    return SequenceStatistics(
        images.T @ images,
        images.T @ target,
        float(target @ target),
        samples,
        samples,
        float(target.sum()),
        images.sum(axis=0),
    )


def _band_inputs(statistics: SequenceStatistics, method: str = "tikhonov"):
    model = AmbientModel(leds_photons())
    weights, alpha = model.weights(statistics, method)
    solved = solved_statistics(statistics).statistics
    terms = model.terms
    penalty = alpha * terms.penalty_scale(solved) if method == "tikhonov" else 0.0
    rss = statistics.residual_energy(weights)
    covariance = weights_covariance(
        solved.gram + penalty * terms.penalty_gram, statistics.gram, rss / (statistics.n_samples - statistics.n_leds)
    )
    return model, weights, solved, terms, penalty, covariance


def _many_draws_band(solved, terms, penalty: float, covariance: np.ndarray, draws: int, seed: int) -> np.ndarray:
    """The band as the draws define it, with many more of them: unconstrained draws from the sandwich, each projected
    onto ``I w ≥ 0`` in the problem's metric (one full solve per draw that leaves it)."""
    hessian = solved.gram + penalty * terms.penalty_gram
    centre = np.linalg.solve(hessian, solved.cross)
    samples = centre[:, None] + np.linalg.cholesky(covariance) @ np.random.default_rng(seed).normal(
        size=(centre.size, draws)
    )
    outside = np.flatnonzero(np.any(terms.emitting @ samples < 0, axis=0))
    for column in outside:
        samples[:, column] = minimise_quadratic(
            hessian, hessian @ samples[:, column], terms.emitting, np.zeros(terms.emitting.shape[0])
        ).x
    return np.std(terms.values @ samples, axis=1, ddof=1)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_far_from_the_constraint_the_band_is_the_sandwich_and_the_draws_scatter(seed: int) -> None:
    """A well-lit in-span scene: the spectrum lies ≥ BAND_MARGIN_Z deviations above 0 wherever an LED emits, the band
    is the sandwich exactly, and 20 000 projected draws (the band's definition, without its 64 draws' ≈ 9 % sampling
    error) scatter as it says to within 3 % at every wavelength."""
    statistics = _statistics(seed, np.array([0.2, 0.05, 0.4, 0.3, 0.6, 0.1, 0.25]) * 50.0, noise=1.0)
    model, weights, solved, terms, penalty, covariance = _band_inputs(statistics)
    sandwich = sandwich_band(terms.values, covariance)
    emits = sandwich > 0
    assert np.all(terms.values[emits] @ weights >= BAND_MARGIN_Z * sandwich[emits])
    band = constrained_band(solved, terms, penalty, covariance, weights)
    np.testing.assert_array_equal(band, sandwich)
    many = _many_draws_band(solved, terms, penalty, covariance, 20_000, seed)
    np.testing.assert_allclose(many[emits], sandwich[emits], rtol=0.03)
    estimate = model.estimate(statistics)
    np.testing.assert_array_equal(estimate.spectrum_std, sandwich)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_near_the_constraint_the_band_is_the_projected_draws(seed: int) -> None:
    """A mix that puts the spectrum near 0 at some wavelengths (one LED off, much noise): the margin is not met, the
    band is the 64 projected draws' (narrower than the sandwich where the constraint cuts the scatter) and agrees
    with 20 000 of them to their sampling error."""
    statistics = _statistics(seed, np.array([0.0, 0.05, 0.4, 0.0, 0.6, 0.0, 0.25]), noise=3.0)
    model, weights, solved, terms, penalty, covariance = _band_inputs(statistics)
    sandwich = sandwich_band(terms.values, covariance)
    assert not np.all(terms.values @ weights >= BAND_MARGIN_Z * sandwich)
    band = constrained_band(solved, terms, penalty, covariance, weights)
    np.testing.assert_array_equal(band, constrained_band(solved, terms, penalty, covariance))  # the draws' band
    assert np.any(band < 0.95 * sandwich)
    many = _many_draws_band(solved, terms, penalty, covariance, 20_000, seed)
    emits = sandwich > 0
    np.testing.assert_allclose(band[emits], many[emits], rtol=0.35)  # 64 draws: ≈ 9 % a wavelength, 4σ


@pytest.mark.parametrize("seed", range(5))
def test_the_weights_covariance_is_the_pseudo_inverses_sandwich(seed: int) -> None:
    """S⁻¹ from its Cholesky factor agrees with the pseudo-inverse's to rounding; a singular S takes the
    pseudo-inverse itself."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(40, 7))
    system, gram = a.T @ a, a.T @ a * rng.uniform(0.5, 2.0)
    inverse = np.linalg.pinv(system)
    np.testing.assert_allclose(weights_covariance(system, gram, 2.5), 2.5 * inverse @ gram @ inverse, rtol=1e-9)
    singular = np.outer(a[0], a[0]) + np.outer(a[1], a[1])
    inverse = np.linalg.pinv(singular)
    np.testing.assert_array_equal(weights_covariance(singular, gram, 2.5), 2.5 * inverse @ gram @ inverse)
