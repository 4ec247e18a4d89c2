"""The light prior (issue 17, build 3): past the LEDs' span, with the model choice of ``auto``."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session.analysis import estimate_sequence
from msflash.acquisition.session.prior_route import estimate_sequence_prior, prior_payload, sequence_channel_statistics
from msflash.acquisition.session.sequence_spectra import camera_responsivities_photons, led_spectra_photons
from msflash.processing import datasets
from msflash.processing.accumulate import accumulate_statistics
from msflash.processing.ambient import estimate_ambient
from msflash.processing.channel_statistics import (
    ChannelStatistics,
    Moments,
    accumulate_channel_statistics,
    plane_channels,
)
from msflash.processing.errors import SpectralDataError
from msflash.processing.light_library import NEAR_COPY_COSINE, lights_of
from msflash.processing.light_prior import (
    PriorEstimate,
    PriorModel,
    floored_normal_equations,
    learn_light_prior,
    learn_reflectance_basis,
    normal_equations,
    prior_candidate_lights,
    prior_model,
    solved_moments,
)
from msflash.processing.noise_floor import NOISE_FLOOR_SHARE
from msflash.processing.prior_choice import choose_model, held_out_errors
from msflash.processing.spectra import Spectra, WavelengthGrid
from msflash.processing.statistics import FrameStackSpec
from tests.processing import unseen_sequences as us
from tests.processing.light_prior_study import rendering_with, study_surfaces

GRID = WavelengthGrid(400, 700, 10)


def estimate_ambient_prior(
    statistics: ChannelStatistics, led_spectra: Spectra, responsivities: Spectra, **options: float
) -> PriorEstimate:
    """The light prior's estimate of a sequence's channel statistics."""
    return prior_model(statistics.channels, led_spectra, responsivities, **options).estimate(statistics)


def _unit(values: np.ndarray) -> np.ndarray:
    return values / np.linalg.norm(values, axis=0)


def _scene(
    light: np.ndarray,
    leds: Spectra,
    camera: Spectra,
    surfaces: np.ndarray,
    cfa: str | None = None,
    noise: float = 0.0,
    patch: int = 8,
    seed: int = 0,
) -> tuple[np.ndarray, list[np.ndarray], FrameStackSpec]:
    """Float frames (ambient, ambient + each LED) of a chart of ``surfaces`` (n_wl × S), photons throughout."""
    columns = 8
    rows = -(-surfaces.shape[1] // columns)
    labels = np.repeat(
        np.repeat(np.arange(rows * columns).reshape(rows, columns) % surfaces.shape[1], patch, 0), patch, 1
    )

    def responses(spd):
        return (surfaces * spd[:, None]).T @ camera.values  # (S, 3)

    ambient = responses(light)[labels]
    frames = [ambient + responses(leds.values[:, i])[labels] for i in range(leds.count)]
    rng = np.random.default_rng(seed)
    peak = max(float(f.max()) for f in frames)
    stack = []
    for image in [ambient, *frames]:
        image = image / peak
        if cfa is not None:
            index = np.array(["RGB".index(c) for c in cfa]).reshape(2, 2)
            sites = np.tile(index, (image.shape[0] // 2, image.shape[1] // 2))
            image = np.take_along_axis(image, sites[:, :, None], axis=2)[:, :, 0]
        stack.append(image + noise * rng.standard_normal(image.shape))
    spec = FrameStackSpec(0.0, 10.0, 1.0, (1.0,) * leds.count, np.eye(leds.count))
    return stack[0], stack[1:], spec


def _leds(which: tuple[int, ...] = (0, 3, 6)) -> Spectra:
    return datasets.paper_leds().resample(GRID, outside="zero").select(list(which)).to_unit("photons")


def _camera(name: str = "Canon 5DMarkII") -> Spectra:
    return datasets.camera_responsivities(name).resample(GRID, outside="zero")


def test_channel_statistics_sum_to_the_eq5_statistics_rgb_and_bayer():
    leds, camera = _leds((0, 2, 3, 6)), _camera()
    light = datasets.illuminant("D65", GRID).to_unit("photons").values[:, 0]
    surfaces = datasets.macbeth().resample(WavelengthGrid(400, 700, 4)).resample(GRID).values
    for cfa in (None, "GRBG"):
        ambient, frames, spec = _scene(light, leds, camera, surfaces, cfa=cfa, noise=0.002, patch=16)
        channel = accumulate_channel_statistics(ambient, frames, spec, cfa=cfa)
        summed = channel.led_statistics()
        direct = accumulate_statistics(ambient, frames, spec, bin_factor=4, cfa_period=2 if cfa else 1, workers=1)
        assert channel.channels == plane_channels(cfa)
        np.testing.assert_allclose(summed.gram, direct.gram, rtol=1e-9)
        np.testing.assert_allclose(summed.cross, direct.cross, rtol=1e-9)
        assert summed.ambient_energy == pytest.approx(direct.ambient_energy, rel=1e-9)
        assert summed.n_samples == direct.n_samples
        np.testing.assert_allclose(summed.noise.gram, direct.noise.gram, rtol=1e-9)
        assert channel.n_folds == 5 and channel.counts.sum() == channel.n_blocks > 0


def test_channel_statistics_unmix_any_levels_and_bin_any_size():
    leds, camera = _leds((0, 2, 3, 6)), _camera()
    light = datasets.illuminant("A", GRID).to_unit("photons").values[:, 0]
    surfaces = datasets.macbeth().resample(WavelengthGrid(400, 700, 4)).resample(GRID).values
    ambient, frames, one_hot = _scene(light, leds, camera, surfaces, patch=12)
    only = [frame - ambient for frame in frames]
    # six frames for four LEDs: pairs, then two at half drive, with their own exposures
    levels = np.vstack([np.eye(4) + np.eye(4, k=1), 0.5 * np.eye(4)[:2]])
    scales = (1.0, 0.5, 2.0, 1.0, 1.0, 0.25)
    mixed = [
        (ambient + sum(level * image for level, image in zip(row, only))) / scale for row, scale in zip(levels, scales)
    ]
    spec = FrameStackSpec(0.0, 10.0, 1.0, scales, levels)
    reference = accumulate_channel_statistics(ambient, frames, one_hot)
    unmixed = accumulate_channel_statistics(ambient, mixed, spec)
    # the raw moments are mapped after summing: cancellation costs ~1e-8 of the small LED-only moments
    np.testing.assert_allclose(
        unmixed.moments.ff, reference.moments.ff, rtol=1e-6, atol=1e-9 * reference.moments.ff.max()
    )
    np.testing.assert_allclose(
        unmixed.moments.fa, reference.moments.fa, rtol=1e-6, atol=1e-9 * reference.moments.fa.max()
    )
    for factor in (1, 3):  # no noise probe for odd blocks
        channel = accumulate_channel_statistics(ambient, mixed, spec, bin_factor=factor)
        direct = accumulate_statistics(ambient, mixed, spec, bin_factor=factor, workers=1)
        assert channel.noise is None
        np.testing.assert_allclose(channel.led_statistics().gram, direct.gram, rtol=1e-7)
        np.testing.assert_allclose(channel.led_statistics().cross, direct.cross, rtol=1e-7)


def test_noise_free_estimate_is_exact_when_light_and_surfaces_are_in_the_model():
    leds, camera = _leds((0, 1, 2, 3, 4, 5, 6)), _camera()
    prior = learn_light_prior(GRID)
    reflectance = learn_reflectance_basis(GRID)
    # A light of the prior's basis (the mean light with a tilt), surfaces in the reflectance basis.
    phi = np.zeros(prior.dims)
    phi[0], phi[1:] = (
        1.0,
        prior.mean + 0.3 * np.sqrt(np.diag(prior.covariance)) * np.sign(np.arange(prior.dims - 1) % 2 - 0.5),
    )
    light = prior.basis.values @ phi
    assert light.min() > 0
    rng = np.random.default_rng(1)
    surfaces = reflectance.basis.values @ (
        rng.normal(size=(reflectance.basis.count, 30)) * np.sqrt(reflectance.weights)[:, None]
    )
    ambient, frames, spec = _scene(light, leds, camera, surfaces, patch=8)
    statistics = accumulate_channel_statistics(ambient, frames, spec)
    estimate = estimate_ambient_prior(statistics, leds, camera, ridge=0.0)  # the exact Wiener limit
    # in the LEDs' units: the frames were normalised by one peak, ambient and LEDs alike
    np.testing.assert_allclose(
        estimate.spectrum.values[:, 0], light, rtol=0, atol=1e-4 * light.max()
    )  # H: condition ~1e8
    assert estimate.relative_residual < 1e-6
    # the LED span cannot do it
    led = estimate_ambient(statistics.led_statistics(), leds)
    assert us.rmse(led.spectrum.values[:, 0], light) > 0.03


FLUORESCENT = "NIST 50: NIST F32T8/TL835 (Triphosphor)"
"""A tuning-split triphosphor tube the prior does not learn from (a near copy of a held-out light)."""


@pytest.fixture(scope="module")
def fluorescent_sequences(tmp_path_factory: pytest.TempPathFactory) -> dict[str | None, us.Rendered]:
    """:data:`FLUORESCENT` on surfaces not in the reflectance basis, RGB and Bayer."""
    root = tmp_path_factory.mktemp("prior")
    tuning = lights_of("tuning")
    assert FLUORESCENT in tuning.names and FLUORESCENT not in learn_light_prior(GRID).training
    rendered = {}
    for cfa in (None, "RGGB"):
        with rendering_with(tuning.column(FLUORESCENT), tuning.wavelengths_nm):
            rendered[cfa] = us.render_case(us.Case(f"fl-{cfa}", light="lib", cfa=cfa, patch_px=16), root / f"fl-{cfa}")
    return rendered


def test_light_outside_the_led_span_beats_the_led_bound_rgb_and_bayer(fluorescent_sequences):
    spectra = {}
    for cfa, rendered in fluorescent_sequences.items():
        sequence = read_sequence(rendered.directory)
        result = estimate_sequence_prior(sequence)
        bound = us.led_bound(rendered)
        error = us.rmse(result.prior.spectrum.values[:, 0], rendered.truth)
        default = us.rmse(estimate_sequence(sequence).spectrum.values[:, 0], rendered.truth)
        assert error < 0.5 * bound and error < 0.5 * default, (cfa, error, bound, default)  # 0.09–0.11 vs 0.38, 0.34
        assert result.choice.model == "prior", result.choice.reason
        assert "light prior predicts held-out pixels better" in result.choice.reason
        # the band is a band: positive, narrower than the spectrum's peak
        assert 0 < result.prior.spectrum_std.max() < result.prior.spectrum.values.max()
        spectra[cfa] = result.prior.spectrum.values[:, 0]
    # Bayer and RGB frames of one scene give nearly one estimate
    assert us.rmse(spectra["RGGB"], spectra[None]) < 0.05


def _noisy_statistics(scale: float = 1.0, noise: float = 0.02, seed: int = 1) -> tuple[ChannelStatistics, PriorModel]:
    """CIE D65 under three paper LEDs, strong pixel noise (each fold's noise share differs), and its prior model."""
    leds, camera = _leds((0, 3, 6)), _camera("Nikon D40")
    light = scale * datasets.illuminant("D65", GRID).to_unit("photons").values[:, 0]
    surfaces = study_surfaces(GRID.wavelengths_nm)
    ambient, frames, spec = _scene(light, leds, camera, surfaces, noise=noise, patch=12, seed=seed)
    statistics = accumulate_channel_statistics(ambient, frames, spec)
    return statistics, prior_model(statistics.channels, leds, camera)


def _solved_on(model: PriorModel, monkeypatch: pytest.MonkeyPatch, run) -> list[tuple]:
    """The (moments, observed) each call of ``model.solve`` was handed while ``run()`` ran."""
    seen, solve = [], PriorModel.solve

    def spying(self, moments, n_samples, nonnegative=True, observed=None):
        seen.append((moments, observed))
        return solve(self, moments, n_samples, nonnegative, observed)

    monkeypatch.setattr(PriorModel, "solve", spying)
    run()
    return seen


def _assert_moments_equal(found: Moments, expected: Moments) -> None:
    for name in ("ff", "fa", "aa"):
        np.testing.assert_allclose(getattr(found, name), getattr(expected, name), rtol=1e-12, atol=0, err_msg=name)


def test_the_prior_is_solved_on_the_moments_less_all_their_noise(monkeypatch: pytest.MonkeyPatch):
    """Errors in variables: the prior's normal equations are the observed moments less the *whole* noise probe of
    the blocks they sum — all five folds' for the estimate, the four training folds' for each held-out prediction —
    and its σ² (λ, the band) is read from the observed residual, which holds the noise the estimate still carries."""
    statistics, model = _noisy_statistics()
    moments, noise = statistics.moments, statistics.noise
    assert noise is not None and not np.allclose(noise.fold(0).ff, noise.total().ff / statistics.n_folds, rtol=0.1)
    (solved, observed), *_ = _solved_on(model, monkeypatch, lambda: model.estimate(statistics))
    _assert_moments_equal(solved, moments.total() - noise.total())
    _assert_moments_equal(observed, moments.total())
    folds = _solved_on(model, monkeypatch, lambda: held_out_errors(statistics, model))
    assert len(folds) == statistics.n_folds
    for fold, (solved, observed) in enumerate(folds):
        _assert_moments_equal(solved, moments.without(fold) - noise.without(fold))
        _assert_moments_equal(observed, moments.without(fold))


def test_an_estimate_forms_each_set_of_normal_equations_once(monkeypatch: pytest.MonkeyPatch):
    """The observed moments' normal equations set σ² (λ, the band) and the relative residual: formed once for both
    (they were formed again for the residual), the denoised moments' once for φ; the answer as before."""
    from msflash.processing import light_prior

    statistics, model = _noisy_statistics()
    expected = model.estimate(statistics)
    formed: list[Moments] = []
    real = light_prior.normal_equations

    def counted(predictors: np.ndarray, moments: Moments) -> tuple[np.ndarray, np.ndarray, float]:
        formed.append(moments)
        return real(predictors, moments)

    monkeypatch.setattr(light_prior, "normal_equations", counted)
    found = model.estimate(statistics)
    assert len(formed) == 2
    _assert_moments_equal(formed[0], statistics.moments.total())
    _assert_moments_equal(formed[1], solved_moments(statistics))
    assert found.relative_residual == expected.relative_residual > 0
    assert np.array_equal(found.spectrum_std, expected.spectrum_std)


def test_the_prior_estimate_does_not_depend_on_which_band_of_rows_comes_first():
    """The folds are bands of block rows; the estimate is of the blocks, so listing the bands in another order must
    not move it. (Denoised by the first fold's noise alone, it moved with that fold's share of the noise.)"""
    statistics, model = _noisy_statistics()
    order = np.roll(np.arange(statistics.n_folds), 2)

    def moments_in(moments: Moments) -> Moments:
        return Moments(moments.ff[order], moments.fa[order], moments.aa[order])

    assert statistics.noise is not None
    reordered = replace(
        statistics,
        moments=moments_in(statistics.moments),
        noise=moments_in(statistics.noise),
        counts=statistics.counts[order],
        led_sums=statistics.led_sums[order],
        ambient_sums=statistics.ambient_sums[order],
    )
    first, second = model.estimate(statistics), model.estimate(reordered)
    np.testing.assert_allclose(second.spectrum.values, first.spectrum.values, rtol=1e-7, atol=1e-9)


def test_a_dim_scene_whose_denoised_normal_matrix_is_indefinite_is_solved_on_a_floored_one():
    """Where the noise probe exceeds the signal along some combination of light coefficients (a dim, noisy scene)
    the denoised normal matrix ``H(S − N)`` is indefinite; those directions are raised to a share of the noise along
    them, as the LEDs' span raises its Gram matrix's (processing.noise_floor), so the prior still solves — and the
    matrix is untouched wherever the signal dominates."""
    statistics, model = _noisy_statistics(scale=0.01, noise=0.05, seed=2)
    observed, solved = statistics.moments.total(), solved_moments(statistics)
    clean, observed_hessian = (
        normal_equations(model.predictors, solved)[0],
        normal_equations(model.predictors, observed)[0],
    )
    noise = observed_hessian - clean
    eigenvalues, vectors = np.linalg.eigh(clean)
    assert eigenvalues[0] < 0  # the case this test is about
    hessian, _, _, floored = floored_normal_equations(model.predictors, solved, observed_hessian)
    assert floored > 0 and np.linalg.eigvalsh(hessian)[0] > 0
    noise_along = np.einsum("ji,jk,ki->i", vectors, noise, vectors)
    kept = eigenvalues >= NOISE_FLOOR_SHARE * noise_along
    assert np.count_nonzero(~kept) == floored
    np.testing.assert_allclose(
        vectors[:, kept].T @ hessian @ vectors[:, kept], np.diag(eigenvalues[kept]), atol=1e-9 * eigenvalues[-1]
    )
    estimate = model.estimate(statistics)
    assert np.all(np.isfinite(estimate.spectrum.values)) and np.all(np.isfinite(estimate.spectrum_std))
    errors = held_out_errors(statistics, model)
    assert np.all(np.isfinite([errors.led, errors.prior, errors.led_observed, errors.prior_observed]))


def test_choice_keeps_the_leds_when_the_ambient_is_in_their_span():
    leds, camera = _leds((0, 1, 2, 3, 4, 5, 6)), _camera("Nikon D40")
    light = leds.values @ np.array([0.3, 0.5, 0.4, 0.6, 0.8, 0.7, 0.5])
    surfaces = study_surfaces(GRID.wavelengths_nm)
    ambient, frames, spec = _scene(light, leds, camera, surfaces, noise=0.001, patch=12)
    statistics = accumulate_channel_statistics(ambient, frames, spec)
    choice = choose_model(statistics, prior_model(statistics.channels, leds, camera))
    assert choice.model == "led", choice.reason
    assert choice.errors.led < 0.01 and choice.led_error <= choice.prior_error


def test_choice_takes_the_prior_when_the_ambient_is_outside_the_span():
    leds, camera = _leds((0, 3, 6)), _camera("Nikon D40")
    light = datasets.illuminant("FL11", GRID).to_unit("photons").values[:, 0]
    ambient, frames, spec = _scene(light, leds, camera, study_surfaces(GRID.wavelengths_nm), noise=0.001, patch=12)
    statistics = accumulate_channel_statistics(ambient, frames, spec)
    choice = choose_model(statistics, prior_model(statistics.channels, leds, camera))
    assert choice.model == "prior" and choice.prior_error < 0.98 * choice.led_error, choice.reason


def test_dark_ambient_gives_no_light_a_warning_and_the_led_model():
    leds, camera = _leds(), _camera()
    ambient, frames, spec = _scene(np.zeros(GRID.size), leds, camera, study_surfaces(GRID.wavelengths_nm), patch=12)
    statistics = accumulate_channel_statistics(ambient, frames, spec)
    model = prior_model(statistics.channels, leds, camera)
    estimate = model.estimate(statistics)
    assert np.all(estimate.spectrum.values == 0) and "no ambient light" in estimate.warnings[0]
    assert choose_model(statistics, model).model == "led"


def test_prior_never_learns_a_held_out_light_or_a_near_copy_of_one():
    held = lights_of("held_out")
    prior = learn_light_prior(GRID)
    assert not set(prior.training) & set(held.names)
    candidates = prior_candidate_lights(WavelengthGrid(380, 780, 5))
    assert candidates.names == prior.training
    visible = (held.wavelengths_nm >= 400) & (held.wavelengths_nm <= 700)
    similarity = _unit(candidates.values[visible]).T @ _unit(held.values[visible])
    assert similarity.max() < NEAR_COPY_COSINE
    assert any(n.startswith("CIE daylight") for n in prior.training) and any(
        n.startswith("blackbody") for n in prior.training
    )
    # a cross-validation exclusion drops the light and its near copies
    label = lights_of("tuning").names[0]
    assert label not in learn_light_prior(GRID, exclude=(label,)).training


def test_prior_and_reflectance_basis_are_orthonormal_on_any_grid():
    for grid in (GRID, WavelengthGrid(380, 780, 5), WavelengthGrid(402, 698, 4)):
        prior, reflectance = learn_light_prior(grid), learn_reflectance_basis(grid)
        np.testing.assert_allclose(prior.basis.values.T @ prior.basis.values, np.eye(prior.dims), atol=1e-10)
        np.testing.assert_allclose(
            reflectance.basis.values.T @ reflectance.basis.values, np.eye(reflectance.basis.count), atol=1e-10
        )
        assert prior.basis.unit == "photons" and prior.covariance.shape == (prior.dims - 1,) * 2


def test_bad_input_is_one_line_spectral_data_error():
    leds, camera = _leds(), _camera()
    light = datasets.illuminant("A", GRID).to_unit("photons").values[:, 0]
    ambient, frames, spec = _scene(light, leds, camera, study_surfaces(GRID.wavelengths_nm)[:, :24])
    statistics = accumulate_channel_statistics(ambient, frames, spec)
    cases = [
        lambda: estimate_ambient_prior(statistics, _leds((0, 3)), camera),
        lambda: estimate_ambient_prior(statistics, leds.to_unit("energy"), camera),
        lambda: estimate_ambient_prior(statistics, leds, camera.resample(WavelengthGrid(400, 700, 5))),
        lambda: prior_model(("R", "G", "G", "B"), leds, camera).estimate(statistics),
        lambda: accumulate_channel_statistics(ambient, frames[:2], spec),
        lambda: accumulate_channel_statistics(ambient[:, :-1], frames, spec),
        lambda: accumulate_channel_statistics(ambient[:, :, 0], [f[:, :, 0] for f in frames], spec, cfa="RGBX"),
        lambda: accumulate_channel_statistics(ambient[:4], [f[:4] for f in frames], spec),
        lambda: PriorModel(
            leds, camera, ("R", "G", "B"), learn_light_prior(GRID), learn_reflectance_basis(GRID), kappa=0
        ),
        lambda: learn_light_prior(GRID, dims=1),
        lambda: estimate_ambient_prior(statistics, leds, camera.replace(names=("X", "Y", "Z"))),
    ]
    for case in cases:
        with pytest.raises(SpectralDataError) as caught:
            case()
        message = str(caught.value)
        assert "\n" not in message and "expected" in message, message


def test_route_statistics_match_the_sequence(fluorescent_sequences):
    sequence = read_sequence(fluorescent_sequences["RGGB"].directory)
    statistics = sequence_channel_statistics(sequence)
    assert statistics.channels == ("R", "G", "G", "B") and statistics.n_leds == 7
    model = prior_model(statistics.channels, led_spectra_photons(sequence), camera_responsivities_photons(sequence))
    assert model.predictors.shape == (16, 4, 28)


def test_payload_says_which_model_and_why_in_the_sequence_unit(fluorescent_sequences):
    sequence = read_sequence(fluorescent_sequences[None].directory)
    result = estimate_sequence_prior(sequence)
    payload = json.loads(json.dumps(prior_payload(sequence, result), default=lambda v: np.asarray(v).tolist()))
    assert payload["model"] == payload["model_choice"]["model"] == result.choice.model
    assert payload["model_choice"]["reason"] == result.choice.reason
    errors = payload["model_choice"]["held_out_relative_error"]
    assert errors["prior"] < errors["led"] * (1 - payload["model_choice"]["margin"])
    assert len(payload["spectrum"]) == len(payload["wavelengths_nm"]) == len(payload["spectrum_std"])
    # energy in the file: the photon spectrum divided by λ/555 nm
    photons = result.prior.spectrum.values[:, 0]
    np.testing.assert_allclose(payload["spectrum"], photons * 555.0 / sequence.wavelengths_nm, rtol=1e-9)
