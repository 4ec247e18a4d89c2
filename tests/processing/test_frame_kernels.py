"""The one-pass statistics and synthesis against a straightforward reference written here.

The reference takes the slow, obvious way: every frame linearised to float64, block sums by a
reshape, half differences by a checkerboard of ± signs over each block's members, saturated blocks dropped, products by
``@``. The fast routes — the compiled kernels (:mod:`processing.frame_kernels`) and the numpy route
they replace — must give the same statistics to floating-point tolerance, on frames whose sizes
are not multiples of the block, tile or task sizes, Bayer mosaics, saturated pixels, and 1 or 2
workers.
"""

from __future__ import annotations

import numpy as np
import pytest

from msflash.processing import block_rows, block_sums, frame_kernels, statistics, synthesis
from msflash.processing.accumulate import accumulate_statistics
from msflash.processing.block_rows import BlockRows
from msflash.processing.errors import SpectralDataError
from msflash.processing.statistics import ChannelMoments, FrameStackSpec, SequenceStatistics
from msflash.processing.synthesis import synthesize

WHITE = 4000.0
BLACK = 64.0


@pytest.fixture(params=["compiled", "numpy"])
def route(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    """Run a test on the compiled kernels and on the numpy route."""
    monkeypatch.setenv(frame_kernels.KERNELS_VARIABLE, "numpy" if request.param == "numpy" else "numba")
    frame_kernels._compiled.cache_clear()
    if request.param == "compiled" and not frame_kernels.enabled():
        pytest.skip("numba is not installed")
    yield request.param
    frame_kernels._compiled.cache_clear()


def _frames(
    shape: tuple[int, ...], n_leds: int, seed: int, dtype: type = np.uint16, saturate: bool = True
) -> tuple[np.ndarray, list[np.ndarray], FrameStackSpec]:
    rng = np.random.default_rng(seed)
    top = min(int(WHITE) - 1, np.iinfo(dtype).max - 1)
    scene = rng.uniform(BLACK, top / 3, shape)
    ambient = rng.poisson(scene).astype(dtype)
    frames = []
    for _ in range(n_leds):
        lit = np.clip(rng.poisson(scene * rng.uniform(1.1, 1.8)), 0, top)
        frames.append(lit.astype(dtype))
    if saturate:
        frames[min(1, n_leds - 1)][3:5, 7:9] = np.iinfo(dtype).max if WHITE > np.iinfo(dtype).max else int(WHITE)
        ambient[-2, -3] = min(int(WHITE) + 5, np.iinfo(dtype).max)
    white = min(WHITE, float(np.iinfo(dtype).max))
    scales = tuple(float(s) for s in rng.uniform(0.5, 2.0, n_leds))
    spec = FrameStackSpec(BLACK, white, 0.8, scales, np.diag(rng.uniform(0.5, 1.0, n_leds)))
    return ambient, frames, spec


def _block_rows(
    n_leds: int, shape: tuple[int, ...], period: int, factor: int, spec: FrameStackSpec, **options: bool
) -> BlockRows:
    """Block rows for frames of ``shape`` with ``spec``'s white and black levels."""
    return BlockRows(
        n_leds, block_sums.plane_shape(shape, period), factor, spec.white_level, black_level=spec.black_level, **options
    )


def _planes(frame: np.ndarray, period: int) -> np.ndarray:
    """(H, W, C) float64 planes, the obvious way."""
    if period == 2:
        rows, columns = frame.shape[0] // 2, frame.shape[1] // 2
        return np.stack([frame[p : 2 * rows : 2, q : 2 * columns : 2] for p in (0, 1) for q in (0, 1)], axis=-1).astype(
            float
        )
    return (frame if frame.ndim == 3 else frame[:, :, None]).astype(float)


def _blocks(plane: np.ndarray, factor: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Block sums, half differences (members at even row + column minus those at odd) and block maxima, each (h, w, C)."""
    h, w, c = plane.shape[0] // factor, plane.shape[1] // factor, plane.shape[2]
    members = plane[: h * factor, : w * factor].reshape(h, factor, w, factor, c)
    parity = np.add.outer(np.arange(factor), np.arange(factor)) % 2
    sign = np.where(parity == 0, 1.0, -1.0)[None, :, None, :, None]
    return members.sum(axis=(1, 3)), (members * sign).sum(axis=(1, 3)), members.max(axis=(1, 3))


def _reference_blocks(
    ambient: np.ndarray, led_frames: list[np.ndarray], spec: FrameStackSpec, factor: int, period: int
) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
    """Each frame's block sums and half differences (LED frames first, the ambient last) and the blocks no frame
    saturates."""
    sums, halves, valid = [], [], None
    for frame in [*led_frames, ambient]:
        block_sums, half, peak = _blocks(_planes(frame, period), factor)
        sums.append(block_sums)
        halves.append(half)
        ok = (peak < spec.white_level).all(axis=2)
        valid = ok if valid is None else valid & ok
    assert valid is not None
    return sums, halves, valid


def reference_statistics(
    ambient: np.ndarray, led_frames: list[np.ndarray], spec: FrameStackSpec, factor: int, period: int, stride: int
) -> SequenceStatistics:
    """Eq. 4–6's statistics of the block sums, with the half differences' noise, written out directly."""
    sums, halves, valid = _reference_blocks(ambient, led_frames, spec, factor, period)
    black = spec.black_level * factor * factor
    scales = np.asarray(spec.led_scales)
    a = spec.ambient_scale * (sums[-1] - black)
    differences = np.stack([scales[j] * (sums[j] - black) - a for j in range(len(led_frames))])
    f = np.einsum("kj,j...->k...", spec.unmixing, differences)
    f_valid, a_valid = f[:, valid].reshape(f.shape[0], -1), a[valid].reshape(-1)
    probed = np.zeros_like(valid)
    probed[::stride] = True
    probe_valid = valid & probed
    noise_a = spec.ambient_scale * halves[-1]
    noise_d = np.stack([scales[j] * halves[j] - noise_a for j in range(len(led_frames))])
    noise_f = np.einsum("kj,j...->k...", spec.unmixing, noise_d)
    nf, na = noise_f[:, probe_valid].reshape(f.shape[0], -1), noise_a[probe_valid].reshape(-1)
    scale = valid.sum() / probe_valid.sum()
    return SequenceStatistics(
        gram=f_valid @ f_valid.T,
        cross=f_valid @ a_valid,
        ambient_energy=float(a_valid @ a_valid),
        n_samples=int(valid.sum()) * a.shape[2],
        n_total=a.size,
        ambient_sum=float(a_valid.sum()),
        led_sums=f_valid.sum(axis=1),
        noise=statistics.NoiseMoments(scale * nf @ nf.T, scale * nf @ na, float(scale * na @ na)),
    )


def assert_same(actual: SequenceStatistics, expected: SequenceStatistics, rtol: float = 1e-9) -> None:
    scale = float(np.abs(expected.gram).max())
    np.testing.assert_allclose(actual.gram, expected.gram, rtol=rtol, atol=rtol * scale)
    np.testing.assert_allclose(actual.cross, expected.cross, rtol=rtol, atol=rtol * scale)
    np.testing.assert_allclose(actual.ambient_energy, expected.ambient_energy, rtol=rtol)
    np.testing.assert_allclose(
        actual.led_sums, expected.led_sums, rtol=rtol, atol=rtol * float(np.abs(expected.led_sums).max())
    )
    np.testing.assert_allclose(actual.ambient_sum, expected.ambient_sum, rtol=rtol)
    assert (actual.n_samples, actual.n_total) == (expected.n_samples, expected.n_total)
    assert (actual.noise is None) == (expected.noise is None)
    if actual.noise is not None and expected.noise is not None:
        noise_scale = float(np.abs(expected.noise.gram).max())
        np.testing.assert_allclose(actual.noise.gram, expected.noise.gram, rtol=rtol, atol=rtol * noise_scale)
        np.testing.assert_allclose(actual.noise.cross, expected.noise.cross, rtol=rtol, atol=rtol * noise_scale)
        np.testing.assert_allclose(actual.noise.ambient_energy, expected.noise.ambient_energy, rtol=rtol)


CASES = [
    # shape, period, factor: sizes not multiples of the block; Bayer mosaics of odd size
    ((37, 53, 3), 1, 4),
    ((41, 67, 3), 1, 2),
    ((43, 59, 3), 1, 3),
    ((45, 71), 2, 4),
    ((39, 61), 2, 2),
    ((33, 47), 1, 4),
]


@pytest.mark.parametrize(("shape", "period", "factor"), CASES)
@pytest.mark.parametrize("workers", [1, 2])
def test_binned_statistics_match_the_reference(
    route: str, shape: tuple[int, ...], period: int, factor: int, workers: int
) -> None:
    ambient, frames, spec = _frames(shape, 3, seed=sum(shape) + factor)
    actual = accumulate_statistics(
        ambient, frames, spec, bin_factor=factor, cfa_period=period, workers=workers, chunk_pixels=37
    )
    expected = reference_statistics(ambient, frames, spec, factor, period, 1)
    if factor % 2:
        expected = SequenceStatistics(**{**expected.__dict__, "noise": None})
    assert actual.n_samples < actual.n_total  # the saturated blocks are out
    assert_same(actual, expected)


@pytest.mark.parametrize("workers", [1, 2])
def test_a_strided_noise_probe_matches_the_reference(route: str, workers: int, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(block_rows, "PROBE_BLOCKS", 20)  # small frames probe every 2nd–4th block row
    ambient, frames, spec = _frames((93, 85, 3), 4, seed=5)
    stride = block_rows.probe_stride(93 // 4, 85 // 4)
    assert stride > 1
    actual = accumulate_statistics(ambient, frames, spec, bin_factor=4, workers=workers)
    assert_same(actual, reference_statistics(ambient, frames, spec, 4, 1, stride))


def assert_identical(actual: object, expected: object, where: str = "statistics", rtol: float = 0.0) -> None:
    """Every field the same to the bit (arrays, numbers, nested moments); with ``rtol``, the float arrays and numbers
    within ``rtol`` of the largest magnitude of their field (integers still exact)."""
    assert type(actual) is type(expected), where
    if hasattr(expected, "__dataclass_fields__"):
        for name in expected.__dataclass_fields__:
            assert_identical(getattr(actual, name), getattr(expected, name), f"{where}.{name}", rtol)
    elif isinstance(expected, np.ndarray) and rtol and expected.dtype.kind == "f":
        scale = float(np.max(np.abs(expected))) if expected.size else 0.0
        np.testing.assert_allclose(actual, expected, rtol=0, atol=rtol * scale, err_msg=where, strict=True)
    elif isinstance(expected, np.ndarray):
        np.testing.assert_array_equal(actual, expected, err_msg=where, strict=True)
    elif rtol and isinstance(expected, float):
        assert abs(actual - expected) <= rtol * abs(expected), where  # type: ignore[operator]
    else:
        assert actual == expected or (actual != actual and expected != expected), where  # NaN equals NaN here


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize(
    ("shape", "period", "factor", "weighting"),
    [((70, 98, 3), 1, 4, True), ((70, 98, 3), 1, 8, True), ((66, 90), 2, 4, True), ((37, 53, 3), 1, 1, False)],
)
def test_both_routes_give_the_same_statistics_to_rounding(
    dtype: type, shape: tuple[int, ...], period: int, factor: int, weighting: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The compiled and the numpy route: the all-pixel moments are exact integers on both (the same bits, whatever
    the threads); the block sums' moments are numpy's or the compiled :func:`frame_kernels.block_statistics`, which
    agree to 1e-12 relative (the two routes of the threads alike to the bit)."""
    monkeypatch.setattr(frame_kernels, "MOMENT_TASK_PIXELS", 500)  # tasks and chunks cut the frames differently
    ambient, frames, spec = _frames(shape, 4, seed=11, dtype=dtype)
    results = {}
    for name in ("numpy", "numba"):
        monkeypatch.setenv(frame_kernels.KERNELS_VARIABLE, name)
        frame_kernels._compiled.cache_clear()
        if name == "numba" and not frame_kernels.enabled():
            frame_kernels._compiled.cache_clear()
            pytest.skip("numba is not installed")
        results[name] = [
            accumulate_statistics(
                ambient,
                frames,
                spec,
                bin_factor=factor,
                cfa_period=period,
                workers=workers,
                weighting=weighting,
                chunk_pixels=777,
            )
            for workers in (1, 2)
        ]
    frame_kernels._compiled.cache_clear()
    reference = results["numpy"][0]
    assert reference.weighted == weighting
    assert reference.n_samples < reference.n_total  # saturated pixels are out on both routes
    for name, results_of_route in results.items():
        assert_identical(results_of_route[1], results_of_route[0])  # the threads change nothing
        assert_identical(results_of_route[0], reference, rtol=0.0 if factor == 1 or name == "numpy" else 1e-12)


@pytest.mark.parametrize(("shape", "period", "factor"), [((70, 98, 3), 1, 4), ((66, 90), 2, 4), ((93, 85, 3), 1, 3)])
@pytest.mark.parametrize("weighting", [False, True])
def test_the_compiled_moments_agree_with_numpy_to_rounding(
    shape: tuple[int, ...], period: int, factor: int, weighting: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """:class:`BlockRows` with ``compiled`` True and False on the same rows: the moments, the noise's, the channel
    moments and the estimate within 1e-12 of each other (relative to each field's largest value) — saturated blocks
    and excluded ones, a strided probe, a mosaic, an odd block (no probe), weighted and not."""
    if not frame_kernels.prepare():
        pytest.skip("numba is not installed")
    monkeypatch.setattr(block_rows, "PROBE_BLOCKS", 40)
    ambient, frames, spec = _frames(shape, 3, seed=5)
    taken = {}
    for compiled in (False, True):
        rows = _block_rows(3, ambient.shape, period, factor, spec, weighting=weighting, compiled=compiled)
        for row, frame in [(3, ambient), *enumerate(frames)]:
            rows.add_frame(row, frame, period)
        excluded = np.zeros(rows.block_shape[::2], dtype=bool)
        excluded[1, :3] = True
        rows.exclude(excluded)
        taken[compiled] = rows.statistics(spec)
    numpy_route, compiled_route = taken[False], taken[True]
    assert numpy_route.n_samples < numpy_route.n_total and (numpy_route.noise is None) == bool(factor % 2)
    assert_identical(compiled_route, numpy_route, rtol=1e-12)


@pytest.mark.parametrize("shape", [(37, 53, 3), (45, 71), (97, 89, 3)])
@pytest.mark.parametrize("workers", [1, 2])
@pytest.mark.parametrize("n_leds", [2, 3, 7])  # 4, 5 and 9 moment rows: the kernel's 3-row blocks padded or not
def test_all_pixel_statistics_match_the_reference(
    route: str, shape: tuple[int, ...], workers: int, n_leds: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(frame_kernels, "MOMENT_TASK_PIXELS", 500)  # several tasks, the last one short
    ambient, frames, spec = _frames(shape, n_leds, seed=3)
    actual = accumulate_statistics(ambient, frames, spec, chunk_pixels=101, workers=workers)
    # Every sample on its own (a mosaic's too): blocks of 1 of the frame as it is.
    expected = reference_statistics(ambient, frames, spec, 1, 1, 1)
    assert_same(actual, SequenceStatistics(**{**expected.__dict__, "noise": None}))


def test_streamed_block_rows_match_the_reference(route: str) -> None:
    """A capture adds raw frames one by one (FlashSession): the same statistics."""
    ambient, frames, spec = _frames((45, 71), 3, seed=8)
    rows = _block_rows(3, ambient.shape, 2, 2, spec)
    for row, frame in [(0, frames[0]), (3, ambient), (1, frames[1]), (2, frames[2])]:
        rows.add_frame(row, frame, 2)
    assert_same(rows.statistics(spec), reference_statistics(ambient, frames, spec, 2, 2, 1))


@pytest.mark.parametrize(("shape", "period", "factor"), [((45, 71), 2, 2), ((70, 98, 3), 1, 4)])
def test_block_rows_give_the_same_bits_whatever_the_frames_order(
    route: str, shape: tuple[int, ...], period: int, factor: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The ambient frame first or after an LED frame (its noise line then fitted between LED frames): the same rows,
    probe, saturated blocks and statistics to the bit — a strided probe, a mosaic, saturated pixels; a row added
    twice is refused."""
    monkeypatch.setattr(block_rows, "PROBE_BLOCKS", 40)
    ambient, frames, spec = _frames(shape, 3, seed=21)
    results = []
    for ambient_first in (True, False):
        rows = _block_rows(3, ambient.shape, period, factor, spec, weighting=True)
        order = [(3, ambient), *enumerate(frames)] if ambient_first else [(0, frames[0]), (3, ambient), (1, frames[1])]
        for row, frame in order[:3]:
            rows.add_frame(row, frame, period)
        with pytest.raises(SpectralDataError, match="taken"):
            rows.add_frame(order[2][0], order[2][1], period)  # a row added is taken
        for row, frame in order[3:] if ambient_first else [(2, frames[2])]:
            rows.add_frame(row, frame, period)
        assert rows.probe_stride > 1
        taken = rows.statistics(spec)
        excluded = np.logical_or.reduce(rows._invalid) if rows._invalid else None
        results.append((rows.rows.copy(), rows.differences.copy(), excluded, taken))
    (rows_1, probe_1, excluded_1, one), (rows_n, probe_n, excluded_n, other) = results
    assert excluded_1 is not None and excluded_1.any()  # the saturated pixels dropped blocks
    np.testing.assert_array_equal(excluded_n, excluded_1)
    np.testing.assert_array_equal(rows_n, rows_1)
    np.testing.assert_array_equal(probe_n, probe_1)
    for field in ("gram", "cross", "ambient_energy", "n_samples"):
        np.testing.assert_array_equal(getattr(other, field), getattr(one, field))
    for name, value in vars(one.channels).items():
        np.testing.assert_array_equal(getattr(other.channels, name), value, err_msg=name)


def reference_channel_moments(
    ambient: np.ndarray, led_frames: list[np.ndarray], spec: FrameStackSpec, factor: int, period: int, stride: int
) -> ChannelMoments:
    """:class:`ChannelMoments` written out: per valid block b, ``f_i,b`` and ``a_b`` in R^C and their outer products
    summed, the probed blocks' half differences alike (scaled by valid ÷ probed valid blocks)."""
    sums, halves, valid = _reference_blocks(ambient, led_frames, spec, factor, period)
    black, scales = spec.black_level * factor * factor, np.asarray(spec.led_scales)

    def images(values: list[np.ndarray], offset: float) -> tuple[np.ndarray, np.ndarray]:
        a = spec.ambient_scale * (values[-1] - offset)
        d = np.stack([scales[j] * (values[j] - offset) - a for j in range(len(led_frames))])
        return np.einsum("kj,j...->k...", spec.unmixing, d), a  # (k, h, w, C), (h, w, C)

    def moments(f: np.ndarray, a: np.ndarray, where: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        fb, ab = f[:, where], a[where]  # (k, blocks, C), (blocks, C)
        return np.einsum("kbc,bd->kcd", fb, ab), np.einsum("kbc,kbd->kcd", fb, fb), ab.T @ ab

    probed = np.zeros_like(valid)
    probed[::stride] = True
    scale = valid.sum() / (valid & probed).sum()
    noise = moments(*images(halves, 0.0), valid & probed)
    return ChannelMoments(*moments(*images(sums, black), valid), int(valid.sum()), *(scale * part for part in noise))


@pytest.mark.parametrize(("shape", "period", "factor"), [((70, 98, 3), 1, 4), ((66, 90), 2, 4), ((93, 85, 3), 1, 2)])
@pytest.mark.parametrize("weighting", [False, True])
def test_channel_moments_match_the_reference(
    route: str,
    shape: tuple[int, ...],
    period: int,
    factor: int,
    weighting: bool,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The per-channel moments flicker reads (:class:`ChannelMoments`) are unweighted whatever the main moments'
    weights, over the same valid blocks, in bands of block rows (several here), with a strided probe on the
    largest frame."""
    monkeypatch.setattr(block_rows, "CHANNEL_BAND_VALUES", 900)
    monkeypatch.setattr(block_rows, "PROBE_BLOCKS", 400)
    ambient, frames, spec = _frames(shape, 4, seed=sum(shape))
    n = len(frames)
    rows = _block_rows(n, ambient.shape, period, factor, spec, weighting=weighting)
    for row, frame in [(n, ambient), *enumerate(frames)]:
        rows.add_frame(row, frame, period)
    actual = rows.statistics(spec).channels
    expected = reference_channel_moments(ambient, frames, spec, factor, period, rows.probe_stride)
    assert actual is not None and actual.n_blocks == expected.n_blocks
    assert rows.probe_stride > 1 or shape != (93, 85, 3)
    for name in ("fa", "ff", "aa", "noise_fa", "noise_ff", "noise_aa"):
        value, reference = getattr(actual, name), getattr(expected, name)
        scale = float(np.abs(reference).max())
        np.testing.assert_allclose(value, reference, rtol=1e-9, atol=1e-9 * scale, err_msg=name)


def reference_synthesis(
    ambient: np.ndarray, led_frames: list[np.ndarray], spec: FrameStackSpec, weights: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``m_a + Σ w_k m_f,k`` with ``m_f = pinv(L)(F − m_a)`` on linearised frames, and the saturated pixels."""
    a = spec.ambient_scale * (ambient.astype(float) - spec.black_level)
    linear = [s * (f.astype(float) - spec.black_level) for s, f in zip(spec.led_scales, led_frames)]
    led_only = np.einsum("kj,j...->k...", spec.unmixing, np.stack([f - a for f in linear]))
    image = a + np.einsum("k,k...->...", weights, led_only)
    hit = np.zeros(ambient.shape, dtype=bool)
    for frame in [ambient, *led_frames]:
        hit |= frame >= spec.white_level
    return image, hit.any(axis=2) if hit.ndim == 3 else hit


@pytest.mark.parametrize("shape", [(131, 157, 3), (67, 45), (1, 1, 3)])
@pytest.mark.parametrize("workers", [1, 2])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_synthesis_matches_the_reference(
    route: str, shape: tuple[int, ...], workers: int, dtype: type, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(synthesis, "COMPILED_TASK_PIXELS", 1000)  # several tasks, the last one short
    ambient, frames, spec = _frames(shape, 4, seed=shape[0], saturate=shape[0] > 10)
    weights = np.array([0.3, 0.9, 0.0, 0.55])
    image, saturated = synthesize(ambient, frames, spec, weights, workers=workers, chunk_pixels=777, dtype=dtype)
    expected, expected_saturated = reference_synthesis(ambient, frames, spec, weights)
    assert image.dtype == dtype and image.shape == shape
    tolerance = 1e-6 if dtype == np.float32 else 1e-12
    np.testing.assert_allclose(image, expected, rtol=tolerance, atol=tolerance * float(np.abs(expected).max()))
    np.testing.assert_array_equal(saturated, expected_saturated)
    assert saturated.any() == (shape[0] > 10)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("n_leds", [1, 2, 6, 7, 10])  # the kernel adds four frames a sweep: every remainder
def test_the_two_synthesis_routes_write_the_same_image_bit_for_bit(
    dtype: type, n_leds: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A process with the kernels loaded (live view, a study) and a fresh one (msflash flash) write the
    # same file: the numpy route repeats the compiled kernel's float64 arithmetic, step for step.
    monkeypatch.setenv(frame_kernels.KERNELS_VARIABLE, "numba")
    frame_kernels._compiled.cache_clear()
    if not frame_kernels.enabled():
        frame_kernels._compiled.cache_clear()
        pytest.skip("numba is not installed")
    ambient, frames, spec = _frames((97, 203, 3), n_leds, seed=11)
    weights = np.resize([0.31, 0.97, 0.0, 0.55, 1.0, 0.123456789, 0.7], n_leds)
    compiled, compiled_saturated = synthesize(ambient, frames, spec, weights, dtype=dtype)
    monkeypatch.setenv(frame_kernels.KERNELS_VARIABLE, "numpy")
    frame_kernels._compiled.cache_clear()
    plain, plain_saturated = synthesize(ambient, frames, spec, weights, dtype=dtype, chunk_pixels=501)
    frame_kernels._compiled.cache_clear()
    np.testing.assert_array_equal(plain, compiled)
    np.testing.assert_array_equal(plain_saturated, compiled_saturated)


def test_synthesis_refuses_an_image_type_it_cannot_write() -> None:
    ambient, frames, spec = _frames((8, 8, 3), 2, seed=1)
    with pytest.raises(SpectralDataError, match="image type int16; expected float32 or float64"):
        synthesize(ambient, frames, spec, np.ones(2), dtype=np.int16)


POLICY = """
import sys
import numpy as np
from msflash.processing import frame_kernels
from msflash.processing.accumulate import accumulate_statistics
from msflash.processing.statistics import FrameStackSpec
frame_kernels.COMPILE_BYTES = int(sys.argv[1])
frames = [np.full((32, 40, 3), 100 + k, np.uint16) for k in range(4)]
accumulate_statistics(frames[0], frames[1:], FrameStackSpec(0, 4000, 1.0, (1.0,) * 3, np.eye(3)), bin_factor=4)
print(frame_kernels.enabled(), "numba" in sys.modules)
"""


@pytest.mark.parametrize(("threshold", "expected"), [(1 << 40, "False False"), (0, "True True")])
def test_small_one_off_work_does_not_pay_numbas_start_up(threshold: int, expected: str) -> None:
    """A fresh process loads numba only for work of at least COMPILE_BYTES (unless told otherwise)."""
    import os
    import subprocess
    import sys

    if not frame_kernels.prepare():
        pytest.skip("numba is not installed")
    environment = {key: value for key, value in os.environ.items() if key != frame_kernels.KERNELS_VARIABLE}
    result = subprocess.run(
        [sys.executable, "-c", POLICY, str(threshold)], capture_output=True, text=True, env=environment, timeout=300
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.split("\n")[-2] == expected


@pytest.mark.parametrize(
    ("shape", "cfa", "factor"), [((70, 98, 3), None, 4), ((66, 90), "GRBG", 4), ((37, 53, 3), None, 3)]
)
def test_channel_statistics_are_the_same_on_both_routes_to_the_bit(
    shape: tuple[int, ...], cfa: str | None, factor: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The light prior's and the families' channel-resolved moments (:mod:`processing.channel_statistics`) take the
    compiled block pass where it is loaded: the same block sums, half differences and saturated blocks as numpy's, so
    the same moments per fold — odd sizes, a mosaic, saturated pixels, an odd block (no probe)."""
    from msflash.processing.channel_statistics import accumulate_channel_statistics

    ambient, frames, spec = _frames(shape, 3, seed=5)
    results = {}
    for name in ("numpy", "numba"):
        monkeypatch.setenv(frame_kernels.KERNELS_VARIABLE, name)
        frame_kernels._compiled.cache_clear()
        if name == "numba" and not frame_kernels.enabled():
            frame_kernels._compiled.cache_clear()
            pytest.skip("numba is not installed")
        results[name] = accumulate_channel_statistics(ambient, frames, spec, cfa=cfa, bin_factor=factor)
    frame_kernels._compiled.cache_clear()
    numpy_route, compiled = results["numpy"], results["numba"]
    assert numpy_route.n_blocks < numpy_route.n_blocks_total  # saturated blocks are out on both routes
    assert np.array_equal(numpy_route.counts, compiled.counts)
    for name in ("ff", "fa", "aa"):
        assert np.array_equal(getattr(numpy_route.moments, name), getattr(compiled.moments, name))
        if factor % 2 == 0:
            assert np.array_equal(getattr(numpy_route.noise, name), getattr(compiled.noise, name))
    assert (numpy_route.noise is None) == (factor % 2 == 1) == (compiled.noise is None)


@pytest.mark.parametrize("cfa", ["RGGB", None])
def test_the_compiled_moments_give_the_numpy_estimate_to_rounding(cfa: str | None) -> None:
    """The bench's world (a small one), streamed as ``msflash estimate`` does on each route: the default estimate's
    spectrum and weights agree to 1e-9 relative (the moments to 1e-12: the solve's conditioning and α's search
    amplify their last digits)."""
    from msflash.lab.bench.processing import benchmark_world
    from msflash.processing.ambient import estimate_ambient

    if not frame_kernels.prepare():
        pytest.skip("numba is not installed")
    world = benchmark_world(96, 128, cfa=cfa)
    frames, spec, period = world["frames"], world["spec"], 2 if cfa else 1
    estimates = []
    for compiled in (False, True):
        rows = _block_rows(len(frames) - 1, frames[0].shape, period, 4, spec, weighting=True, compiled=compiled)
        for row, frame in zip([len(frames) - 1, *range(len(frames) - 1)], frames, strict=True):
            rows.add_frame(row, frame, period)
        estimates.append(estimate_ambient(rows.statistics(spec), world["leds"]))
    numpy_route, compiled_route = estimates
    for name in ("ambient_weights", "spectrum"):
        expected, actual = getattr(numpy_route, name), getattr(compiled_route, name)
        expected, actual = getattr(expected, "values", expected), getattr(actual, "values", actual)
        np.testing.assert_allclose(actual, expected, rtol=0, atol=1e-9 * float(np.max(np.abs(expected))), err_msg=name)


@pytest.mark.parametrize(("shape", "period"), [((70, 98), 2), ((40, 36, 2), 1), ((36, 44, 4), 1), ((36, 40, 3), 1)])
@pytest.mark.parametrize("factor", [2, 4, 18])
def test_the_compiled_block_pass_is_exact_at_the_full_16_bit_range(
    shape: tuple[int, ...], period: int, factor: int
) -> None:
    """The block pass's 32-bit column sums (two channels packed in one 64-bit word where a pixel group holds an even
    number of values, the alternating sums biased to stay non-negative) against int64 sums written out, on samples
    at 0 and 65 535 (the largest sums and the largest half differences of either sign) and in between."""
    if not frame_kernels.prepare():
        pytest.skip("numba is not installed")
    rng = np.random.default_rng(factor)
    frame = np.where(rng.random(shape) < 0.5, 0, 65535).astype(np.uint16)
    frame[: shape[0] // 2] = rng.integers(0, 65536, (shape[0] // 2, *shape[1:]), dtype=np.uint16)
    planes = block_sums.cfa_planes(frame, period).astype(np.int64)
    height, width, channels = planes.shape[0] // factor, planes.shape[1] // factor, planes.shape[2]
    blocks = planes[: height * factor, : width * factor].reshape(height, factor, width, factor, channels)
    signs = np.where((np.arange(factor)[:, None] + np.arange(factor)[None, :]) % 2 == 0, 1, -1)
    expected_sums = blocks.sum(axis=(1, 3)).transpose(0, 2, 1)  # (H/f, C, W/f)
    expected_halves = np.einsum("hawbc,ab->hwc", blocks, signs)  # (H/f, W/f, C)
    sums = np.empty((height, channels, width))
    halves = np.empty((height, width, channels)) if factor % 2 == 0 else None
    done, saturated = frame_kernels.block_pass(frame, factor, period, 70000.0, 1, sums, halves)
    assert done and saturated is None
    np.testing.assert_array_equal(sums, expected_sums)
    if halves is not None:
        np.testing.assert_array_equal(halves, expected_halves)
