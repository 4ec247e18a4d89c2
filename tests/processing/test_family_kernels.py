"""The family model's compiled route (processing/family_kernels.py) against its numpy route: the same estimate."""

from __future__ import annotations

import numpy as np
import pytest

from msflash.processing import family_kernels
from msflash.processing.family_fit import fit_discharge, fit_form, fit_mixture
from msflash.processing.light_families import family_model
from msflash.processing.light_forms import daylight, planck
from msflash.processing.scipy_cores import nnls as scipy_nnls
from msflash.processing.spectral_data_term import scene_form
from tests.processing.test_light_families import GRID, _leds_and_camera, _phosphor_white_with_red, _statistics

numba_kernels = pytest.importorskip("msflash.processing.family_kernels_numba", reason="numba (the fast extra) absent")


def _lights() -> dict[str, np.ndarray]:
    nm = GRID.wavelengths_nm
    lines = np.zeros(nm.size)
    lines[[4, 15, 21]] = [1.0, 2.0, 1.5]  # a discharge lamp's lines on the grid, over a weak continuum
    return {
        "blackbody 2800 K": planck(nm, 2800.0) * nm,
        "daylight 6500 K": daylight(GRID, 6500.0) * nm,
        "phosphor white + red": _phosphor_white_with_red(),
        "lines": lines + 0.05 * planck(nm, 3000.0) * nm,
    }


def test_the_compiled_nonnegative_fit_is_scipys() -> None:
    """Lawson–Hanson on random and nearly collinear designs: the residual of scipy's NNLS, the same solution."""
    rng = np.random.default_rng(3)
    for trial in range(400):
        columns = int(rng.integers(1, 13))
        design = rng.normal(size=(31, columns)) * rng.uniform(0.01, 1.0, columns)
        if trial % 3 == 0 and columns > 2:
            design[:, 1] = design[:, 0] + 1e-7 * rng.normal(size=31)
        target = rng.normal(size=31)
        expected, norm = scipy_nnls(design, target, 30 * columns)
        solution, norm2, converged = numba_kernels.nnls(np.ascontiguousarray(design), target, 30 * columns)
        assert converged
        assert norm2 == pytest.approx(norm**2, rel=1e-9, abs=1e-12)
        assert np.all(solution >= 0)
        if trial % 3:  # well-posed: the solution is unique
            np.testing.assert_allclose(solution, expected, rtol=1e-7, atol=1e-9)


@pytest.mark.parametrize("light", sorted(_lights()))
def test_both_routes_fit_and_judge_alike(light: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every form's fit, the discharge greedy fit, the mixtures and the whole estimate: the same on both routes."""
    leds, camera = _leds_and_camera()
    statistics = _statistics(_lights()[light], seed=7)
    model = family_model(statistics.channels, leds, camera)
    scene = scene_form(statistics, model.reduction)
    problem = scene.whitened(list(range(scene.n_folds)))
    results = {}
    for route in ("numpy", "numba"):
        monkeypatch.setenv("MSFLASH_KERNELS", route)
        assert (family_kernels.kernels() is not None) == (route == "numba")
        forms = [fit_form(form, GRID, problem) for form in model.forms]
        greedy = fit_discharge(GRID, problem)
        mixtures = [fit_mixture(greedy[-1], fit, GRID, problem) for fit in forms[:3]]
        mixtures.append(fit_mixture(forms[0], forms[-1], GRID, problem))
        results[route] = (forms + greedy + mixtures, model.estimate(statistics))
    (fits_numpy, numpy_estimate), (fits_numba, numba_estimate) = results["numpy"], results["numba"]
    for one, other in zip(fits_numpy, fits_numba):
        assert one.name == other.name
        assert one.atom_names == other.atom_names
        assert other.objective == pytest.approx(one.objective, rel=1e-6, abs=1e-12), one.name
    assert numba_estimate.chosen.fit.name == numpy_estimate.chosen.fit.name
    assert numba_estimate.auto_model == numpy_estimate.auto_model
    by_name = {c.fit.name: c for c in numpy_estimate.candidates}
    for candidate in numba_estimate.candidates:
        expected = by_name[candidate.fit.name]
        assert candidate.held_out_error == pytest.approx(expected.held_out_error, rel=1e-6, abs=1e-12)
        assert candidate.held_out_error_noise_removed == pytest.approx(
            expected.held_out_error_noise_removed, rel=1e-5, abs=1e-9
        )
    spectrum = numpy_estimate.spectrum.values[:, 0]
    np.testing.assert_allclose(numba_estimate.spectrum.values[:, 0], spectrum, atol=1e-6 * np.abs(spectrum).max())


def test_the_compiled_fits_are_opt_in(monkeypatch: pytest.MonkeyPatch) -> None:
    """Loading them costs a process seconds against milliseconds saved: only a prepared process (or one forced by
    MSFLASH_KERNELS=numba) takes them, and never while a camera streams (frame_kernels.paused) or with numpy."""
    from msflash.processing import frame_kernels

    monkeypatch.delenv("MSFLASH_KERNELS", raising=False)
    monkeypatch.setattr(family_kernels, "_prepared", False)
    assert family_kernels.kernels() is None
    assert family_kernels.prepare()
    assert family_kernels.kernels() is not None
    with frame_kernels.paused():
        assert family_kernels.kernels() is None
    with family_kernels.as_one_shot():  # the bench's one-shot figure: the numpy fits, the frame kernels kept
        assert family_kernels.kernels() is None and frame_kernels.enabled()
    assert family_kernels.kernels() is not None
    monkeypatch.setenv("MSFLASH_KERNELS", "numpy")
    assert family_kernels.kernels() is None


def test_a_route_passed_to_the_fits_is_the_one_they_take(monkeypatch: pytest.MonkeyPatch) -> None:
    """The family estimate asks for the compiled fits once and passes the answer to every fit: ``compiled=None``
    gives the numpy route's fits to the bit, the kernels passed in the compiled route's, whatever the process has
    prepared — so one estimate never mixes the two routes."""
    from msflash.processing.family_fit import ASK, start_costs

    leds, camera = _leds_and_camera()
    statistics = _statistics(_lights()["phosphor white + red"], seed=11)
    model = family_model(statistics.channels, leds, camera)
    scene = scene_form(statistics, model.reduction)
    problem = scene.whitened(list(range(scene.n_folds)))

    def fits(compiled: object = ASK) -> list:  # ASK: each fit asks family_kernels.kernels() itself
        costs = start_costs(model.forms, GRID, problem, compiled)
        forms = [fit_form(form, GRID, problem, True, cost, compiled) for form, cost in zip(model.forms, costs)]
        greedy = fit_discharge(GRID, problem, 6, compiled)
        return [*forms, *greedy, fit_mixture(greedy[-1], forms[0], GRID, problem, compiled)]

    def same(one: list, other: list) -> bool:
        return all(
            a.name == b.name and np.array_equal(a.theta, b.theta) and np.array_equal(a.amplitudes, b.amplitudes)
            and a.objective == b.objective
            for a, b in zip(one, other, strict=True)
        )  # fmt: skip

    monkeypatch.setenv("MSFLASH_KERNELS", "numpy")
    numpy_route = fits()
    monkeypatch.setenv("MSFLASH_KERNELS", "numba")
    compiled = family_kernels.kernels()
    assert compiled is not None
    compiled_route = fits()
    assert not same(numpy_route, compiled_route)  # the routes agree to rounding only: the test can tell them apart
    assert same(fits(None), numpy_route)  # asked once as "numpy", whatever the process could take
    assert same(fits(compiled), compiled_route)
    monkeypatch.setenv("MSFLASH_KERNELS", "numpy")
    assert same(fits(compiled), compiled_route)  # the answer passed in, not the environment now
