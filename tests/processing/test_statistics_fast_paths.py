"""Fast paths (no-saturation skip, block sums, flat synthesis chunks) against the plain computations."""

from __future__ import annotations

import numpy as np
import pytest

from msflash.processing.accumulate import accumulate_statistics
from msflash.processing.block_sums import bin_frame, saturated_blocks
from msflash.processing.statistics import FrameStackSpec
from msflash.processing.synthesis import synthesize
from tests.processing.test_statistics import MULTIPLEXED, assert_matches, naive_statistics, random_stack


def naive_binned(ambient, leds, spec, factor, cfa_period=1, mask=None):
    """Block sums and block maxima from :func:`bin_frame`, then the naive statistics."""
    binned = [bin_frame(f, factor, cfa_period) for f in [ambient, *leds]]
    saturated = np.maximum.reduce([top for _, top in binned]) >= spec.white_level
    valid = ~saturated.any(axis=2) if saturated.ndim == 3 else ~saturated
    if mask is not None:
        sums, _ = bin_frame(mask.astype(np.uint8), factor, cfa_period)
        full = sums == factor * factor
        valid &= full.all(axis=2) if full.ndim == 3 else full
    block = FrameStackSpec(
        spec.black_level * factor * factor, np.inf, spec.ambient_scale, spec.led_scales, spec.led_levels
    )
    sums = [s.astype(float) for s, _ in binned]
    return naive_statistics(sums[0], sums[1:], block, valid)


@pytest.mark.parametrize("saturate", [0.0, 0.02], ids=["none", "some"])
@pytest.mark.parametrize(
    ("shape", "cfa"), [((37, 45, 3), 1), ((37, 45), 1), ((38, 46), 2)], ids=["rgb", "mono", "bayer"]
)
@pytest.mark.parametrize("factor", [1, 2, 4])
def test_binned_equals_naive(saturate: float, shape: tuple[int, ...], cfa: int, factor: int) -> None:
    if factor == 1 and cfa == 2:
        pytest.skip("bin_factor 1 uses every mosaic sample (no CFA planes)")
    rng = np.random.default_rng(factor + len(shape) + cfa)
    ambient, leds, spec = random_stack(rng, shape, MULTIPLEXED, white=4095.0, saturate=saturate)
    stats = accumulate_statistics(ambient, leds, spec, bin_factor=factor, cfa_period=cfa, chunk_pixels=97)
    assert_matches(stats, naive_binned(ambient, leds, spec, factor, cfa))


def test_saturation_in_one_chunk_only() -> None:
    rng = np.random.default_rng(11)
    ambient, leds, spec = random_stack(rng, (64, 40, 3), np.eye(3), white=4095.0)
    leds[2][50, 7, 1] = 4095  # one sample of one frame, far from the first chunks
    for factor in (1, 4):
        stats = accumulate_statistics(ambient, leds, spec, bin_factor=factor, chunk_pixels=64)
        expected = naive_binned(ambient, leds, spec, factor) if factor > 1 else naive_statistics(ambient, leds, spec)
        assert stats.n_samples == stats.n_total - 3  # one pixel (or block) of three channels
        assert_matches(stats, expected)


def test_uint16_at_type_maximum_is_saturated() -> None:
    rng = np.random.default_rng(12)
    ambient, leds, spec = random_stack(rng, (16, 16, 3), np.eye(2), white=65535.0)
    leds[0][3, 3, 0] = 65535
    assert_matches(accumulate_statistics(ambient, leds, spec, bin_factor=4), naive_binned(ambient, leds, spec, 4))
    image, saturated = synthesize(ambient, leds, spec, np.ones(2), chunk_pixels=10)
    assert saturated.sum() == 1 and saturated[3, 3]


@pytest.mark.parametrize("factor", [1, 4])
def test_float_frames_match_integer_frames(factor: int) -> None:
    rng = np.random.default_rng(13)
    ambient, leds, spec = random_stack(rng, (32, 24, 3), MULTIPLEXED, white=4095.0, saturate=0.01)
    as_int = accumulate_statistics(ambient, leds, spec, bin_factor=factor)
    as_float = accumulate_statistics(ambient.astype(float), [f.astype(float) for f in leds], spec, bin_factor=factor)
    assert_matches(
        as_float, naive_binned(ambient, leds, spec, factor) if factor > 1 else naive_statistics(ambient, leds, spec)
    )
    assert as_float.n_samples == as_int.n_samples


def test_binned_mask_equals_naive() -> None:
    rng = np.random.default_rng(14)
    ambient, leds, spec = random_stack(rng, (40, 36, 3), MULTIPLEXED, white=4095.0, saturate=0.005)
    mask = np.ones((40, 36), dtype=bool)
    mask[5:9, 10:30] = False
    stats = accumulate_statistics(ambient, leds, spec, bin_factor=4, sample_mask=mask)
    assert_matches(stats, naive_binned(ambient, leds, spec, 4, mask=mask))


@pytest.mark.parametrize("chunk", [1, 13, 1 << 15])
def test_synthesis_saturation_in_one_chunk_and_float_frames(chunk: int) -> None:
    rng = np.random.default_rng(15)
    ambient, leds, spec = random_stack(rng, (30, 20, 3), MULTIPLEXED, white=4095.0)
    leds[1][25, 4, 2] = 4095
    weights = np.array([0.4, 1.2, -0.3])
    image, saturated = synthesize(ambient, leds, spec, weights, chunk_pixels=chunk)
    expected = np.zeros((30, 20), dtype=bool)
    expected[25, 4] = True
    np.testing.assert_array_equal(saturated, expected)
    float_image, float_saturated = synthesize(
        ambient.astype(float), [f.astype(float) for f in leds], spec, weights, chunk_pixels=chunk
    )
    np.testing.assert_array_equal(float_saturated, expected)
    np.testing.assert_allclose(float_image, image, rtol=0, atol=1e-5 * np.abs(image).max())


@pytest.mark.parametrize(
    "saturate", [0.0, 0.0003, 0.002, 0.02], ids=["none", "few-blocks", "many-blocks", "most-blocks"]
)
def test_block_rows_frame_by_frame_equals_the_binned_pass(saturate: float) -> None:
    """BlockRows filled one frame at a time, in any order (a capture) gives the binned pass's statistics, few or
    most blocks saturated."""
    from msflash.processing.block_rows import BlockRows
    from msflash.processing.block_sums import cfa_planes

    rng = np.random.default_rng(11)
    ambient, leds, spec = random_stack(rng, (41, 53, 3), np.eye(4), white=4095.0, saturate=saturate)
    reference = accumulate_statistics(ambient, leds, spec, bin_factor=4, workers=1)
    rows = BlockRows(len(leds), ambient.shape, 4, spec.white_level)
    for row in [2, 0, 4, 1, 3]:  # any arrival order; row 4 is the ambient frame
        rows.add(row, cfa_planes(ambient if row == 4 else leds[row], 1))
    stats = rows.statistics(spec)
    assert 0 < stats.n_samples <= stats.n_total
    assert (stats.n_samples < stats.n_total) == (saturate > 0)
    if saturate == 0.02:
        assert stats.n_samples < 0.75 * stats.n_total  # most blocks out
    assert_matches(
        stats,
        {
            "gram": reference.gram,
            "cross": reference.cross,
            "ambient_energy": reference.ambient_energy,
            "n_samples": reference.n_samples,
            "n_total": reference.n_total,
            "ambient_sum": reference.ambient_sum,
            "led_sums": reference.led_sums,
        },
    )


def test_block_rows_refuses_a_missing_frame() -> None:
    from msflash.processing.block_rows import BlockRows
    from msflash.processing.block_sums import cfa_planes
    from msflash.processing.errors import SpectralDataError

    rng = np.random.default_rng(12)
    ambient, leds, spec = random_stack(rng, (16, 16, 3), np.eye(2), white=4095.0, saturate=0.0)
    rows = BlockRows(2, ambient.shape, 4, spec.white_level)
    rows.add(2, cfa_planes(ambient, 1))
    rows.add(0, cfa_planes(leds[0], 1))
    with pytest.raises(SpectralDataError, match="2 of 3 frames"):
        rows.statistics(spec)
    with pytest.raises(SpectralDataError, match="expected"):
        rows.add(1, cfa_planes(leds[1][:8], 1))
    with pytest.raises(SpectralDataError, match="row 0 is taken"):
        rows.add(0, cfa_planes(leds[1], 1))


@pytest.mark.parametrize("saturate", [0.0, 0.02], ids=["none", "some"])
def test_threads_do_not_change_the_results(saturate: float) -> None:
    """Two worker threads give bit-identical statistics and synthesis (same sums, same order)."""
    rng = np.random.default_rng(13)
    ambient, leds, spec = random_stack(rng, (67, 71, 3), MULTIPLEXED, white=4095.0, saturate=saturate)
    one = accumulate_statistics(ambient, leds, spec, bin_factor=2, workers=1, chunk_pixels=101)
    two = accumulate_statistics(ambient, leds, spec, bin_factor=2, workers=2, chunk_pixels=101)
    for name in ("gram", "cross", "led_sums"):
        np.testing.assert_array_equal(getattr(one, name), getattr(two, name))
    assert (one.ambient_energy, one.n_samples) == (two.ambient_energy, two.n_samples)
    weights = np.linspace(0.1, 0.9, spec.n_leds)
    image_one, saturated_one = synthesize(ambient, leds, spec, weights, chunk_pixels=97, workers=1)
    image_two, saturated_two = synthesize(ambient, leds, spec, weights, chunk_pixels=97, workers=2)
    np.testing.assert_array_equal(image_one, image_two)
    np.testing.assert_array_equal(saturated_one, saturated_two)
    assert saturated_one.any() == (saturate > 0)


def test_diagonal_levels_unmix_as_the_pseudo_inverse() -> None:
    """One LED per frame: the reciprocal fast path is exactly numpy's pinv."""
    rng = np.random.default_rng(14)
    for _ in range(200):
        k = int(rng.integers(1, 9))
        levels = np.diag(rng.uniform(-3, 3, k) * 10.0 ** rng.uniform(-4, 4, k))
        spec = FrameStackSpec(0.0, 1.0, 1.0, (1.0,) * k, levels)
        np.testing.assert_array_equal(spec.unmixing, np.linalg.pinv(levels))


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32, np.float64])
def test_saturated_blocks_equal_the_any_of_each_block(dtype: type) -> None:
    """Block maxima ≥ white ⇔ some sample of the block ≥ white, for any factor, channels and crop."""
    rng = np.random.default_rng(7)
    for _ in range(60):
        factor = int(rng.choice([1, 2, 3, 4, 8]))
        channels = int(rng.choice([1, 3]))
        height, width = (int(v) for v in rng.integers(factor, 50, size=2))
        plane = (rng.random((height, width, channels)) * 250).astype(dtype)
        if np.issubdtype(dtype, np.floating):
            plane[0, 0, 0] = np.nan  # NaN never counts as saturated, as with >=
        white = float(rng.choice([120, 240, 249]))
        rows, columns = height // factor, width // factor
        hit = (plane >= white).any(axis=2)[: rows * factor, : columns * factor]
        expected = hit.reshape(rows, factor, columns, factor).any(axis=(1, 3))
        np.testing.assert_array_equal(saturated_blocks(plane, factor, white), expected)


def test_block_rows_exclude_between_frames_equals_a_masked_pass() -> None:
    """Blocks excluded by the caller part-way through a frame-by-frame fill leave every product."""
    from msflash.processing.block_rows import BlockRows
    from msflash.processing.block_sums import cfa_planes

    rng = np.random.default_rng(5)
    ambient, leds, spec = random_stack(rng, (40, 48, 3), np.eye(3), white=4095.0, saturate=0.0005)
    blocks = rng.random((10, 12)) < 0.1
    rows = BlockRows(len(leds), ambient.shape, 4, spec.white_level)
    batch = BlockRows(len(leds), ambient.shape, 4, spec.white_level)
    for row in [3, 0, 1, 2]:
        frame = cfa_planes(ambient if row == 3 else leds[row], 1)
        rows.add(row, frame)
        batch.add(row, frame)
        if row == 0:
            rows.exclude(blocks)
    batch.exclude(blocks)
    ours, reference = rows.statistics(spec), batch.statistics(spec)
    assert ours.n_samples == reference.n_samples < ours.n_total - np.count_nonzero(blocks) * 3 + 1
    np.testing.assert_allclose(ours.gram, reference.gram, rtol=1e-10)
    np.testing.assert_allclose(ours.cross, reference.cross, rtol=1e-10)
    assert ours.ambient_energy == pytest.approx(reference.ambient_energy, rel=1e-10)
