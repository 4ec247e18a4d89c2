"""Local ambient estimation (issue 9): tiled statistics, smoothing, model selection, local synthesis.

Scenes come from :func:`lab.study.local.make_scenario` (random surface mosaics, the sim rig's
sensor with noise); the seeds here (< 100) are not the study's (≥ 1000), and the selection margin
was calibrated on the study's scenes, not on these.
"""

from __future__ import annotations

import re
from functools import cache

import numpy as np
import pytest

from msflash.lab.study.local import (
    Scenario,
    alone_rmse,
    led_bound,
    make_scenario,
    pixel_bound,
    pixel_rmse,
    pixel_truth,
    run_study,
    tiled_rmse,
)
from msflash.processing.accumulate import accumulate_statistics
from msflash.processing.ambient import AmbientModel
from msflash.processing.image_formation import MixedIllumination, expected_response
from msflash.processing.local import denoised_global, estimate_local, synthesize_local, upsample_tiles
from msflash.processing.local_selection import SELECTION_MARGIN, _solve_regions, segment_regions, select_model
from msflash.processing.metrics import spectrum_rmse
from msflash.processing.region_cells import Cells
from msflash.processing.statistics import FrameStackSpec
from msflash.processing.synthesis import synthesize
from msflash.processing.tile_statistics import TiledStatistics, _block_sums_and_differences, tile_statistics
from tests.helpers import EXACT, FLOAT32, ambient, camera, chart, leds_photons, linear_frames, rendered_frames, spec_for

SHAPE = (160, 192)
TILES = 6


@cache
def scenario(kind: str, seed: int) -> Scenario:
    return make_scenario(kind, seed, SHAPE)


@cache
def tiled(kind: str, seed: int) -> TiledStatistics:
    s = scenario(kind, seed)
    return tile_statistics(s.ambient, s.led_frames, s.spec, TILES, bin_factor=4)


# -- tiled statistics ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("bin_factor", "cfa", "tiles"), [(1, None, 5), (2, None, (3, 4)), (4, None, 2), (2, "GRBG", 3)]
)
def test_tiles_sum_to_the_global_statistics(bin_factor: int, cfa: str | None, tiles: int | tuple[int, int]) -> None:
    from msflash.processing.sensor import SensorModel

    sensor = SensorModel(cfa=cfa)
    frames = rendered_frames(ambient("tungsten"), sensor=sensor, noise=True, scene=chart(specular_strip_px=5))
    a, led_frames, exposures, gains = frames
    a, led_frames = a[:56], [f[:56] for f in led_frames]  # even height: the CFA planes lose nothing
    spec = spec_for(sensor, exposures, gains, np.eye(7))
    period = 2 if cfa else 1
    reference = accumulate_statistics(a, led_frames, spec, bin_factor=bin_factor, cfa_period=period)
    total = tile_statistics(a, led_frames, spec, tiles, bin_factor=bin_factor, cfa_period=period).total()
    assert reference.saturated_fraction > 0  # the specular strip saturates: masking is exercised
    np.testing.assert_allclose(total.gram, reference.gram, rtol=EXACT * 100)
    np.testing.assert_allclose(total.cross, reference.cross, rtol=EXACT * 100)
    np.testing.assert_allclose(total.led_sums, reference.led_sums, rtol=EXACT * 100)
    assert total.ambient_energy == pytest.approx(reference.ambient_energy, rel=EXACT)
    assert total.ambient_sum == pytest.approx(reference.ambient_sum, rel=EXACT)
    assert (total.n_samples, total.n_total) == (reference.n_samples, reference.n_total)


@pytest.mark.parametrize("dtype", [np.uint16, np.float64])
@pytest.mark.parametrize(("factor", "channels"), [(2, 1), (4, 3), (6, 4)])
def test_block_sums_and_half_differences_are_exact(dtype: type, factor: int, channels: int) -> None:
    """One pass gives each block's sum and its checkerboard half difference: the members at even row + column
    minus those at odd (edges dropped)."""
    rng = np.random.default_rng(factor)
    plane = rng.integers(0, 65536, size=(5 * factor + 1, 7 * factor + 3, channels)).astype(dtype)
    sums, differences = np.empty((5, 7, channels)), np.empty((5, 7, channels))
    _block_sums_and_differences(plane, factor, sums, differences)
    blocks = plane[: 5 * factor, : 7 * factor].astype(float).reshape(5, factor, 7, factor, channels)
    np.testing.assert_array_equal(sums, blocks.sum(axis=(1, 3)))
    even = blocks[:, 0::2, :, 0::2].sum(axis=(1, 3)) + blocks[:, 1::2, :, 1::2].sum(axis=(1, 3))
    odd = blocks[:, 0::2, :, 1::2].sum(axis=(1, 3)) + blocks[:, 1::2, :, 0::2].sum(axis=(1, 3))
    np.testing.assert_array_equal(differences, even - odd)


def _in_span_noisy_stack(
    noise_gain: float, seed: int = 0
) -> tuple[np.ndarray, list[np.ndarray], FrameStackSpec, np.ndarray]:
    """Float frames whose ambient is exactly ``Σ w_k`` LED image k, with signal-dependent noise ``σ² = gain · signal``.

    The LED images are 8 × 8-pixel patches of random levels per channel with a ±20 % texture inside
    (blocks of 4 see both), so the weights are well determined once the noise bias is gone. At gain 10
    the per-pixel noise is about the size of one LED's signal (far noisier than the sim rig's frames).
    """
    rng = np.random.default_rng(seed)
    k, height, width = 7, 256, 384
    patches = rng.uniform(0.1, 1.0, size=(k, height // 8, width // 8, 3))
    images = (
        np.repeat(np.repeat(patches, 8, axis=1), 8, axis=2) * rng.uniform(0.8, 1.2, size=(k, height, width, 3)) * 100
    )
    weights = rng.uniform(0.2, 1.0, size=k)
    ambient_image = np.tensordot(weights, images, axes=1)

    def noisy(x: np.ndarray) -> np.ndarray:
        return x + rng.normal(size=x.shape) * np.sqrt(noise_gain * x)

    spec = FrameStackSpec(
        black_level=0.0, white_level=1e12, ambient_scale=1.0, led_scales=(1.0,) * k, led_levels=np.eye(k)
    )
    return noisy(ambient_image), [noisy(ambient_image + image) for image in images], spec, weights


def test_denoised_statistics_remove_the_noise_bias_of_the_led_only_images() -> None:
    """Errors in variables: the LED-only images are differences of noisy frames, so their moments are biased.

    Plain least squares on the observed statistics is pulled away from the true weights; on the
    denoised statistics (half-block cross-products) it recovers them, with no noise model given.
    """
    ambient_frame, led_frames, spec, weights = _in_span_noisy_stack(noise_gain=10.0)
    t = tile_statistics(ambient_frame, led_frames, spec, 3, bin_factor=4)
    assert t.denoised is not None and t.denoised.shape == t.shape
    observed, denoised = t.total(), t.denoised.total()
    # Counts and sums carry no noise bias: they are the observed ones.
    assert denoised.n_samples == observed.n_samples and denoised.ambient_sum == observed.ambient_sum
    # The noise adds to every diagonal of the observed Gram matrix (independent frames).
    assert np.all(np.diag(observed.gram) > np.diag(denoised.gram))
    error_observed = np.abs(np.linalg.solve(observed.gram, observed.cross) - weights).max()
    error_denoised = np.abs(np.linalg.solve(denoised.gram, denoised.cross) - weights).max()
    assert error_observed > 0.07 and error_denoised < 0.4 * error_observed, (error_observed, error_denoised)
    # The global model of estimate_local, denoised_global and the local model solve on the denoised
    # statistics; without the noise correction everything is solved as observed (the paper's estimate).
    leds = leds_photons()
    assert np.abs(denoised_global(t, leds, "lstsq") - weights).max() < 0.4 * error_observed
    corrected = estimate_local(t, leds, "global", solver="lstsq").global_estimate.ambient_weights
    np.testing.assert_allclose(corrected, denoised_global(t, leds, "lstsq"), rtol=1e-9)
    paper = estimate_local(t, leds, "global", solver="lstsq", noise_correction=False).global_estimate.ambient_weights
    np.testing.assert_allclose(paper, np.linalg.solve(observed.gram, observed.cross), rtol=1e-6)
    local = estimate_local(
        t, leds, "local", solver="lstsq", smoothing=1e6, regions_allowed=False
    )  # every tile sees all
    assert np.abs(local.tile_weights - weights).max() < 0.4 * error_observed
    plain = estimate_local(
        t, leds, "local", solver="lstsq", smoothing=1e6, regions_allowed=False, noise_correction=False
    )
    np.testing.assert_allclose(plain.tile_weights[0, 0], paper, rtol=1e-6)
    # The cells carry the same correction (single blocks: exactly the tiles'); odd bin factors have none.
    cells = Cells.of(t.blocks, 1)  # type: ignore[arg-type]
    everything = cells.denoised_statistics(np.ones(cells.gram.shape[0], dtype=bool))
    assert everything is not None
    np.testing.assert_allclose(everything.gram, denoised.gram, rtol=1e-9)
    np.testing.assert_allclose(everything.cross, denoised.cross, rtol=1e-9)
    assert tile_statistics(ambient_frame, led_frames, spec, 3, bin_factor=3).denoised is None


@pytest.mark.parametrize(
    ("shape", "bin_factor", "period", "block"),
    [
        ((1, 1), 1, 2, "2×2-pixel block (1×1 of the mosaic's 2×2 quads)"),
        ((3, 7), 2, 2, "4×4-pixel block (2×2 of the mosaic's 2×2 quads)"),
        ((3, 7, 3), 4, 1, "4×4-pixel block; expected a larger frame"),
    ],
)
def test_a_frame_smaller_than_one_block_names_the_block_in_pixels(
    shape, bin_factor: int, period: int, block: str
) -> None:
    """A 1×1 Bayer frame was 'smaller than one 1×1 block' (the block counted in quads, not pixels)."""
    from msflash.processing.errors import SpectralDataError

    frame = np.ones(shape)
    spec = FrameStackSpec(0.0, 1e9, 1.0, (1.0,), np.eye(1))
    with pytest.raises(SpectralDataError, match=re.escape(f"frame of shape {shape} is smaller than one {block}")):
        tile_statistics(frame, [frame], spec, 2, bin_factor=bin_factor, cfa_period=period)


def test_tile_geometry_covers_the_frame() -> None:
    t = tiled("uniform", 1)
    assert t.shape == (TILES, TILES)
    assert t.row_edges[0] == 0 and t.row_edges[-1] == SHAPE[0] and t.column_edges[-1] == SHAPE[1]
    assert t.areas.sum() == SHAPE[0] * SHAPE[1]


def test_smoothing_is_a_weighted_sum_of_neighbours() -> None:
    t = tiled("boundary", 2)
    wide = t.smoothed(1e6)  # every tile sees all the others with weight 1
    np.testing.assert_allclose(wide.gram[2, 3], t.total().gram, rtol=1e-9)
    narrow = t.smoothed(1e-3)  # only itself
    np.testing.assert_allclose(narrow.gram, t.gram, rtol=1e-12)
    left_out = t.smoothed(1.0, leave_out=True)
    np.testing.assert_allclose(
        left_out.cross, t.smoothed(1.0).cross - t.cross, rtol=1e-9, atol=1e-9 * np.abs(t.cross).max()
    )
    expected = sum(
        np.exp(-((i - 2) ** 2 + (j - 3) ** 2) / 2.0) * t.cross[i, j] for i in range(TILES) for j in range(TILES)
    )
    np.testing.assert_allclose(t.smoothed(1.0).cross[2, 3], expected, rtol=1e-9)


def test_noise_free_in_span_local_recovers_each_side_exactly() -> None:
    """Two LED-mix ambients split down the middle: tiles entirely on one side recover its weights."""
    left_mix, right_mix = (
        np.array([0.2, 0.05, 0.4, 0.3, 0.6, 0.1, 0.25]),
        np.array([0.6, 0.3, 0.1, 0.05, 0.2, 0.4, 0.1]),
    )
    leds = leds_photons()
    scene = chart()
    mixing = np.zeros(scene.shape)
    mixing[:, 28:] = 1.0
    left = leds.replace(values=(leds.values @ left_mix)[:, None], names=("left",))
    right = leds.replace(values=(leds.values @ right_mix)[:, None], names=("right",))
    illumination = MixedIllumination.two_ambients(left, right, mixing)
    dark = left.replace(values=np.zeros_like(left.values))
    cam = camera()
    frames = [
        expected_response(scene, illumination.plus(dark.replace(values=leds.values @ row[:, None])), cam, 1.0)
        for row in np.vstack([np.zeros(7), np.eye(7)])
    ]
    _, _, spec = linear_frames(left)
    t = tile_statistics(frames[0], frames[1:], spec, (1, 4))
    local = estimate_local(t, leds, "local", solver="lstsq", smoothing=1e-3)
    np.testing.assert_allclose(local.tile_weights[0, 0], left_mix, rtol=1e-6)
    np.testing.assert_allclose(local.tile_weights[0, 3], right_mix, rtol=1e-6)
    assert estimate_local(t, leds, "auto", solver="lstsq").model == "local"
    # The two-region model finds the split.
    regions = estimate_local(t, leds, "local", solver="lstsq")
    assert regions.structure == "regions"
    labels = regions.regions.label_map(frames[0].shape[:2])  # type: ignore[union-attr]
    left_label = bool(labels[0, 0])
    # The box vote may pull the edge by up to its radius (2 blocks) towards the brighter side.
    assert np.all(labels[:, :26] == left_label) and np.all(labels[:, 30:] != left_label)
    assert np.mean(labels[:, :28] == left_label) > 0.9 and np.mean(labels[:, 28:] != left_label) > 0.9
    # (The pooled weights are then not exact: the unregularised lstsq amplifies the few mixed cells.)


def test_block_cells_sum_to_the_tile_statistics() -> None:
    """The cells (single blocks, and 2 × 2 blocks) carry the same statistics as the tiles."""
    t = tiled("boundary", 2)
    total = t.total()
    for group in (1, 2):
        cells = Cells.of(t.blocks, group)  # type: ignore[arg-type]
        assert cells.valid.shape == (t.blocks.shape[0] // group, t.blocks.shape[1] // group)  # type: ignore[union-attr]
        everything = cells.statistics(np.ones(cells.gram.shape[0], dtype=bool))
        np.testing.assert_allclose(everything.led_sums, total.led_sums, rtol=1e-9 if group == 1 else 0.05)
        if group == 1:  # every block: exactly the tiles' sums
            np.testing.assert_allclose(everything.gram, total.gram, rtol=1e-9)
            np.testing.assert_allclose(everything.cross, total.cross, rtol=1e-9)
            assert everything.ambient_energy == pytest.approx(total.ambient_energy, rel=1e-9)
        # Per-cell residuals of any weights add up to the pooled statistics' residual.
        w = np.array([0.2, 0.1, 0.0, 0.3, 0.5, 0.2, 0.1])
        expected = everything.ambient_energy - 2 * everything.cross @ w + w @ everything.gram @ w
        assert cells.errors(w[None]).sum() == pytest.approx(expected, rel=1e-9)


# -- model selection ------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", [1, 3, 5, 7, 9])
def test_uniform_scene_auto_chooses_global(seed: int) -> None:
    s = scenario("uniform", seed)
    selection = select_model(tiled("uniform", seed), s.led_spectra)
    assert selection.model == "global", selection.scores
    assert min(v for k, v in selection.scores.items() if k != "global") > 1.0 - SELECTION_MARGIN
    auto = estimate_local(tiled("uniform", seed), s.led_spectra, "auto")
    # No loss of accuracy: auto *is* the global estimate.
    np.testing.assert_array_equal(auto.mean_weights, auto.global_estimate.ambient_weights)


@pytest.mark.parametrize(("camera_name", "seed"), [("NikonD200IR", 0), ("AptinaMT9M031", 15)])
def test_noise_free_uniform_scene_stays_global_though_a_local_fit_cuts_its_tiny_misfit(
    camera_name: str, seed: int
) -> None:
    """Without noise the global model's held-out error is only the misfit of an ambient outside the
    LEDs' span (relative residual ~1 %); neighbours' fits cut it by 20–30 %, which the ratio alone
    would take for a second ambient. The cut is ~10⁻⁵ of the ambient image's energy, far below
    the 10⁻³ a local model must explain."""
    s = make_scenario("uniform", seed, SHAPE, camera=camera_name, noise=False)
    t = tile_statistics(s.ambient, s.led_frames, s.spec, TILES, bin_factor=4)
    selection = select_model(t, s.led_spectra)
    assert min(v for k, v in selection.scores.items() if k != "global") < 0.8  # the ratio alone says local
    assert selection.explained_gain < 1e-4 and selection.model == "global"
    assert estimate_local(t, s.led_spectra, "auto").model == "global"


@pytest.mark.parametrize(("kind", "seed"), [("boundary", 2), ("boundary", 4), ("boundary", 6), ("gradient", 8)])
def test_two_illuminant_scene_auto_chooses_local(kind: str, seed: int) -> None:
    s = scenario(kind, seed)
    selection = select_model(tiled(kind, seed), s.led_spectra)
    assert selection.model == "local", selection.scores
    assert min(v for k, v in selection.scores.items() if k != "global") < 0.5
    assert selection.explained_gain > 4 * selection.min_explained_gain


def test_local_cuts_the_spectrum_rmse_on_two_illuminant_scenes() -> None:
    """Boundary scenes 2, 4, 6: per scene local beats global; on their mean, most of what perfect locality gives."""
    rows = []
    for seed in (2, 4, 6):
        s = scenario("boundary", seed)
        t = tiled("boundary", seed)
        auto = estimate_local(t, s.led_spectra, "auto")
        assert auto.structure == "regions"
        global_rmse = pixel_rmse(auto.global_estimate.spectrum.values[:, 0], s)
        local_rmse = pixel_rmse(auto, s)
        assert local_rmse < 0.9 * global_rmse, (s.names, global_rmse, local_rmse)
        # The labels follow the true boundary, not the tile grid.
        labels = auto.regions.label_map(SHAPE)  # type: ignore[union-attr]
        truth = s.illumination.weights[..., 1] > s.illumination.weights[..., 0]
        assert max(np.mean(labels == truth), np.mean(labels != truth)) >= 0.9
        rows.append(
            [
                global_rmse,
                local_rmse,
                pixel_rmse(estimate_local(t, s.led_spectra, "local", regions_allowed=False), s),
                alone_rmse("boundary", seed, SHAPE),
                pixel_bound(s),
                pixel_rmse(estimate_local(t, s.led_spectra, "auto", noise_correction=False), s),
            ]
        )
    global_rmse, local_rmse, tiles_rmse, alone, bound, observed_rmse = np.mean(rows, axis=0)
    assert local_rmse <= 0.75 * global_rmse, rows
    # Part of either error is the LEDs' inability to reproduce the named ambients (~0.18 here):
    # the raw cut is smaller than the cut of the excess over that bound.
    assert local_rmse - bound <= 0.5 * (global_rmse - bound), rows
    # Most of the error left is the estimator's own: with each ambient estimated alone over the
    # whole scene (perfect locality) the error drops little further.
    assert alone < global_rmse and local_rmse - alone <= 0.35 * (global_rmse - alone), rows
    assert local_rmse <= tiles_rmse, rows
    # Without the noise correction the regions' estimates are worse (tungsten and daylight sides).
    assert local_rmse < observed_rmse, rows


def test_gradient_scene_keeps_the_tile_model() -> None:
    """A smooth ramp is explained better by an affine field than by two regions: tiles are solved."""
    s = scenario("gradient", 8)
    t = tiled("gradient", 8)
    regions = segment_regions(t, s.led_spectra, 0.01)
    assert regions is not None and regions.residual > regions.affine_residual
    auto = estimate_local(t, s.led_spectra, "auto")
    assert (auto.model, auto.structure, auto.regions) == ("local", "tiles", None)


def test_pixel_metric_is_each_pixels_estimate_against_its_own_ambient() -> None:
    """The study's metric: per pixel, the pixel's estimate against the pixel's true ambient, averaged."""
    s = scenario("boundary", 2)
    truth = pixel_truth(s)
    second = (s.illumination.weights[..., 1] > 0).ravel()
    sides = [truth[~second][0], truth[second][0]]
    estimate = s.led_spectra.values @ np.full(7, 0.3)
    expected = np.mean(~second) * spectrum_rmse(estimate, sides[0]) + np.mean(second) * spectrum_rmse(
        estimate, sides[1]
    )
    assert pixel_rmse(estimate, s) == pytest.approx(expected, rel=1e-9)
    # The bound is the best LED fit of each side, weighted by the sides' areas.
    fits = [
        tiled_rmse(led_bound(s.led_spectra.values, side[None, None]), side[None, None], np.ones((1, 1)))
        for side in sides
    ]
    assert pixel_bound(s) == pytest.approx(np.mean(~second) * fits[0] + np.mean(second) * fits[1], rel=1e-6)


def test_alone_reference_renders_the_same_scene_under_each_ambient() -> None:
    mixed = scenario("boundary", 2)
    for index in (0, 1):
        single = make_scenario("boundary", 2, SHAPE, alone=index)
        assert single.names == mixed.names
        np.testing.assert_array_equal(single.illumination.spectra.values, mixed.illumination.spectra.values)
        assert np.all(single.illumination.weights[..., 1] == index)


def test_forced_global_and_bad_method() -> None:
    s = scenario("boundary", 2)
    forced = estimate_local(tiled("boundary", 2), s.led_spectra, "global")
    assert forced.model == "global" and forced.selection is None
    assert np.all(forced.tile_weights == forced.global_estimate.ambient_weights)
    with pytest.raises(ValueError, match="auto, global, local"):
        estimate_local(tiled("boundary", 2), s.led_spectra, "patchy")


# -- the spatially varying image ----------------------------------------------------------------
def test_upsampling_is_exact_at_tile_centres_and_constant_for_constant_tiles() -> None:
    t = tiled("uniform", 1)
    values = np.arange(TILES * TILES, dtype=float).reshape(TILES, TILES)
    maps = upsample_tiles(values, t)
    rows, columns = t.centres
    assert maps.shape == SHAPE
    for i in range(TILES):
        for j in range(TILES):
            if float(rows[i]).is_integer() and float(columns[j]).is_integer():
                assert maps[int(rows[i]), int(columns[j])] == pytest.approx(values[i, j])
    np.testing.assert_allclose(upsample_tiles(np.full((TILES, TILES, 2), 3.0), t), 3.0)
    assert maps.min() >= values.min() and maps.max() <= values.max()


def test_local_synthesis_equals_global_for_equal_weights_and_blends_between() -> None:
    s = scenario("boundary", 2)
    t = tiled("boundary", 2)
    weights = np.array([0.5, 0.1, 0.0, 0.3, 1.0, 0.2, 0.7])
    image, saturated = synthesize_local(s.ambient, s.led_frames, s.spec, np.broadcast_to(weights, (TILES, TILES, 7)), t)
    reference, reference_saturated = synthesize(s.ambient, s.led_frames, s.spec, weights)
    np.testing.assert_allclose(image, reference, rtol=0, atol=FLOAT32 * float(np.abs(reference).max()))
    np.testing.assert_array_equal(saturated, reference_saturated)
    offsets = np.array([0.2, -0.1, 0.0, 0.3, 0.1, -0.2, 0.05])  # a flickering lamp's shares: the same taken out
    flickering, _ = synthesize_local(
        s.ambient, s.led_frames, s.spec, np.broadcast_to(weights, (TILES, TILES, 7)), t, offsets
    )
    flickering_reference, _ = synthesize(s.ambient, s.led_frames, s.spec, weights, ambient_offsets=offsets)
    assert np.abs(flickering_reference - reference).max() > 100 * FLOAT32 * float(np.abs(reference).max())
    np.testing.assert_allclose(flickering, flickering_reference, rtol=0, atol=FLOAT32 * float(np.abs(reference).max()))
    # Two different mixes left and right: pixels at the tile centres get their own tile's image.
    varying = np.zeros((TILES, TILES, 7))
    varying[:, : TILES // 2] = weights
    varying[:, TILES // 2 :] = weights[::-1]
    image, _ = synthesize_local(s.ambient, s.led_frames, s.spec, varying, t)
    reversed_image, _ = synthesize(s.ambient, s.led_frames, s.spec, weights[::-1])
    rows, columns = t.centres
    r, c0, c1 = int(rows[1]), int(columns[0]), int(columns[-1])
    np.testing.assert_allclose(image[r, c0], reference[r, c0], rtol=1e-4)
    np.testing.assert_allclose(image[r, c1], reversed_image[r, c1], rtol=1e-4)


# -- the acceptance study (long) ------------------------------------------------------------------
@cache
def _study() -> dict:
    return run_study(n_uniform=100, n_mixed=30, sweep=False)


@pytest.mark.study
def test_acceptance_study() -> None:
    """Issue 9 acceptance, the parts that are met: ≥ 95 % global on uniform scenes with no loss, ≤ 3× cost.

    On boundary scenes the local estimate must reach most of the cut that perfect locality gives
    (each ambient estimated alone over the whole scene): what is left is the estimator's own
    error. Measured numbers: docs/local-estimation.md.
    """
    summary = _study()
    assert summary["uniform"]["global_rate"] >= 0.95
    assert summary["uniform"]["rmse_auto"] <= summary["uniform"]["rmse_global"] * 1.001
    assert summary["timing"]["auto_ratio"] <= 3.0
    boundary = summary["boundary"]
    assert boundary["regions_rate"] >= 0.9 and boundary["label_accuracy"] >= 0.97
    assert boundary["rmse_global"] - boundary["rmse_auto"] >= 0.8 * (boundary["rmse_global"] - boundary["rmse_alone"])
    assert summary["gradient"]["rmse_auto"] < summary["gradient"]["rmse_global"]


@pytest.mark.study
def test_issue_target_thirty_percent_cut_on_boundary_scenes() -> None:
    """The issue's figure as it states it: raw spectrum RMSE, local (auto) against global, on two-illuminant (boundary) scenes.

    Global is the paper's estimate (what ``msflash estimate --method global`` gives); the local model
    is solved on denoised statistics. Seeds from 1000 (not used in development): 35.7 %; other
    fresh sets: 34.3 % (500 000), 30.2 % (300 000). Against the global model solved on denoised
    statistics too (what locality alone adds): 35.0 %, 32.3 %, 29.3 %; docs/local-estimation.md.
    """
    boundary = _study()["boundary"]
    assert boundary["auto_cut"] >= 0.30
    # Most of it is locality's: against the global model with the same (denoised) estimator.
    assert boundary["locality_cut"] >= 0.9 * boundary["auto_cut"]


def test_a_region_of_fewer_samples_than_leds_keeps_its_first_weights() -> None:
    """A region of a few blocks (a flickering rendering's second region held 4) cannot be solved by eq. 4–6: it
    keeps the labelling's ridge weights instead of refusing the whole estimate (it raised SpectralDataError)."""
    s = scenario("boundary", 2)
    cells = Cells.of(tiled("boundary", 2).blocks)
    labels = np.zeros(cells.valid.shape, dtype=bool)
    labels[tuple(np.argwhere(cells.valid)[0])] = True  # one cell: fewer samples than the 7 LEDs
    assert cells.statistics(labels[cells.valid]).n_samples <= 7
    first = np.stack([np.full(7, 0.2), np.full(7, 0.4)])
    final = _solve_regions(cells, labels, first, AmbientModel(s.led_spectra), "tikhonov", "auto", True)
    np.testing.assert_array_equal(final[1], first[1])
    assert not np.array_equal(final[0], first[0])  # the large region is solved
