"""The family model (processing/light_families.py, issue 30 item 2): its data term, its forms and its choice."""

from __future__ import annotations

import numpy as np
import pytest

from msflash.processing import datasets
from msflash.processing.channel_statistics import ChannelStatistics, Moments
from msflash.processing.family_fit import Fit
from msflash.processing.light_families import SIMPLER_WITHIN, Candidate, choose, family_model
from msflash.processing.light_forms import FORMS, daylight, discharge_atoms, planck
from msflash.processing.light_prior import (
    learn_reflectance_basis,
    light_predictors,
    normal_equations,
    plane_responsivities,
)
from msflash.processing.spectra import WavelengthGrid
from msflash.processing.spectral_data_term import reduce_predictors, scene_form, unit_predictors

GRID = WavelengthGrid(400.0, 700.0, 10.0)


def _leds_and_camera():
    leds = datasets.paper_leds().resample(GRID).to_unit("photons")
    camera = datasets.camera_responsivities("Canon5DMarkII").resample(GRID).to_unit("photons")
    return leds, camera


def _statistics(
    light_photons: np.ndarray, seed: int = 0, folds: int = 5, blocks: int = 40, surfaces=None, camera=None
) -> ChannelStatistics:
    """Noise-free channel statistics of surfaces (Natural-100 unless given; random gains) under ``light_photons``."""
    leds, default_camera = _leds_and_camera()
    camera = default_camera if camera is None else camera
    rng = np.random.default_rng(seed)
    surfaces = datasets.natural100().resample(GRID).values if surfaces is None else surfaces
    planes = plane_responsivities(camera, ("R", "G", "B"))
    k = leds.count
    ff, fa, aa, counts = [], [], [], []
    for _ in range(folds):
        chosen = surfaces[:, rng.integers(0, surfaces.shape[1], blocks)] * rng.uniform(0.3, 1.0, blocks)
        f = np.einsum("nc,nb,ni->bci", planes, chosen, leds.values).reshape(blocks, 3 * k)
        a = np.einsum("nc,nb,n->bc", planes, chosen, light_photons)
        ff.append(f.T @ f), fa.append(f.T @ a), aa.append(a.T @ a), counts.append(blocks)
    moments = Moments(np.array(ff), np.array(fa), np.array(aa))
    return ChannelStatistics(
        moments,
        None,
        np.array(counts),
        np.zeros((folds, 3 * k)),
        np.zeros((folds, 3)),
        folds * blocks,
        k,
        ("R", "G", "B"),
    )


def test_the_reduction_is_exact_and_small() -> None:
    leds, camera = _leds_and_camera()
    predictors = unit_predictors(leds, camera, ("R", "G", "B"))
    reduction = reduce_predictors(predictors)
    rank = reduction.lift.shape[0]
    assert rank <= leds.count + 3 * 8  # LED weights + the planes' reflectance-basis projections
    rebuilt = np.einsum("qn,qcl->ncl", reduction.lift, reduction.shapes)
    np.testing.assert_allclose(rebuilt, predictors, atol=1e-9 * np.abs(predictors).max())


def test_the_scene_form_is_the_light_priors_data_term_for_any_spectrum() -> None:
    """J(e) from the reduced form equals Σ_b ‖a_b − K(e) f_b‖² computed with the prior's own predictors."""
    leds, camera = _leds_and_camera()
    statistics = _statistics(planck(GRID.wavelengths_nm, 3000.0) * GRID.wavelengths_nm)
    model = family_model(statistics.channels, leds, camera)
    scene = scene_form(statistics, model.reduction)
    trial = daylight(GRID, 6500.0) * GRID.wavelengths_nm
    predictors = light_predictors(
        leds.values, plane_responsivities(camera, statistics.channels), trial[:, None], learn_reflectance_basis(GRID)
    )
    hessian, linear, energy = normal_equations(predictors, statistics.moments.total())
    expected = (energy - 2 * linear[0] + hessian[0, 0]) / energy
    problem = scene.whitened(list(range(scene.n_folds)), denoised=False)
    assert problem.error(trial) == pytest.approx(expected, rel=1e-6)


def test_the_fold_complements_are_each_folds_whitened_complement_to_the_bit() -> None:
    """SceneForm.complements sums every complement at once (the family estimate's held-out terms): the same numbers
    as whitening each complement alone, with a noise share and an empty fold (left out as a held-out fold, kept in
    the others' complements)."""
    leds, camera = _leds_and_camera()
    statistics = _statistics(planck(GRID.wavelengths_nm, 4000.0) * GRID.wavelengths_nm, seed=3)
    noise = Moments(*(0.01 * m for m in (statistics.moments.ff, statistics.moments.fa, statistics.moments.aa)))
    counts = statistics.counts.copy()
    counts[2] = 0
    statistics = ChannelStatistics(
        statistics.moments, noise, counts, statistics.led_sums, statistics.ambient_sums,
        statistics.n_blocks_total, statistics.n_leds, statistics.channels,
    )  # fmt: skip
    scene = scene_form(statistics, family_model(statistics.channels, leds, camera).reduction)
    complements = scene.complements()
    assert sorted(complements) == [0, 1, 3, 4]
    for fold, got in complements.items():
        expected = scene.whitened([f for f in range(scene.n_folds) if f != fold])
        for name in ("root", "target", "constant", "hessian", "linear", "energy", "lift"):
            assert np.array_equal(getattr(expected, name), getattr(got, name)), (fold, name)


def test_a_fits_spectrum_is_computed_once_and_read_only() -> None:
    atoms, amplitudes = np.arange(12.0).reshape(4, 3), np.array([1.0, 0.5, 2.0])
    fit = Fit("x", "x", np.zeros(0), atoms, amplitudes, 0.0, 3)
    assert fit.spectrum is fit.spectrum and fit.with_seconds(1.0).spectrum is fit.spectrum
    assert np.array_equal(fit.spectrum, atoms @ amplitudes) and not fit.spectrum.flags.writeable


@pytest.mark.parametrize(
    "kelvin",
    [
        pytest.param(
            2200.0,
            marks=pytest.mark.xfail(
                strict=True,
                reason="a finding, not a flake: on these noise-free Natural-100 blocks a violet-pumped white's four "
                "bands predict held-out pixels 22 % better than the true 2200 K blackbody (0.0018 against 0.0023, the "
                "LEDs' span 0.0023) — the pixel model's own misfit, which the held-out folds share; the estimate lands "
                "at 0.52 of the LEDs' error (0.5 asked) and the temperature is still read to 0.01 % "
                "(docs/light-families.md, 'What the pixels cannot tell')",
            ),
        ),
        3400.0,
        5600.0,
    ],
)
def test_a_blackbody_scene_is_read_as_a_blackbody_of_its_temperature(kelvin: float) -> None:
    leds, camera = _leds_and_camera()
    light = planck(GRID.wavelengths_nm, kelvin) * GRID.wavelengths_nm
    statistics = _statistics(light, seed=int(kelvin))
    estimate = family_model(statistics.channels, leds, camera).estimate(statistics)
    fit = next(c.fit for c in estimate.candidates if c.fit.name == "thermal/blackbody")
    assert fit.parameters()["kelvin"] == pytest.approx(kelvin, rel=0.03)
    shape = estimate.spectrum.values[:, 0] / estimate.spectrum.values[:, 0].max()
    error = np.sqrt(np.mean((shape - light / light.max()) ** 2))
    led = estimate.led.fit.spectrum / estimate.led.fit.spectrum.max()
    assert error < 0.5 * np.sqrt(np.mean((led - light / light.max()) ** 2)), estimate.reason


def test_the_discharge_dictionary_holds_the_known_lines() -> None:
    atoms, names = discharge_atoms(GRID)
    assert atoms.shape == (GRID.size, len(names)) and np.all(atoms >= 0)
    mercury = atoms[:, names.index("Hg 546")]
    assert set(GRID.wavelengths_nm[mercury > 0]) == {540.0, 550.0}  # 546.07 nm shared by its two samples


def _candidate(name: str, parameters: int, error: float) -> Candidate:
    fit = Fit(name, name.split("/")[0], np.zeros(0), np.ones((3, 1)), np.ones(1), 0.0, parameters)
    return Candidate(fit, error, error)


def test_the_choice_prefers_the_simplest_candidate_that_predicts_about_as_well() -> None:
    led = _candidate("led", 7, 0.010)
    flexible = _candidate("solid_state/4 bands", 12, 0.0050)
    simple = _candidate("thermal/blackbody", 2, 0.0050 * (1 + SIMPLER_WITHIN * 0.9))
    worse = _candidate("thermal/daylight", 2, 0.0050 * (1 + SIMPLER_WITHIN * 1.5))
    chosen, reason, auto, auto_reason = choose([flexible, simple, worse], led)
    assert chosen is simple and "fewer parameters" in reason and auto == "thermal/blackbody"
    chosen, _, auto, auto_reason = choose([_candidate("discharge/3 atoms", 3, 0.0099)], led)
    assert auto == "led" and "as well" in auto_reason  # not 2 % better than the LEDs' span: keep it


def test_auto_keeps_the_leds_when_the_gain_is_within_the_noise_correction() -> None:
    """A candidate 20 % better than the LEDs' span on held-out pixels (noise removed), where removing the noise took
    far more off the errors than that gain: the evidence is the noise correction's, and ``auto`` keeps the LEDs."""
    led = Candidate(_candidate("led", 7, 0.0).fit, 0.10, 0.030)  # observed 0.10, 0.03 once the noise is removed
    bands = Candidate(_candidate("solid_state/4 bands", 12, 0.0).fit, 0.099, 0.024)
    _, _, auto, auto_reason = choose([bands], led)
    assert auto == "led" and "noise's share" in auto_reason
    quiet = Candidate(led.fit, 0.031, 0.030)  # the same gain where the noise correction is small: leave the LEDs
    assert choose([Candidate(bands.fit, 0.025, 0.024)], quiet)[2] == "solid_state/4 bands"


@pytest.mark.parametrize("form", [f for f in FORMS if f.tangent is not None], ids=lambda f: f.name)
def test_each_forms_closed_form_tangent_is_the_derivative_of_its_spectrum(form) -> None:  # noqa: ANN001
    """The Kaufman refinement steps along ``∂(B(θ) a)/∂θ``: each closed form equals central differences of the atoms
    at interior points of the form's bounds."""
    rng = np.random.default_rng(1)
    lower = np.array([b[0] for b in form.bounds])
    upper = np.array([b[1] for b in form.bounds])
    for _ in range(3):
        theta = lower + (upper - lower) * rng.uniform(0.2, 0.8, lower.size)
        amplitudes = rng.uniform(0.5, 2.0, form.atoms(GRID, theta).shape[1])
        tangent = form.tangent(GRID, theta, amplitudes)
        for j in range(theta.size):
            step = 1e-6 * (upper[j] - lower[j])
            up, down = theta.copy(), theta.copy()
            up[j] += step
            down[j] -= step
            expected = (form.atoms(GRID, up) - form.atoms(GRID, down)) @ amplitudes / (2 * step)
            np.testing.assert_allclose(tangent[:, j], expected, rtol=1e-3, atol=1e-6 * np.abs(expected).max())


def _phosphor_white_with_red() -> np.ndarray:
    """A warm phosphor-converted white like the physics suite's worst held-out case (physics-held_out-002): a
    463-nm pump 26 nm wide, a yellow phosphor and a strong red one (photons)."""
    nm = GRID.wavelengths_nm
    energy = (
        np.exp(-0.5 * ((nm - 463.0) / (26.0 / 2.3548)) ** 2)
        + 1.7 * np.exp(-0.5 * ((nm - 562.0) / (100.0 / 2.3548)) ** 2)
        + 0.8 * np.exp(-0.5 * ((nm - 650.0) / (90.0 / 2.3548)) ** 2)
    )
    return energy * nm / 555.0


def test_a_phosphor_white_is_not_read_as_a_spike_where_the_camera_is_blind() -> None:
    """Under Munsell chips (outside the reflectance basis's Natural-100) and a Nikon D70, free bands (any centre,
    8–180 nm) missed this light by 0.69 of the LEDs' error; the solid-state forms as LEDs are made, held where the
    camera sees, and averaged by evidence: 0.38."""
    leds, _ = _leds_and_camera()
    camera = datasets.camera_responsivities("NikonD70").resample(GRID).to_unit("photons")
    light = _phosphor_white_with_red()
    surfaces = datasets.vrhel("munsell").resample(GRID).values
    statistics = _statistics(light, seed=0, surfaces=surfaces, camera=camera)
    estimate = family_model(statistics.channels, leds, camera).estimate(statistics)
    shape = estimate.spectrum.values[:, 0] / estimate.spectrum.values[:, 0].max()
    truth = light * float(light @ shape) / float(light @ light)
    error = float(np.sqrt(np.mean((shape - truth) ** 2)))
    led = estimate.led.fit.spectrum / estimate.led.fit.spectrum.max()
    led_error = float(np.sqrt(np.mean((led - light * float(light @ led) / float(light @ light)) ** 2)))
    assert error < 0.5 * led_error, (estimate.reason, error, led_error)


def test_solid_state_bands_are_held_where_the_camera_sees() -> None:
    leds, camera = _leds_and_camera()
    model = family_model(("R", "G", "B"), leds, camera)
    low, high = model.seen_nm
    assert GRID.wavelengths_nm[0] <= low < high <= GRID.wavelengths_nm[-1]
    for form in model.forms:
        if form.family != "solid_state":
            continue
        for name, (lower, upper) in zip(form.parameters, form.bounds):
            if name.startswith("centre_"):
                assert low <= lower <= upper <= high, (form.name, name)
            else:
                assert lower >= 12.0, (form.name, name)  # no LED or phosphor band is narrower
