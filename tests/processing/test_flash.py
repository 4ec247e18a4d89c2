"""Flash solvers: matching (eq. 7) and complementary (eq. 8–9), bounds, reachability, tie-breaks."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from msflash.processing import datasets
from msflash.processing.errors import SolverError, SpectralDataError, TargetUnreachableWarning
from msflash.processing.flash import (
    MATCHING_ROUND_OFF,
    UNREACHABLE_RELATIVE_ERROR,
    camera_led_matrix,
    solve_complementary,
    solve_matching,
)
from tests.helpers import GRID, SOLVER, WEIGHTS_EXACT, camera, led_mix, leds_photons

BOUNDS = ("physical", "nonnegative", "free")
AMBIENT_WEIGHTS = np.array([0.05, 0.02, 0.1, 0.2, 0.6, 0.3, 0.4])
"""A warm (reddish) ambient made of the LEDs."""


def d65():
    return datasets.illuminant("D65", GRID).to_unit("photons")


def chroma(response: np.ndarray) -> np.ndarray:
    return response / np.linalg.norm(response)


def assert_in_bounds(weights: np.ndarray, bounds: str) -> None:
    if bounds in ("physical", "nonnegative"):
        assert np.all(weights >= 0)
    if bounds == "physical":
        assert np.all(weights <= 1)


# -- matching ---------------------------------------------------------------------------------
@pytest.mark.parametrize("bounds", BOUNDS)
def test_matching_is_proportional_to_nonnegative_ambient(bounds: str) -> None:
    solution = solve_matching(AMBIENT_WEIGHTS, leds_photons(), camera(), bounds=bounds)
    np.testing.assert_allclose(solution.flash_weights, AMBIENT_WEIGHTS / AMBIENT_WEIGHTS.max(), atol=WEIGHTS_EXACT)
    assert solution.flash_weights.max() == pytest.approx(1.0, abs=1e-15)
    assert solution.relative_error < WEIGHTS_EXACT
    assert solution.target_reached and solution.scale is None and solution.mode == "matching"


def test_matching_with_negative_ambient_weights_stays_in_bounds() -> None:
    ambient = np.array([0.3, -0.1, 0.2, 0.5, 0.4, -0.05, 0.3])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TargetUnreachableWarning)
        solution = solve_matching(ambient, leds_photons(), camera())
    assert_in_bounds(solution.flash_weights, "physical")
    assert solution.flash_weights.max() == pytest.approx(1.0)
    # Its colour is as close as any non-negative mix: at least as close as the clipped ambient.
    matrix = camera_led_matrix(camera(), leds_photons())
    clipped = np.clip(ambient, 0, None)
    wanted = chroma(matrix @ ambient)
    assert (
        np.linalg.norm(chroma(matrix @ solution.flash_weights) - wanted)
        <= np.linalg.norm(chroma(matrix @ clipped) - wanted) + SOLVER
    )


def test_matching_zero_ambient_raises() -> None:
    with pytest.raises(SolverError, match="all zero"):
        solve_matching(np.zeros(7), leds_photons(), camera())


@pytest.mark.parametrize("bounds", ["physical", "nonnegative"])
@pytest.mark.parametrize(
    "ambient",
    [
        -AMBIENT_WEIGHTS,  # every camera channel negative: no light matches it better than none
        # A dark tile's noise-only estimate (sim rig, ambient frame at the black level): same situation.
        np.array([-1.67, -1.22, 5.56, -9.52, 2.34, -4.74, 2.05]) * 1e-12,
    ],
)
def test_matching_whose_best_mix_is_no_light_raises_instead_of_rescaling_round_off(
    ambient: np.ndarray, bounds: str
) -> None:
    """The QP's answer is w_f = 0 up to ~1e-9 round-off of either sign; rescaling that round-off to
    max 1 used to return a 'full-drive' mix with weights down to -0.5 under physical bounds."""
    with pytest.raises(SolverError, match="no non-negative LED mix matches"):
        solve_matching(ambient, leds_photons(), camera(), bounds=bounds)  # type: ignore[arg-type]


# -- complementary ----------------------------------------------------------------------------
@pytest.mark.parametrize("bounds", BOUNDS)
def test_complementary_target_equal_to_ambient_gives_zero_flash(bounds: str) -> None:
    target = led_mix(AMBIENT_WEIGHTS)
    solution = solve_complementary(AMBIENT_WEIGHTS, leds_photons(), camera(), target, bounds=bounds)
    np.testing.assert_allclose(solution.flash_weights, 0.0, atol=WEIGHTS_EXACT)
    assert solution.scale == pytest.approx(1.0, rel=WEIGHTS_EXACT)
    assert solution.relative_error < WEIGHTS_EXACT


@pytest.mark.parametrize("bounds", BOUNDS)
def test_complementary_reaches_d65_when_it_can(bounds: str) -> None:
    solution = solve_complementary(AMBIENT_WEIGHTS, leds_photons(), camera(), d65(), bounds=bounds)
    assert_in_bounds(solution.flash_weights, bounds)
    assert solution.scale >= 0
    matrix = camera_led_matrix(camera(), leds_photons())
    result = matrix @ (AMBIENT_WEIGHTS + solution.flash_weights)
    target = camera().values.T @ d65().values[:, 0]
    assert solution.target_reached
    assert np.linalg.norm(chroma(result) - chroma(target)) < 1e-4
    # s is the slack of eq. 8–9: ambient + flash ≈ s · Cᵀ i_d in absolute terms too.
    np.testing.assert_allclose(result, solution.scale * target, rtol=1e-3)


def test_complementary_least_total_power_tie_break() -> None:
    # Two LED sets that look the same to the camera: the cheapest mix wins.
    solution = solve_complementary(AMBIENT_WEIGHTS, leds_photons(), camera(), d65(), bounds="nonnegative")
    assert solution.flash_weights.sum() > 0
    matrix = camera_led_matrix(camera(), leds_photons())
    null = np.linalg.svd(matrix)[2][3:]  # directions the camera cannot see
    for direction in null:
        for step in (1e-3, -1e-3):
            candidate = solution.flash_weights + step * direction
            if np.all(candidate >= 0):
                assert candidate.sum() >= solution.flash_weights.sum() - SOLVER


def test_unreachable_target_warns() -> None:
    # Only the red LEDs: no mix can add the blue that D65 needs to a warm ambient.
    reds = leds_photons().select([4, 5, 6])
    with pytest.warns(TargetUnreachableWarning, match="cannot reach the target illuminant"):
        solution = solve_complementary(np.array([0.6, 0.3, 0.4]), reds, camera(), d65())
    assert not solution.target_reached
    assert solution.relative_error > UNREACHABLE_RELATIVE_ERROR
    assert solution.warnings and "cannot reach" in solution.warnings[0]
    assert_in_bounds(solution.flash_weights, "physical")
    assert solution.scale >= 0


def test_physical_bounds_cap_a_bright_ambient_request() -> None:
    # A strong blue deficit with a bright ambient needs more than full drive: physical stops at 1,
    # nonnegative may go beyond.
    bright = AMBIENT_WEIGHTS * 50
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", TargetUnreachableWarning)
        physical = solve_complementary(bright, leds_photons(), camera(), d65(), bounds="physical")
    free = solve_complementary(bright, leds_photons(), camera(), d65(), bounds="nonnegative")
    assert_in_bounds(physical.flash_weights, "physical")
    assert physical.flash_weights.max() == pytest.approx(1.0)
    assert free.flash_weights.max() > 1.0
    assert free.target_reached


def test_flash_bad_input() -> None:
    with pytest.raises(SpectralDataError, match="3 ambient weights for 7 LEDs"):
        solve_matching(np.ones(3), leds_photons(), camera())
    with pytest.raises(SpectralDataError, match="not finite"):
        solve_matching(np.array([np.nan] + [1.0] * 6), leds_photons(), camera())
    with pytest.raises(SpectralDataError, match="expected 'photons'"):
        solve_complementary(AMBIENT_WEIGHTS, leds_photons(), camera(), d65().to_unit("energy"))
    with pytest.raises(ValueError, match="flash bounds 'loose'"):
        solve_matching(AMBIENT_WEIGHTS, leds_photons(), camera(), bounds="loose")  # type: ignore[arg-type]


@pytest.mark.parametrize("bounds", BOUNDS)
def test_prepared_matching_problem_is_the_plain_quadratic(bounds: str) -> None:
    """FlashModel factors the matching problem once; each solve equals the one-shot QP on it."""
    from msflash.processing.flash import FlashModel, _box
    from msflash.processing.least_squares import minimise_quadratic

    model = FlashModel(leds_photons(), camera())
    rng = np.random.default_rng(3)
    for ambient in [AMBIENT_WEIGHTS, rng.normal(size=7), rng.uniform(0, 1, size=7)]:
        goal = ambient / abs(ambient).max()
        hessian = model._matching_hessian
        plain = minimise_quadratic(hessian, hessian @ goal, *_box(7, bounds)).x
        plain[abs(plain) < MATCHING_ROUND_OFF] = 0.0
        if plain.max() <= 0:
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", TargetUnreachableWarning)
            np.testing.assert_array_equal(model.matching(ambient, bounds).flash_weights, plain / plain.max())


@pytest.mark.parametrize("bounds", ["physical", "nonnegative", "free"])
def test_complementary_weights_are_the_rounded_clipped_qp_solution(bounds: str) -> None:
    """The weights are the QP's last solution with |w| < 1e-10 set to 0, then clipped to the bounds.

    The rounding and the clipping are fused in FlashModel when the lower bound is 0; this checks
    the fused form against the two-step definition, bit for bit, with ambients inside and outside
    the LEDs' gamut (negative weights, upper bounds active).
    """
    from msflash.processing.flash import FlashModel
    from msflash.processing.least_squares import minimise_quadratic, recording_problems

    model = FlashModel(leds_photons(), camera())
    target = model.target_response(datasets.illuminant("D65", GRID).to_unit("photons"))
    rng = np.random.default_rng(5)
    ambients = [AMBIENT_WEIGHTS, rng.normal(size=7), rng.uniform(0, 3, size=7), np.zeros(7)]
    for ambient in ambients:
        with warnings.catch_warnings(), recording_problems() as problems:
            warnings.simplefilter("ignore", TargetUnreachableWarning)
            weights = model.complementary(ambient, target, bounds).flash_weights
        x = minimise_quadratic(*problems[-1]).x[:7]
        x[abs(x) < 1e-10] = 0.0
        if bounds != "free":
            x = np.clip(x, 0.0, 1.0 if bounds == "physical" else None)
        np.testing.assert_array_equal(weights, x)
        assert not np.signbit(weights[weights == 0]).any()
