"""The sensor's noise line from one raw frame (processing.noise_level) and the noise probe of the moments.

On a Bayer mosaic one CFA plane's samples lie 2 pixels apart, so scene texture the two halves of a
block do not share filled the noise probe: on the simulated chart 99 % of the half differences' energy
was the chart, the photon-transfer line fitted to them put the weights up to 20× off either way, and
raw frames landed at 1.2× the LED bound where RGB ones landed at 0.92× (docs/raw-frames.md).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from msflash.processing.block_rows import BlockRows
from msflash.processing.block_sums import block_sums_and_differences, cfa_planes
from msflash.processing.noise_level import FIT_CELLS, PixelNoise, detail_noise_line, fit_detail_line, haar_details
from msflash.processing.scenes import chart_scene
from msflash.processing.sensor import SensorModel
from tests.helpers import ambient, rendered_frames

SENSOR = SensorModel(cfa="RGGB")
"""The sim rig's former sensor as a mosaic: 0.5 e⁻/DN (a variance of 2 DN² per DN), 2 e⁻ read noise."""
SIM_CHART = chart_scene("chart110", patch_px=8, border_px=2, specular_strip_px=4)
"""The sim rig's chart: 8-pixel patches, 2-pixel borders, a saturating highlight strip; 106 × 112 pixels."""


def _true_pixel_noise(sensor: SensorModel) -> PixelNoise:
    """Photon noise ``level / electrons_per_dn`` DN², read noise and rounding (1/12 DN²)."""
    return PixelNoise(1.0 / sensor.electrons_per_dn, (sensor.read_noise_e / sensor.electrons_per_dn) ** 2 + 1.0 / 12)


def _cells(levels: np.ndarray, rng: np.random.Generator, read: float = 16.0) -> tuple[np.ndarray, ...]:
    """(S, HH, HL, LH) of 2 × 2 cells at ``levels`` (n, 4) with Poisson-Gaussian noise: gain 2, ``read``."""
    x = levels + rng.normal(0.0, np.sqrt(2.0 * levels + read))
    return (
        x.sum(axis=1),
        x[:, 0] - x[:, 1] - x[:, 2] + x[:, 3],
        x[:, 0] - x[:, 1] + x[:, 2] - x[:, 3],
        x[:, 0] + x[:, 1] - x[:, 2] - x[:, 3],
    )


@pytest.mark.parametrize("textured", [0.0, 0.2, 0.45])
def test_the_line_is_found_beside_cells_holding_corners_and_fine_texture(textured: float) -> None:
    """Up to 45 % of the cells hold a corner (one sample 1.5–3× the others) or a fine checkerboard pattern
    (which leaves HL and LH alone): the gain is found within 5 %."""
    rng = np.random.default_rng(7)
    levels = rng.uniform(200.0, 3000.0, (40000, 1)) * np.ones((1, 4))
    chosen = rng.random(levels.shape[0]) < textured
    corner = chosen & (rng.random(levels.shape[0]) < 0.5)
    levels[corner, 0] *= rng.uniform(1.5, 3.0, int(corner.sum()))
    pattern = chosen & ~corner
    levels[pattern] *= np.array([1.3, 0.8, 0.8, 1.3])
    line = fit_detail_line(*_cells(levels, rng))
    assert line is not None
    assert line.gain == pytest.approx(2.0, rel=0.05)


def test_the_read_noise_is_found_where_it_shows() -> None:
    """Dark cells (levels 0–300, read variance 100 a sample): the read term within 15 %, the gain within 5 %."""
    rng = np.random.default_rng(8)
    line = fit_detail_line(*_cells(rng.uniform(0.0, 300.0, (30000, 1)) * np.ones((1, 4)), rng, read=100.0))
    assert line is not None
    assert line.gain == pytest.approx(2.0, rel=0.05) and line.read == pytest.approx(100.0, rel=0.15)


def test_too_few_cells_give_no_line() -> None:
    rng = np.random.default_rng(0)
    assert fit_detail_line(*_cells(rng.uniform(100, 200, (20, 4)), rng)) is None
    assert detail_noise_line(np.zeros((1, 1), dtype=np.uint16), 1, 0.0, 4095.0) is None


def test_a_frame_and_its_cfa_planes_give_the_same_cells_and_saturated_ones_are_left_out() -> None:
    rng = np.random.default_rng(3)
    frame = rng.integers(0, 4000, size=(70, 90)).astype(np.uint16)
    frame[10, 20] = 4095
    from_frame = haar_details(frame, 2, 64.0, 4095.0)
    from_planes = haar_details(cfa_planes(frame, 2), 1, 64.0, 4095.0)
    for ours, theirs in zip(from_frame, from_planes):
        np.testing.assert_array_equal(ours, theirs)
    assert from_frame[0].size == (70 // 4) * (90 // 4) * 4 - 1  # every cell but the saturated one
    plane = cfa_planes(frame, 2)[:, :, 0].astype(float)  # R at (0, 0): the first cell
    top = plane[0:2, 0:2]
    assert from_frame[0][0] == top.sum() - 4 * 64.0
    assert from_frame[1][0] == top[0, 0] - top[0, 1] - top[1, 0] + top[1, 1]


def test_large_frames_are_read_in_strided_rows_of_cells() -> None:
    frame = np.full((2048, 2560), 100, dtype=np.uint16)
    levels, *_ = haar_details(frame, 2, 0.0, 4095.0)
    assert FIT_CELLS // 2 < levels.size <= FIT_CELLS + 2560


def test_the_simulated_bayer_charts_noise_line_is_the_sensors() -> None:
    """On the sim rig's chart as a mosaic (8-pixel patches, 2-pixel borders: 4 × 4 samples a CFA plane), the
    line read from the ambient frame is the sensor's within 10 % (gain) — the block half differences it was
    fitted to before held the chart."""
    frame, _, _, _ = rendered_frames(ambient("tungsten"), scene=SIM_CHART, sensor=SENSOR, noise=True, peak_fraction=0.7)
    line = detail_noise_line(frame, 2, SENSOR.black_level, SENSOR.white_level)
    assert line is not None
    assert line.gain == pytest.approx(_true_pixel_noise(SENSOR).gain, rel=0.1)


def test_the_weights_of_a_bayer_chart_follow_the_sensors_noise() -> None:
    """The inverse-variance weights of the chart's 4 × 4-sample blocks are shaped as those of the sensor's true
    noise: within 5 % of one ratio for 90 % of the blocks (the darkest 5 % are floored by design). At the
    demo's exposure the highlight strip is just below white; fitted to the half differences (which then held
    the strip's edge and the chart's), the weights' ratio to these ran from 0.05 to 11 across the levels."""
    frame, leds, _, _ = rendered_frames(
        ambient("tungsten"), scene=SIM_CHART, sensor=SENSOR, noise=True, peak_fraction=0.07
    )
    rows = BlockRows(len(leds), cfa_planes(frame, 2).shape, 4, SENSOR.white_level, black_level=256.0, weighting=True)
    rows.add_frame(len(leds), frame, 2)
    weights = rows._weights
    assert weights is not None
    levels = rows.rows[len(leds)] - 16 * SENSOR.black_level
    true = _true_pixel_noise(SENSOR)
    expected = 1.0 / (true.gain * np.maximum(levels, 0.0) + 16 * true.read)
    ratio = weights / expected
    assert np.quantile(np.abs(ratio / np.median(ratio) - 1.0), 0.9) < 0.05


def test_the_checkerboard_probe_cancels_the_charts_edges() -> None:
    """Noise-free, the half differences of the chart's blocks (CFA planes of the mosaic) hold what the halves
    do not share: the checkerboard leaves 0.8 % of the block sums' energy (the corners); even-minus-odd
    columns, the probe before, left 9 % (every edge along the columns)."""
    frame, _, _, _ = rendered_frames(
        ambient("tungsten"), scene=SIM_CHART, sensor=SENSOR, noise=False, peak_fraction=0.7
    )
    sums, differences = block_sums_and_differences(cfa_planes(frame, 2), 4)
    signal = sums - 16 * SENSOR.black_level
    assert np.sum(differences**2) < 0.02 * np.sum(signal**2)


def _plain_fit(levels: np.ndarray, hh: np.ndarray, hl: np.ndarray, lh: np.ndarray) -> PixelNoise | None:
    """The fit written the plain way (a stable argsort, ``np.median`` per detail, the maximum of every round's
    variances, boolean masks): what :func:`fit_detail_line` computes with fewer passes."""
    from msflash.processing import noise_level as nl

    levels = np.maximum(levels, 0.0)
    squares, texture = hh * hh, hl * hl + lh * lh
    per_band = levels.size // nl.LEVEL_BANDS
    order = np.argsort(levels, kind="stable")[: per_band * nl.LEVEL_BANDS]
    centres = levels[order].reshape(nl.LEVEL_BANDS, per_band).mean(axis=1)
    medians = [np.median(np.square(d[order]).reshape(nl.LEVEL_BANDS, per_band), axis=1) for d in (hh, hl, lh)]
    variances = np.minimum.reduce(medians) / nl.CHI2_1_MEDIAN
    variances = np.maximum(variances, float(np.max(variances)) * 1e-12)
    gain, offset = nl._weighted_line(centres, variances, per_band / (variances * variances))
    for _ in range(nl.ROUNDS):
        variance = gain * levels + offset
        variance = np.maximum(variance, float(np.max(variance)) * 1e-12)
        keep = (texture <= nl.SMOOTH_QUANTILE * variance) & (squares <= nl.DETAIL_CUT * variance)
        if np.count_nonzero(keep) < nl.MIN_CELLS:
            break
        previous = (gain, offset)
        gain, offset = nl._weighted_line(levels[keep], squares[keep] / nl._CUT_MEAN, 1.0 / variance[keep] ** 2)
        steady = abs(gain - previous[0]) <= nl.CONVERGED * abs(gain)
        if steady and abs(offset - previous[1]) <= nl.CONVERGED * abs(offset):
            break
    if not gain * float(np.median(levels)) + offset > 0:
        return None
    return PixelNoise(gain=float(gain), read=float(offset) / 4.0)


@pytest.mark.parametrize("cells", [5120, 4095, 1000, 300])
@pytest.mark.parametrize(("whole", "top"), [(True, 400), (True, 40000), (False, 400)])
def test_the_fit_is_the_plain_fit_to_the_bit(cells: int, whole: bool, top: int) -> None:
    """Whole-number levels (integer samples) with many ties, below 65535 (sorted as 16-bit integers) and above
    (sorted by the keys ``level · n + index``), and fractional ones (the stable sort); bands of even and odd
    counts; a third of the cells textured."""
    rng = np.random.default_rng(cells)
    levels = np.repeat(rng.integers(top // 40, top, (cells, 1)), 4, axis=1).astype(float)
    levels[::3, 0] *= 3.0
    details = _cells(levels, rng)
    if whole:
        details = tuple(np.round(detail) for detail in details)
    assert fit_detail_line(*details) == _plain_fit(*details)


def _compiled_kernels() -> object:
    """The compiled kernels, loaded (or the test skipped without numba)."""
    from msflash.processing import frame_kernels

    pytest.importorskip("numba")
    if not frame_kernels.prepare():
        pytest.skip("the compiled kernels are off (MSFLASH_KERNELS=numpy)")
    return frame_kernels._compiled()


def _close(line: PixelNoise | None, reference: PixelNoise | None) -> bool:
    if line is None or reference is None:
        return line is reference
    return bool(np.allclose([line.gain, line.read], [reference.gain, reference.read], rtol=1e-12, atol=0.0))


@pytest.mark.parametrize("cells", [5120, 4095, 1000, 300, 130, 63])
@pytest.mark.parametrize(("whole", "top"), [(True, 400), (True, 40000), (False, 400)])
def test_the_compiled_fit_is_the_numpy_fit_to_rounding(cells: int, whole: bool, top: int) -> None:
    """The fit of the compiled route (:func:`processing.frame_kernels.detail_line`: its own stable sort, band medians
    by selection, sums in order) against numpy's, on the cases of the plain-fit test and too few cells (None on both):
    the same line to 1e-12 relative."""
    _compiled_kernels()
    rng = np.random.default_rng(cells + top)
    levels = np.repeat(rng.integers(top // 40, top, (cells, 1)), 4, axis=1).astype(float)
    levels[::3, 0] *= 3.0
    details = _cells(levels, rng)
    if whole:
        details = tuple(np.round(detail) for detail in details)
    reference = fit_detail_line(*details)
    assert (reference is None) == (cells < 64)
    assert _close(fit_detail_line(*details, compiled=True), reference)


def test_the_compiled_fit_finds_no_line_where_numpy_finds_none() -> None:
    """Identical samples (no noise to see), negative levels (clipped to 0) with no detail, and non-finite details."""
    _compiled_kernels()
    flat = np.full(4000, 400.0), np.zeros(4000), np.zeros(4000), np.zeros(4000)
    negative = -np.arange(4000.0), np.zeros(4000), np.ones(4000), np.zeros(4000)
    broken = np.arange(4000.0), np.full(4000, np.inf), np.zeros(4000), np.zeros(4000)
    for details in (flat, negative, broken):
        assert fit_detail_line(*details) is None
        assert fit_detail_line(*details, compiled=True) is None


@pytest.mark.parametrize("kind", ["whole", "large whole", "fractional", "zeros and ties"])
def test_the_compiled_stable_order_is_numpys_stable_argsort(kind: str) -> None:
    """The radix sort behind the compiled fit gives the order of numpy's stable argsort, ties in index order."""
    kernels: Any = _compiled_kernels()
    rng = np.random.default_rng(3)
    levels = {
        "whole": rng.integers(0, 400, 5000).astype(float),
        "large whole": rng.integers(0, 1 << 40, 5000).astype(float),
        "fractional": rng.uniform(0.0, 1e6, 5000),
        "zeros and ties": np.repeat([0.0, 2.5, 1e-300, 7.0], 1000),
    }[kind]
    assert np.array_equal(kernels._stable_order(levels), np.argsort(levels, kind="stable"))


def test_block_rows_of_the_compiled_route_fit_the_compiled_line() -> None:
    """Block rows that take the compiled moments fit the ambient's line on that route too (decided once per stack):
    to rounding the numpy route's."""
    from msflash.processing.block_sums import plane_shape

    _compiled_kernels()
    frame, _, _, _ = rendered_frames(
        ambient("tungsten"), scene=SIM_CHART, sensor=SENSOR, noise=True, seed=3, peak_fraction=0.5
    )
    lines = []
    for compiled in (True, False):
        rows = BlockRows(
            1, plane_shape(frame.shape, 2), 4, SENSOR.white_level, SENSOR.black_level, weighting=True, compiled=compiled
        )
        rows.add_frame(1, frame, 2)
        lines.append(rows.ambient_noise)
    assert lines[0] is not None and _close(lines[0], lines[1])
    assert lines[0] == detail_noise_line(frame, 2, SENSOR.black_level, SENSOR.white_level, compiled=True)


@pytest.mark.parametrize(
    ("shape", "period", "dtype", "white"),
    [
        ((1027, 1283), 2, np.uint16, 65535.0),  # a mosaic at the full 16-bit range, sizes not multiples of a cell
        ((1027, 1283), 2, np.uint16, 4095.0),  # 12-bit: cells with a saturated sample left out
        ((301, 203, 3), 1, np.uint16, 60000.0),
        ((64, 96, 3), 1, np.uint8, 250.0),
        ((6, 5), 2, np.uint16, 65535.0),  # one row of cells
    ],
)
def test_the_compiled_haar_details_are_numpys_to_the_bit(
    shape: tuple[int, ...], period: int, dtype: type, white: float
) -> None:
    """The compiled cells (:func:`processing.frame_kernels.haar_cells`) against numpy's: the same arrays, value for
    value (exact sums of integer samples), the same cells left out, at several strides."""
    _compiled_kernels()
    top = min(np.iinfo(dtype).max, int(white * 1.02))  # about 8 % of the cells reach white below the type's top
    frame = np.random.default_rng(len(shape)).integers(0, top, shape, endpoint=True).astype(dtype)
    for max_cells in (4096, 100, 10**9):
        reference = haar_details(frame, period, 64.0, white, max_cells)
        cells = haar_details(frame, period, 64.0, white, max_cells, compiled=True)
        assert all(a.dtype == b.dtype and np.array_equal(a, b) for a, b in zip(cells, reference, strict=True))
        assert reference[0].size > 0 and (white >= top or np.max(reference[0]) < 4 * white)


@pytest.mark.parametrize("size", [1, 2, 3, 8, 255, 320])
def test_the_compiled_band_median_is_numpys_median(size: int) -> None:
    """The selection behind the compiled fit's band medians (many ties, as squares of integer details; distinct
    values; one value repeated) gives ``np.median`` exactly and leaves the values as they were."""
    kernels: Any = _compiled_kernels()
    rng = np.random.default_rng(size)
    for values in (rng.integers(0, 6, size) ** 2.0, rng.permutation(size) * 1.5, np.full(size, 4.0)):
        kept = values.copy()
        median = kernels._band_median(values, np.empty(size), np.empty(size))
        assert median == np.median(values) and np.array_equal(values, kept)


def test_a_frame_of_padded_rows_takes_numpys_cells() -> None:
    """A frame whose rows are padded (a view into wider rows) is not one of the kernels' warmed specialisations: the
    compiled route hands it to numpy's cells (the same arrays), and the fit on it is the contiguous frame's."""
    _compiled_kernels()
    wide = np.random.default_rng(5).integers(0, 4000, (260, 330)).astype(np.uint16)
    padded = wide[:, :320]
    assert not padded.flags.c_contiguous
    cells = haar_details(padded, 2, 64.0, 4095.0, compiled=True)
    reference = haar_details(np.ascontiguousarray(padded), 2, 64.0, 4095.0)
    assert all(np.array_equal(a, b) for a, b in zip(cells, reference, strict=True))
    assert detail_noise_line(padded, 2, 64.0, 4095.0, compiled=True) == detail_noise_line(
        np.ascontiguousarray(padded), 2, 64.0, 4095.0, compiled=True
    )


@pytest.mark.parametrize("case", ["mosaic", "rgb", "saturated", "all saturated", "no line", "below black", "no floor"])
def test_the_compiled_block_weights_are_numpys_to_the_bit(case: str) -> None:
    """The ambient's inverse-variance weights on the compiled route (the floor's levels gathered by a kernel, the
    weights' steps in one pass) are numpy's to the bit: a quantile is one value, and the steps are the same IEEE
    operations in the same order; the fallbacks (no line, every block saturated, no positive floor) alike."""
    from msflash.processing.noise_level import ambient_block_weights

    _compiled_kernels()
    rng = np.random.default_rng(5)
    layout = (13, 3, 17) if case == "rgb" else (12, 4, 20)
    black = 64.0 * 240.0
    ambient = rng.integers(0, 64 * 4095, math.prod(layout)).astype(float)
    if case == "below black":
        ambient[::3] = rng.integers(0, int(black), ambient[::3].size)
    saturated = None
    if case in ("saturated", "all saturated"):
        saturated = rng.random((layout[0], layout[2])) < 0.3
        if case == "all saturated":
            saturated[:] = True
    pixel = None if case == "no line" else PixelNoise(gain=0.7, read=-5.0 if case == "no floor" else 1.3)
    expected = ambient_block_weights(pixel, 8, ambient, layout, black, saturated)
    found = ambient_block_weights(pixel, 8, ambient, layout, black, saturated, compiled=True)
    assert found.dtype == expected.dtype and found.shape == expected.shape
    np.testing.assert_array_equal(found, expected)
    if case in ("no line", "all saturated", "no floor"):
        np.testing.assert_array_equal(found, np.ones(ambient.size))  # uniform weights
