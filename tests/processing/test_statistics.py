"""One-pass sufficient statistics against a naive full-array computation."""

from __future__ import annotations

import numpy as np
import pytest

from msflash.processing.accumulate import accumulate_statistics
from msflash.processing.errors import SpectralDataError
from msflash.processing.statistics import FrameStackSpec, SequenceStatistics
from tests.helpers import EXACT


def naive_statistics(
    ambient: np.ndarray, led_frames: list[np.ndarray], spec: FrameStackSpec, mask: np.ndarray | None = None
) -> dict:
    """Linearise, difference, unmix and sum over the valid samples with full arrays."""
    frames = [ambient, *led_frames]
    stack = np.stack([f.astype(float) for f in frames])
    valid_pixel = ~np.any(stack >= spec.white_level, axis=0)
    if valid_pixel.ndim == 3:
        valid_pixel = valid_pixel.all(axis=2)
    if mask is not None:
        valid_pixel &= mask
    a = (stack[0] - spec.black_level) * spec.ambient_scale
    diffs = np.stack([(stack[j + 1] - spec.black_level) * s - a for j, s in enumerate(spec.led_scales)])
    only = np.tensordot(np.linalg.pinv(spec.led_levels), diffs, axes=1)  # (k, H, W[, C])
    a_valid = a[valid_pixel].reshape(-1)
    f_valid = np.stack([o[valid_pixel].reshape(-1) for o in only])
    return {
        "gram": f_valid @ f_valid.T,
        "cross": f_valid @ a_valid,
        "ambient_energy": a_valid @ a_valid,
        "n_samples": a_valid.size,
        "n_total": a.size,
        "ambient_sum": a_valid.sum(),
        "led_sums": f_valid.sum(axis=1),
    }


def random_stack(
    rng: np.random.Generator, shape: tuple[int, ...], levels: np.ndarray, white: float, saturate: float = 0.0
) -> tuple[np.ndarray, list[np.ndarray], FrameStackSpec]:
    """Integer frames with random exposures/gains and some saturated samples."""
    n_frames = levels.shape[0]
    ambient = rng.integers(100, 3000, size=shape).astype(np.uint16)
    leds = [ambient + rng.integers(0, 1000, size=shape).astype(np.uint16) for _ in range(n_frames)]
    if saturate:
        for frame in leds:
            frame[rng.random(shape) < saturate] = white
    spec = FrameStackSpec(
        black_level=64.0,
        white_level=white,
        ambient_scale=1 / (rng.uniform(1e3, 1e4) * 1.5),
        led_scales=tuple(1 / (rng.uniform(1e3, 1e4) * rng.uniform(1, 4)) for _ in range(n_frames)),
        led_levels=levels,
    )
    return ambient, leds, spec


def assert_matches(stats: SequenceStatistics, naive: dict) -> None:
    scale = max(abs(naive["ambient_energy"]), 1e-300)
    np.testing.assert_allclose(stats.gram, naive["gram"], rtol=EXACT, atol=EXACT * scale)
    np.testing.assert_allclose(stats.cross, naive["cross"], rtol=EXACT, atol=EXACT * scale)
    assert stats.ambient_energy == pytest.approx(naive["ambient_energy"], rel=EXACT)
    assert stats.n_samples == naive["n_samples"]
    assert stats.n_total == naive["n_total"]
    assert stats.ambient_sum == pytest.approx(naive["ambient_sum"], rel=EXACT)
    np.testing.assert_allclose(stats.led_sums, naive["led_sums"], rtol=EXACT, atol=EXACT * abs(naive["ambient_sum"]))


MULTIPLEXED = np.array([[1.0, 0.5, 0.0], [0.0, 1.0, 0.25], [0.5, 0.0, 1.0], [1.0, 1.0, 1.0]])
"""Four frames lighting several of three LEDs each (over-determined: pinv, not inverse)."""


@pytest.mark.parametrize("chunk", [1, 7, 100, 1 << 15])
@pytest.mark.parametrize("shape", [(13, 11, 3), (13, 11)], ids=["rgb", "mosaic"])
@pytest.mark.parametrize("levels", [np.eye(3), MULTIPLEXED], ids=["one-hot", "multiplexed"])
def test_chunked_equals_naive(chunk: int, shape: tuple[int, ...], levels: np.ndarray) -> None:
    rng = np.random.default_rng(chunk + len(shape) + levels.shape[0])
    ambient, leds, spec = random_stack(rng, shape, levels, white=4095.0, saturate=0.03)
    stats = accumulate_statistics(ambient, leds, spec, chunk_pixels=chunk)
    naive = naive_statistics(ambient, leds, spec)
    assert 0 < naive["n_samples"] < naive["n_total"]  # the saturation path is exercised
    assert_matches(stats, naive)


@pytest.mark.parametrize("chunk", [5, 1 << 15])
def test_mask_equals_naive(chunk: int) -> None:
    rng = np.random.default_rng(3)
    ambient, leds, spec = random_stack(rng, (9, 17, 3), MULTIPLEXED, white=4095.0, saturate=0.02)
    mask = rng.random((9, 17)) < 0.6
    stats = accumulate_statistics(ambient, leds, spec, sample_mask=mask, chunk_pixels=chunk)
    assert_matches(stats, naive_statistics(ambient, leds, spec, mask))


def test_saturated_fraction_counts_samples_of_saturated_pixels() -> None:
    rng = np.random.default_rng(4)
    ambient, leds, spec = random_stack(rng, (10, 10, 3), np.eye(2), white=4095.0)
    leds[1][2:4, :, 1] = 4095  # 20 pixels saturated in one channel of one frame → all 3 samples excluded
    stats = accumulate_statistics(ambient, leds, spec)
    assert stats.n_total == 300
    assert stats.n_samples == 300 - 60
    assert stats.saturated_fraction == pytest.approx(0.2)


def test_add_disjoint_halves_equals_whole() -> None:
    rng = np.random.default_rng(5)
    ambient, leds, spec = random_stack(rng, (12, 10, 3), MULTIPLEXED, white=4095.0, saturate=0.02)
    whole = accumulate_statistics(ambient, leds, spec)
    top = accumulate_statistics(ambient[:5], [f[:5] for f in leds], spec)
    bottom = accumulate_statistics(ambient[5:], [f[5:] for f in leds], spec)
    total = top + bottom
    assert_matches(
        total,
        {
            "gram": whole.gram,
            "cross": whole.cross,
            "ambient_energy": whole.ambient_energy,
            "n_samples": whole.n_samples,
            "n_total": whole.n_total,
            "ambient_sum": whole.ambient_sum,
            "led_sums": whole.led_sums,
        },
    )


def test_residual_energy_matches_pixels() -> None:
    rng = np.random.default_rng(6)
    ambient, leds, spec = random_stack(rng, (8, 8, 3), np.eye(3), white=1e9)
    stats = accumulate_statistics(ambient, leds, spec)
    a = (ambient - spec.black_level) * spec.ambient_scale
    only = [(f - spec.black_level) * s - a for f, s in zip(leds, spec.led_scales)]
    w = np.array([0.3, -0.2, 0.7])
    direct = float(np.sum((a - sum(wi * o for wi, o in zip(w, only))) ** 2))
    assert stats.residual_energy(w) == pytest.approx(direct, rel=1e-8)


def test_rejects_bad_input() -> None:
    rng = np.random.default_rng(8)
    ambient, leds, spec = random_stack(rng, (4, 4, 3), np.eye(2), white=1e9)
    with pytest.raises(SpectralDataError, match="frame 2 has shape"):
        accumulate_statistics(ambient, [leds[0], leds[1][:3]], spec)
    with pytest.raises(SpectralDataError, match="non-finite"):
        bad = leds[0].astype(float)
        bad[0, 0, 0] = np.nan
        accumulate_statistics(ambient.astype(float), [bad, leds[1].astype(float)], spec)
    with pytest.raises(SpectralDataError, match="LED frames but levels"):
        accumulate_statistics(ambient, leds[:1], spec)
    with pytest.raises(SpectralDataError, match="do not separate every LED"):
        FrameStackSpec(0, 10, 1.0, (1.0, 1.0), np.array([[1.0, 1.0], [0.5, 0.5]]))
    with pytest.raises(SpectralDataError, match="white_level"):
        FrameStackSpec(10, 10, 1.0, (1.0,), np.eye(1))


@pytest.mark.parametrize("bin_factor", [1, 2])
@pytest.mark.parametrize(("frame", "name"), [(0, "the ambient frame"), (2, "LED frame 2")])
def test_non_finite_frame_is_named(bin_factor: int, frame: int, name: str) -> None:
    """'a frame holds non-finite values' did not say which: the ambient, or which LED frame."""
    from msflash.processing.tile_statistics import tile_statistics

    rng = np.random.default_rng(9)
    ambient, leds, spec = random_stack(rng, (8, 8, 3), np.eye(3), white=1e9)
    frames = [ambient.astype(float), *(led.astype(float) for led in leds)]
    frames[frame][3, 4, 1] = np.inf if frame else np.nan
    message = f"frame stack: {name} holds non-finite values"
    with pytest.raises(SpectralDataError, match=message):
        accumulate_statistics(frames[0], frames[1:], spec, bin_factor=bin_factor)
    with pytest.raises(SpectralDataError, match=message):
        tile_statistics(frames[0], frames[1:], spec, 2, bin_factor=bin_factor)


@pytest.mark.parametrize("frame_by_frame", [False, True])
def test_large_frames_probe_a_stride_of_block_rows_and_scale_it(
    monkeypatch: pytest.MonkeyPatch, frame_by_frame: bool
) -> None:
    """Above 4 × PROBE_BLOCKS blocks the noise probe reads every 4th block row, scaled by the valid blocks:
    its noise moments stay within a few per cent of the full probe's (sampling error ~1 %), saturated
    blocks included, and so do the denoised weights."""
    from msflash.processing import block_rows as module

    rng = np.random.default_rng(7)
    shape, k = (1024, 1024, 3), 3
    # Surfaces as 8-px tiles (their colour differs per LED), so blocks differ and the LEDs are distinct.
    leds = [np.kron(rng.uniform(100, 2000, (128, 128, 3)), np.ones((8, 8, 1))) for _ in range(k)]
    truth = np.array([0.5, 0.3, 0.8])
    ambient_light = sum(w * f for w, f in zip(truth, leds, strict=True))

    def noisy(light: np.ndarray) -> np.ndarray:
        return np.clip(rng.normal(light, np.sqrt(light) * 4), 0, 65535).astype(np.uint16)

    ambient = noisy(ambient_light)
    ambient[:64, :64] = 65535  # a saturated corner: blocks left out of both the moments and the probe
    frames = [noisy(ambient_light + f) for f in leds]
    spec = FrameStackSpec(0.0, 65535.0, 1.0, (1.0,) * k, np.eye(k))

    def statistics() -> SequenceStatistics:
        if not frame_by_frame:
            return accumulate_statistics(ambient, frames, spec, bin_factor=4)
        rows = module.BlockRows(k, shape, 4, 65535.0)
        for row, frame in [(k, ambient), *enumerate(frames)]:
            rows.add(row, frame)
        return rows.statistics(spec)

    strided = statistics()
    monkeypatch.setattr(module, "PROBE_BLOCKS", 10**9)  # every block row
    full = statistics()
    assert strided.noise is not None and full.noise is not None
    assert strided.n_samples == full.n_samples < strided.n_total
    np.testing.assert_array_equal(strided.gram, full.gram)
    np.testing.assert_allclose(np.diag(strided.noise.gram), np.diag(full.noise.gram), rtol=0.03)
    np.testing.assert_allclose(strided.noise.ambient_energy, full.noise.ambient_energy, rtol=0.03)
    solve = lambda stats: np.linalg.solve(stats.denoised().gram, stats.denoised().cross)  # noqa: E731
    np.testing.assert_allclose(solve(strided), solve(full), atol=0.01)
    np.testing.assert_allclose(solve(full), truth, atol=0.02)


@pytest.mark.parametrize("seed", range(6))
def test_the_one_led_per_frame_transform_is_the_array_routes_to_the_bit(seed: int) -> None:
    """channel_transform's Python-float route for a diagonal unmixing (one LED per frame) gives the array route's
    transform to the bit (signs of zeros included); a mixed plan takes the array route."""
    from msflash.processing import statistics

    rng = np.random.default_rng(seed)
    k = int(rng.integers(1, 9))
    levels = np.diag(rng.uniform(0.05, 1.0, k))
    spec = FrameStackSpec(
        float(rng.uniform(0, 300)), 4095.0, float(rng.uniform(1e-4, 1.0)), tuple(rng.uniform(1e-4, 1.0, k)), levels
    )
    black = float(rng.uniform(0, 2e4))
    assert spec.unmixing_diagonal is not None
    fast = statistics.channel_transform(spec, black)
    reference = FrameStackSpec(spec.black_level, spec.white_level, spec.ambient_scale, spec.led_scales, levels)
    object.__setattr__(reference, "unmixing_diagonal", None)  # the array route
    slow = statistics.channel_transform(reference, black)
    np.testing.assert_array_equal(fast, slow)
    np.testing.assert_array_equal(np.signbit(fast), np.signbit(slow))
    mixed = FrameStackSpec(0.0, 4095.0, 1.0, (1.0, 0.5), np.array([[1.0, 0.5], [0.0, 1.0]]))
    assert mixed.unmixing_diagonal is None
    assert statistics.channel_transform(mixed, 0.0).shape == (3, 4)
