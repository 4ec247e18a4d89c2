"""Ambient estimation (eq. 4–6): exact recovery, best approximation, invariances, reliability signals."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from msflash.processing.accumulate import accumulate_statistics
from msflash.processing.ambient import (
    ALPHA_GRID,
    AMBIENT_METHODS,
    CONDITION_WARNING,
    DISCREPANCY_SIGMAS,
    RESIDUAL_WARNING,
    estimate_ambient,
)
from msflash.processing.errors import SolverError, SpectralDataError
from msflash.processing.scenes import Scene
from msflash.processing.sensor import CFA_PATTERNS, SensorModel
from msflash.processing.statistics import FrameStackSpec
from tests.helpers import (
    EXACT,
    WEIGHTS_EXACT,
    WEIGHTS_ILL_POSED,
    WEIGHTS_QUANTISED,
    ambient,
    chart,
    direct_lstsq_weights,
    led_mix,
    leds_photons,
    linear_frames,
    one_hot_levels,
    rendered_frames,
    spec_for,
)

PROPERTY = settings(max_examples=25, deadline=None)
TRUE_WEIGHTS = np.array([0.2, 0.05, 0.4, 0.3, 0.6, 0.1, 0.25])
"""A non-negative mix of the 7 LEDs used as the ambient."""
EXACT_METHODS = [("lstsq", "auto"), ("nonneg", "auto"), ("tikhonov", 0.0), ("roughness", 0.0)]
"""Methods that recover an in-span ambient exactly (the penalised ones with α = 0)."""


def estimate(ambient_frame, led_frames, spec, led_spectra=None, method="lstsq", alpha="auto", **options):
    statistics = accumulate_statistics(ambient_frame, led_frames, spec, **options)
    return estimate_ambient(statistics, leds_photons() if led_spectra is None else led_spectra, method, alpha)


@pytest.fixture(scope="module")
def mix_frames():
    return linear_frames(led_mix(TRUE_WEIGHTS))


@pytest.mark.parametrize(("method", "alpha"), EXACT_METHODS)
def test_led_mix_recovered_from_float_frames(mix_frames, method: str, alpha) -> None:
    result = estimate(*mix_frames, method=method, alpha=alpha)
    np.testing.assert_allclose(result.ambient_weights, TRUE_WEIGHTS, atol=WEIGHTS_EXACT)
    np.testing.assert_allclose(
        result.spectrum.values[:, 0],
        led_mix(TRUE_WEIGHTS).values[:, 0],
        atol=WEIGHTS_EXACT * led_mix(TRUE_WEIGHTS).values.max(),
    )
    assert result.relative_residual < WEIGHTS_EXACT
    assert result.warnings == ()
    assert result.saturated_fraction == 0.0
    assert result.method == method


def test_led_mix_default_method_near_exact(mix_frames) -> None:
    # GCV picks the smallest α on the grid for noise-free data; the bias it leaves is tiny.
    result = estimate(*mix_frames, method="tikhonov", alpha="auto")
    np.testing.assert_allclose(result.ambient_weights, TRUE_WEIGHTS, atol=WEIGHTS_QUANTISED)


@pytest.mark.parametrize("method", sorted(AMBIENT_METHODS))
def test_led_mix_recovered_from_rendered_frames(method: str) -> None:
    # noise=False still rounds to integer DN: ±0.5 DN on values up to ~6·10⁴ DN, differenced
    # frames with exposures metered per frame — a relative error of order 10⁻⁴ on the weights.
    sensor = SensorModel()
    a, f, exposures, gains = rendered_frames(led_mix(TRUE_WEIGHTS), sensor=sensor)
    result = estimate(
        a,
        f,
        spec_for(sensor, exposures, gains, one_hot_levels(7)),
        method=method,
        alpha=0.0 if method in ("tikhonov", "roughness") else "auto",
    )
    np.testing.assert_allclose(result.ambient_weights, TRUE_WEIGHTS, atol=WEIGHTS_QUANTISED * TRUE_WEIGHTS.max())


def test_ambient_outside_span_gives_best_camera_space_fit() -> None:
    frames = linear_frames(ambient("tungsten"))
    result = estimate(*frames, method="lstsq")
    direct = direct_lstsq_weights(*frames)
    np.testing.assert_allclose(result.ambient_weights, direct, rtol=WEIGHTS_ILL_POSED)
    statistics = accumulate_statistics(*frames)
    assert statistics.residual_energy(result.ambient_weights) == pytest.approx(
        statistics.residual_energy(direct), rel=WEIGHTS_EXACT
    )
    assert result.relative_residual > 1e-3  # really outside the span


def test_exposure_and_gain_normalisation() -> None:
    reference = estimate(*linear_frames(ambient("fluorescent")))
    exposures = [5000.0, 8000.0, 10000.0, 2500.0, 12500.0, 3000.0, 9000.0, 4000.0]
    gains = [1.5, 1.0, 2.0, 1.0, 4.0, 1.0, 1.25, 3.0]
    varied = estimate(*linear_frames(ambient("fluorescent"), exposures=exposures, gains=gains, black=256.0))
    np.testing.assert_allclose(varied.ambient_weights, reference.ambient_weights, rtol=WEIGHTS_ILL_POSED)
    np.testing.assert_allclose(
        varied.spectrum.values, reference.spectrum.values, atol=WEIGHTS_ILL_POSED * reference.spectrum.values.max()
    )


@pytest.mark.parametrize("cfa", sorted(CFA_PATTERNS))
def test_mosaic_gives_the_same_weights_as_rgb(mix_frames, cfa: str) -> None:
    mosaic_frames = linear_frames(led_mix(TRUE_WEIGHTS), cfa=cfa)
    assert mosaic_frames[0].ndim == 2
    rgb = estimate(*mix_frames)
    raw = estimate(*mosaic_frames)
    np.testing.assert_allclose(raw.ambient_weights, rgb.ambient_weights, atol=WEIGHTS_EXACT)
    assert raw.n_samples == mix_frames[0].shape[0] * mix_frames[0].shape[1]


def test_mosaic_outside_span_matches_direct_fit_of_the_mosaic() -> None:
    frames = linear_frames(ambient("tungsten"), cfa="BGGR")
    statistics = accumulate_statistics(*frames)
    weights = estimate_ambient(statistics, leds_photons(), "lstsq").ambient_weights
    direct = direct_lstsq_weights(*frames)
    np.testing.assert_allclose(weights, direct, rtol=WEIGHTS_ILL_POSED)
    # The fitted image is the best one: its residual equals the direct fit's.
    assert statistics.residual_energy(weights) == pytest.approx(statistics.residual_energy(direct), rel=WEIGHTS_EXACT)


def test_saturated_strip_is_ignored() -> None:
    sensor = SensorModel()
    strip = 6
    scene = chart(specular_strip_px=strip)
    plain = chart()
    levels = one_hot_levels(7)
    a, f, exposures, gains = rendered_frames(led_mix(TRUE_WEIGHTS), sensor=sensor, scene=scene)
    assert np.all(a[-strip:] == sensor.white_level)  # the highlight saturates at the metered exposure
    with_strip = estimate(a, f, spec_for(sensor, exposures, gains, levels), method="nonneg")
    a0, f0, exposures0, gains0 = rendered_frames(led_mix(TRUE_WEIGHTS), sensor=sensor, scene=plain)
    without = estimate(a0, f0, spec_for(sensor, exposures0, gains0, levels), method="nonneg")
    np.testing.assert_allclose(with_strip.ambient_weights, without.ambient_weights, rtol=EXACT, atol=EXACT)
    assert with_strip.saturated_fraction == pytest.approx(strip / scene.shape[0])
    assert without.saturated_fraction == 0.0
    # Had the clipped pixels been used, the estimate would be biased.
    unmasked = FrameStackSpec(sensor.black_level, 1e9, 1 / exposures[0], tuple(1 / e for e in exposures[1:]), levels)
    biased = estimate(a, f, unmasked, method="nonneg")
    assert np.max(np.abs(biased.ambient_weights - TRUE_WEIGHTS)) > 10 * WEIGHTS_QUANTISED
    np.testing.assert_allclose(without.ambient_weights, TRUE_WEIGHTS, atol=WEIGHTS_QUANTISED)


def test_many_saturated_samples_are_flagged() -> None:
    a, f, spec = linear_frames(ambient("tungsten"))
    brightest = np.max(np.stack([a, *f]), axis=(0, 3))
    white = np.quantile(brightest, 0.4)  # 60 % of the pixels reach white in some frame
    result = estimate(a, f, FrameStackSpec(0.0, float(white), spec.ambient_scale, spec.led_scales, spec.led_levels))
    assert result.saturated_fraction > 0.5
    assert any("saturated" in warning for warning in result.warnings)


# -- invariances (hypothesis) -------------------------------------------------------------------
@pytest.fixture(scope="module")
def tungsten_frames():
    return linear_frames(ambient("tungsten"))


@PROPERTY
@given(gain=st.floats(1e-3, 1e3), method=st.sampled_from(sorted(AMBIENT_METHODS)))
def test_spectrum_shape_invariant_to_global_gain(tungsten_frames, gain: float, method: str) -> None:
    a, f, spec = tungsten_frames
    reference = estimate(a, f, spec, method=method)
    scaled = estimate(a * gain, [x * gain for x in f], spec, method=method)
    shape = reference.spectrum.values[:, 0] / reference.spectrum.values.max()
    np.testing.assert_allclose(
        scaled.spectrum.values[:, 0] / scaled.spectrum.values.max(), shape, atol=WEIGHTS_ILL_POSED
    )
    np.testing.assert_allclose(scaled.ambient_weights, reference.ambient_weights, rtol=WEIGHTS_ILL_POSED)


@PROPERTY
@given(order=st.permutations(range(7)), method=st.sampled_from(sorted(AMBIENT_METHODS)))
def test_weights_permute_with_the_leds(tungsten_frames, order: list[int], method: str) -> None:
    a, f, spec = tungsten_frames
    reference = estimate(a, f, spec, method=method)
    permuted = estimate(a, [f[i] for i in order], spec, led_spectra=leds_photons().select(order), method=method)
    np.testing.assert_allclose(permuted.ambient_weights, reference.ambient_weights[order], rtol=WEIGHTS_ILL_POSED)
    np.testing.assert_allclose(
        permuted.spectrum.values, reference.spectrum.values, atol=WEIGHTS_ILL_POSED * reference.spectrum.values.max()
    )


# -- reliability signals ----------------------------------------------------------------------
def test_nearly_dependent_leds_are_flagged() -> None:
    base = leds_photons()
    values = base.values.copy()
    values[:, 3] = values[:, 2] * (1 + 1e-5 * np.linspace(-1, 1, values.shape[0]))  # LED 4 ≈ LED 3
    twins = base.replace(values=values)
    result = estimate(*linear_frames(ambient("tungsten"), led_spectra=twins), led_spectra=twins)
    assert result.condition_number > CONDITION_WARNING
    assert any("nearly dependent" in warning for warning in result.warnings)


def test_large_residual_is_flagged() -> None:
    # The scene moved between the ambient and the LED frames: the LEDs cannot explain the ambient image.
    a, f, spec = linear_frames(ambient("tungsten"))
    moved = np.roll(a, 7, axis=1)
    result = estimate(moved, [moved + (x - a) for x in f], spec)
    assert result.relative_residual > RESIDUAL_WARNING
    assert any("explain the ambient image poorly" in warning for warning in result.warnings)


def test_good_estimate_has_no_warnings(tungsten_frames) -> None:
    result = estimate(*tungsten_frames, method="tikhonov")
    assert result.warnings == ()
    assert result.relative_residual < RESIDUAL_WARNING
    low, high = result.band
    assert np.all(low <= result.spectrum.values[:, 0]) and np.all(result.spectrum.values[:, 0] <= high)


# -- bad input --------------------------------------------------------------------------------
def test_bad_input_is_refused(tungsten_frames) -> None:
    statistics = accumulate_statistics(*tungsten_frames)
    with pytest.raises(SpectralDataError, match="7 LED images"):
        estimate_ambient(statistics, leds_photons().select([0, 1, 2]))
    with pytest.raises(SpectralDataError, match="expected 'photons'"):
        estimate_ambient(statistics, leds_photons().to_unit("energy"))
    with pytest.raises(ValueError, match="ambient method 'bogus' is unknown"):
        estimate_ambient(statistics, leds_photons(), "bogus")


def test_led_with_no_emission_on_the_grid_is_refused(tungsten_frames) -> None:
    """A zero LED column (say, a calibration whose grid misses that LED) would have its weight solved
    for and then dropped from the spectrum without a word."""
    values = leds_photons().values.copy()
    values[:, 2] = 0.0
    spectra = leds_photons().replace(values=values, source="cal.csv")
    statistics = accumulate_statistics(*tungsten_frames)
    with pytest.raises(
        SpectralDataError, match=r"cal.csv: the spectrum of LED led500 has no positive value on 400–700 nm"
    ):
        estimate_ambient(statistics, spectra)


@pytest.mark.parametrize("alpha", [-1.0, float("nan"), float("inf"), "bogus"])
def test_bad_alpha_is_refused(tungsten_frames, alpha) -> None:
    statistics = accumulate_statistics(*tungsten_frames)
    with pytest.raises(SpectralDataError, match="expected a finite number ≥ 0 or 'auto'"):
        estimate_ambient(statistics, leds_photons(), "tikhonov", alpha)


@pytest.mark.parametrize("method", ["tikhonov", "roughness"])
def test_overflowing_alpha_is_refused_naming_alpha(tungsten_frames, method: str) -> None:
    statistics = accumulate_statistics(*tungsten_frames)
    with pytest.raises(
        SpectralDataError, match=f"{method} estimate: the roughness penalty overflows; expected a smaller alpha"
    ):
        estimate_ambient(statistics, leds_photons(), method, 1e308)


@pytest.mark.parametrize("method", sorted(AMBIENT_METHODS))
@pytest.mark.parametrize("ambient_noise", [0.0, 1e-3])
def test_dark_ambient_is_flagged_not_presented_as_a_spectrum(
    tungsten_frames, method: str, ambient_noise: float
) -> None:
    """An ambient frame at the black level (zero, or read noise only) gave a zero (or noise) spectrum
    with no warning at all (zero) or only 'residual' / 'band' warnings that named the wrong cause."""
    a, f, spec = tungsten_frames
    dark = np.random.default_rng(1).normal(0.0, ambient_noise, a.shape) if ambient_noise else np.zeros_like(a)
    result = estimate(dark, [frame - a + dark for frame in f], spec, method=method)
    assert result.ambient_is_dark
    assert result.ambient_z < 4
    assert any("the ambient image holds noise, not light" in w for w in result.warnings)
    assert not any("explain the ambient image poorly" in w for w in result.warnings)
    lit = estimate(a, f, spec, method=method)
    assert not lit.ambient_is_dark and lit.ambient_z > 40


def test_too_few_samples_names_the_cause(tungsten_frames) -> None:
    a, f, spec = tungsten_frames
    with pytest.raises(
        SpectralDataError, match=r"only 3 valid samples of 3 \(0% saturated\).*— the frames are too small"
    ):
        estimate(a[:1, :1], [frame[:1, :1] for frame in f], spec)


def test_dark_led_raises_solver_error(tungsten_frames) -> None:
    a, f, spec = tungsten_frames
    frames = list(f)
    frames[2] = a.copy()  # LED 3 adds nothing
    with pytest.raises(SolverError, match="led500 is empty"):
        estimate(a, frames, spec)


def test_single_surface_scene_is_refused() -> None:
    # One surface gives 3 independent equations for 7 unknowns: the LED-only images are dependent.
    scene = Scene(chart().reflectances, np.zeros((6, 6), dtype=np.int32))
    with pytest.raises(SolverError, match="lstsq estimate: the normal matrix is not positive definite"):
        estimate(*linear_frames(ambient("tungsten"), scene=scene), method="lstsq")


@pytest.mark.parametrize(("cfa", "period"), [(None, 1), ("RGGB", 2), ("BGGR", 2)])
@pytest.mark.parametrize("factor", [2, 4])
def test_binned_statistics_recover_the_mix(cfa: str | None, period: int, factor: int) -> None:
    # Block sums obey the linear model exactly; the binner sums in float32, exact for integer raw
    # data (it is documented for ≤ 16-bit frames), so use rendered integer frames.
    sensor = SensorModel(cfa=cfa)
    a, f, exposures, gains = rendered_frames(led_mix(TRUE_WEIGHTS), sensor=sensor)
    result = estimate(
        a,
        f,
        spec_for(sensor, exposures, gains, one_hot_levels(7)),
        method="lstsq",
        bin_factor=factor,
        cfa_period=period,
    )
    np.testing.assert_allclose(result.ambient_weights, TRUE_WEIGHTS, atol=WEIGHTS_QUANTISED * TRUE_WEIGHTS.max())


def test_binned_statistics_exclude_saturated_blocks() -> None:
    sensor = SensorModel()
    scene = chart(specular_strip_px=8)
    a, f, exposures, gains = rendered_frames(led_mix(TRUE_WEIGHTS), sensor=sensor, scene=scene)
    result = estimate(a, f, spec_for(sensor, exposures, gains, one_hot_levels(7)), method="nonneg", bin_factor=4)
    assert result.saturated_fraction > 0
    np.testing.assert_allclose(result.ambient_weights, TRUE_WEIGHTS, atol=WEIGHTS_QUANTISED)


# -- prepared model (the capture's latency path) ----------------------------------------------
def reference_gcv_alpha(statistics, roughness) -> float:
    """GCV written plainly with numpy.linalg: the prepared path must pick exactly the same α."""
    from msflash.processing.ambient import ALPHA_GRID

    gram, cross = statistics.gram, statistics.cross
    n = max(statistics.n_samples, statistics.n_leds + 1)
    inverse_factor = np.linalg.inv(np.linalg.cholesky(gram + 1e-12 * np.trace(gram) * np.eye(len(gram))).T)
    penalty_gram = roughness.T @ roughness
    penalty = float(np.trace(gram) / max(np.trace(penalty_gram), 1e-300)) * penalty_gram
    eigenvalues, vectors = np.linalg.eigh(inverse_factor.T @ penalty @ inverse_factor)
    z_squared = (vectors.T @ (inverse_factor.T @ cross)) ** 2
    filters = 1.0 / (1.0 + np.outer(ALPHA_GRID, np.clip(eigenvalues, 0.0, None)))
    rss = np.clip(statistics.ambient_energy - filters @ z_squared * 2 + (filters**2) @ z_squared, 0.0, None)
    denominator = (n - filters.sum(axis=1)) ** 2
    scores = np.where(denominator > 0, n * rss / np.where(denominator > 0, denominator, 1.0), np.inf)
    return float(ALPHA_GRID[int(np.flatnonzero(scores <= scores.min() * (1 + 1e-12))[0])])


@PROPERTY
@given(seed=st.integers(0, 2**31 - 1), dependent=st.booleans())
def test_gcv_alpha_is_the_plain_computation(seed: int, dependent: bool) -> None:
    """Bit for bit: GCV scores are flat at small α, so any round-off change could move the minimum."""
    from msflash.processing.ambient import gcv_alpha
    from msflash.processing.statistics import SequenceStatistics

    rng = np.random.default_rng(seed)
    leds = leds_photons().values
    images = rng.normal(size=(300, leds.shape[1])) * rng.uniform(0.1, 10, leds.shape[1])
    if dependent:
        images[:, 1] = images[:, 0] * (1 + 1e-6 * rng.normal(size=300))
    target = images @ rng.normal(size=leds.shape[1]) + rng.normal(size=300) * rng.uniform(1e-3, 3)
    statistics = SequenceStatistics(
        images.T @ images,
        images.T @ target,
        float(target @ target),
        int(rng.integers(20, 10**5)),
        300,
        float(target.sum()),
        images.sum(axis=0),
    )
    roughness = np.diff(leds, axis=0)
    assert gcv_alpha(statistics, roughness) == reference_gcv_alpha(statistics, roughness)


@pytest.mark.parametrize("method", sorted(AMBIENT_METHODS))
def test_prepared_model_equals_the_one_shot_estimate(tungsten_frames, method: str) -> None:
    from msflash.processing.ambient import AmbientModel

    a, f, spec = tungsten_frames
    statistics = accumulate_statistics(a, f, spec)
    model = AmbientModel(leds_photons())
    reference = estimate_ambient(statistics, leds_photons(), method)
    weights, alpha = model.weights(statistics, method)
    np.testing.assert_array_equal(weights, reference.ambient_weights)
    assert alpha == reference.alpha
    np.testing.assert_array_equal(AMBIENT_METHODS[method](statistics, leds_photons().values, "auto")[0], weights)
    full = model.estimate(statistics, method)
    np.testing.assert_array_equal(full.spectrum_std, reference.spectrum_std)
    assert (full.condition_number, full.relative_residual, full.warnings) == (
        reference.condition_number,
        reference.relative_residual,
        reference.warnings,
    )
    with pytest.raises(ValueError, match="unknown"):
        model.weights(statistics, "magic")
    with pytest.raises(SpectralDataError, match="expected one spectrum per LED"):
        three = {"gram": statistics.gram[:3, :3], "cross": statistics.cross[:3], "led_sums": statistics.led_sums[:3]}
        model.weights(dataclasses.replace(statistics, **three, noise=None))


@pytest.mark.parametrize("method", ["lstsq", "nonneg", "tikhonov"])
def test_prepared_constraint_rows_solve_as_the_one_shot_quadratic(tungsten_frames, method: str) -> None:
    """AmbientModel prepares the I w ≥ 0 rows once (LedTerms); each solve equals the one-shot QP on it.

    (Roughness is left out: its last problem may be a majorise–minimise step it rejects.)
    """
    from msflash.processing.ambient import AmbientModel
    from msflash.processing.least_squares import minimise_quadratic, recording_problems

    a, f, spec = tungsten_frames
    statistics = accumulate_statistics(a, f, spec)
    model = AmbientModel(leds_photons())
    with recording_problems() as problems:
        weights, _ = model.weights(statistics, method, 1e-3)
    assert problems
    np.testing.assert_array_equal(minimise_quadratic(*problems[-1]).x, weights)
    constrained = method != "lstsq"
    assert problems[-1][2].shape[0] == (model.terms.emitting.shape[0] if constrained else 0)


def reference_discrepancy_alpha(solved, observed, terms) -> float:
    """The discrepancy search as first written: every α of the bisection solved with ``I w ≥ 0``."""
    from msflash.processing.ambient import _solve_penalised

    scale = terms.penalty_scale(solved)

    def weights(index: int) -> np.ndarray:
        return _solve_penalised(solved, terms, float(ALPHA_GRID[index]) * scale, True, "reference")

    least = weights(0)
    noise_variance = observed.residual_energy(least) / max(observed.n_samples - observed.n_leds, 1)
    allowed = solved.fit_energy(least) + DISCREPANCY_SIGMAS * observed.n_leds * noise_variance
    low, high = 0, ALPHA_GRID.size - 1
    if solved.fit_energy(weights(high)) <= allowed:
        return float(ALPHA_GRID[high])
    while high - low > 1:
        middle = (low + high) // 2
        low, high = (middle, high) if solved.fit_energy(weights(middle)) <= allowed else (low, middle)
    return float(ALPHA_GRID[low])


@PROPERTY
@given(seed=st.integers(0, 2**31 - 1), in_span=st.booleans(), noise=st.floats(1e-4, 10.0))
def test_the_discrepancy_search_chooses_as_a_search_of_constrained_solves(
    seed: int, in_span: bool, noise: float
) -> None:
    """The α of the unconstrained sweep (solves only where ``I w ≥ 0`` binds) is the plain search's; in span the
    constraint rarely binds, a random mix binds it often. The weights are then a constrained solve's at that α, to
    rounding (read from the sweep where the constraint does not bind), and ``AMBIENT_METHODS``' auto search's to the
    bit."""
    from msflash.processing.ambient import AmbientModel, LedTerms, discrepancy_alpha
    from msflash.processing.statistics import SequenceStatistics

    rng = np.random.default_rng(seed)
    leds = leds_photons().values
    images = np.abs(rng.normal(size=(300, leds.shape[1]))) * rng.uniform(0.1, 10, leds.shape[1])
    mix = rng.uniform(0, 1, leds.shape[1]) if in_span else rng.normal(size=leds.shape[1])
    target = images @ mix + rng.normal(size=300) * noise
    statistics = SequenceStatistics(
        images.T @ images,
        images.T @ target,
        float(target @ target),
        300,
        300,
        float(target.sum()),
        images.sum(axis=0),
    )
    terms = LedTerms.of(leds)
    alpha = discrepancy_alpha(statistics, statistics, terms)
    assert alpha == reference_discrepancy_alpha(statistics, statistics, terms)
    weights, used = AmbientModel(leds_photons()).weights(statistics)
    assert used == alpha
    solved = AMBIENT_METHODS["tikhonov"](statistics, leds, alpha)[0]
    np.testing.assert_allclose(weights, solved, rtol=0, atol=1e-9 * np.abs(solved).max())
    np.testing.assert_array_equal(weights, AMBIENT_METHODS["tikhonov"](statistics, leds, "auto")[0])


@PROPERTY
@given(seed=st.integers(0, 2**31 - 1), decades=st.floats(-6, 6))
def test_the_bands_row_deviation_is_numpys_to_the_bit(seed: int, decades: float) -> None:
    from msflash.processing.ambient_band import BAND_DRAWS, row_std

    values = np.random.default_rng(seed).normal(size=(31, BAND_DRAWS)) * 10.0**decades + 10.0**decades
    np.testing.assert_array_equal(row_std(values), np.std(values, axis=1, ddof=1))


def test_the_led_terms_are_prepared_once_per_set_of_values() -> None:
    """LedTerms.of keeps the terms of recent LED sets (every estimate of one set needs the same ones): the same
    object for equal values, its own read-only copy of them (a caller's later change cannot reach them), and the
    terms of fresh preparation to the bit."""
    from msflash.processing.ambient import LedTerms

    values = leds_photons().values.copy()
    terms = LedTerms.of(values)
    assert LedTerms.of(values.copy()) is terms
    assert not terms.values.flags.writeable
    fresh = LedTerms._prepare(values.copy())
    for name in ("values", "roughness", "penalty_gram", "emitting", "ridge"):
        np.testing.assert_array_equal(getattr(terms, name), getattr(fresh, name))
    assert terms.penalty_trace == fresh.penalty_trace
    np.testing.assert_array_equal(terms.nonnegative.inverse_factor, fresh.nonnegative.inverse_factor)
    values[3, 2] += 1.0  # the caller's array changes: the cached terms do not, and the new values get their own
    assert terms.values[3, 2] == fresh.values[3, 2]
    assert LedTerms.of(values) is not terms
