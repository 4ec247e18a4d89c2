"""The computational flash image: ``m_a + Σ w_k m_f,k`` on linearised frames."""

from __future__ import annotations

import numpy as np
import pytest

from msflash.processing.errors import SpectralDataError
from msflash.processing.sensor import SensorModel
from msflash.processing.statistics import FrameStackSpec
from msflash.processing.synthesis import SynthesisStream, frame_coefficients, synthesize, to_raw_values
from tests.helpers import EXACT, FLOAT32, ambient, chart, one_hot_levels, rendered_frames, spec_for

WEIGHTS = np.array([0.5, 0.0, 1.0, 0.25, 2.0, -0.3, 0.8])


def naive(
    ambient_frame: np.ndarray, led_frames: list[np.ndarray], spec: FrameStackSpec, weights: np.ndarray
) -> np.ndarray:
    a = (ambient_frame.astype(float) - spec.black_level) * spec.ambient_scale
    diffs = np.stack([(f.astype(float) - spec.black_level) * s - a for f, s in zip(led_frames, spec.led_scales)])
    only = np.tensordot(spec.unmixing, diffs, axes=1)
    return a + np.tensordot(weights, only, axes=1)


def saturated_naive(frames: list[np.ndarray], white: float) -> np.ndarray:
    bright = np.any(np.stack(frames) >= white, axis=0)
    return bright.any(axis=2) if bright.ndim == 3 else bright


@pytest.mark.parametrize("cfa", [None, "RGGB", "GBRG"])
@pytest.mark.parametrize("chunk", [1, 50, 1 << 15])
def test_equals_naive_sum_with_differing_exposures(cfa: str | None, chunk: int) -> None:
    sensor = SensorModel(cfa=cfa)
    scene = chart(specular_strip_px=3)
    gains = [1.0, 2.0, 1.0, 1.5, 1.0, 4.0, 1.0, 1.0]
    a, f, exposures, gains = rendered_frames(
        ambient("fluorescent"), sensor=sensor, scene=scene, noise=True, gains=gains
    )
    assert len(set(exposures)) > 1
    spec = spec_for(sensor, exposures, gains, one_hot_levels(7))
    image, saturated = synthesize(a, f, spec, WEIGHTS, chunk_pixels=chunk)
    assert image.dtype == np.float32 and image.shape == a.shape
    expected = naive(a, f, spec, WEIGHTS)
    np.testing.assert_allclose(image, expected, rtol=0, atol=FLOAT32 * np.abs(expected).max())
    np.testing.assert_array_equal(saturated, saturated_naive([a, *f], sensor.white_level))
    assert saturated[-3:].all() and saturated.sum() == 3 * scene.shape[1]


def test_multiplexed_levels() -> None:
    rng = np.random.default_rng(0)
    levels = np.array([[1.0, 0.5, 0.0], [0.0, 1.0, 0.5], [0.5, 0.0, 1.0], [1.0, 1.0, 1.0]])
    a = rng.integers(100, 2000, (9, 7, 3)).astype(np.uint16)
    frames = [a + rng.integers(0, 900, a.shape).astype(np.uint16) for _ in range(4)]
    spec = FrameStackSpec(64.0, 4095.0, 1 / 700.0, (1 / 500.0, 1 / 900.0, 1 / 300.0, 1 / 1000.0), levels)
    weights = np.array([0.7, -0.2, 1.3])
    image, saturated = synthesize(a, frames, spec, weights, chunk_pixels=10)
    expected = naive(a, frames, spec, weights)
    np.testing.assert_allclose(image, expected, atol=FLOAT32 * np.abs(expected).max())
    assert not saturated.any()


def test_zero_weights_give_the_linear_ambient() -> None:
    sensor = SensorModel()
    a, f, exposures, gains = rendered_frames(ambient("tungsten"), sensor=sensor)
    spec = spec_for(sensor, exposures, gains, one_hot_levels(7))
    image, _ = synthesize(a, f, spec, np.zeros(7))
    linear = (a.astype(float) - sensor.black_level) * spec.ambient_scale
    np.testing.assert_allclose(image, linear, atol=FLOAT32 * linear.max())


def test_frame_coefficients_sum_to_one_with_the_ambient() -> None:
    spec = FrameStackSpec(0, 100, 1.0, (1.0, 1.0, 1.0), np.array([[1.0, 0, 0], [0, 1.0, 0], [1.0, 1.0, 1.0]]))
    ambient_coefficient, coefficients = frame_coefficients(spec, np.array([0.2, 0.3, 0.4]))
    np.testing.assert_allclose(coefficients, np.linalg.pinv(spec.led_levels).T @ [0.2, 0.3, 0.4], atol=EXACT)
    assert ambient_coefficient + coefficients.sum() == pytest.approx(1.0, abs=EXACT)


def test_to_raw_values_round_trip() -> None:
    image = np.array([[[0.0, 1.0, 2.5]]])
    raw = to_raw_values(image, exposure_us=100.0, gain=2.0, black_level=64.0, white_level=300.0)
    assert raw.dtype == np.uint16
    assert raw.tolist() == [[[64, 264, 300]]]  # 2.5·200 + 64 = 564 clips to the white level


def test_bad_weights_and_shapes() -> None:
    spec = FrameStackSpec(0, 100, 1.0, (1.0, 1.0), np.eye(2))
    a = np.zeros((4, 4, 3))
    with pytest.raises(SpectralDataError, match="3 flash weights; expected 2"):
        synthesize(a, [a, a], spec, np.ones(3))
    with pytest.raises(SpectralDataError, match="finite"):
        synthesize(a, [a, a], spec, np.array([np.inf, 0.0]))
    with pytest.raises(SpectralDataError, match="frame 2 has shape"):
        synthesize(a, [a, a[:2]], spec, np.ones(2))


@pytest.mark.parametrize("weights", [[1e308, 1e308], [1e300, 0.0], [0.0, -1e36]])
def test_weights_that_overflow_the_float32_image_are_refused(weights: list[float]) -> None:
    """1e308 gave a NaN image (plus numpy overflow warnings on stderr); 1e36 × 100 exceeds float32."""
    spec = FrameStackSpec(0, 100, 1.0, (1.0, 1.0), np.eye(2))
    a = np.full((4, 4, 3), 50, dtype=np.uint16)
    with pytest.raises(SpectralDataError, match="overflow the float32 image"):
        synthesize(a, [a + 10, a + 20], spec, np.array(weights))


def test_large_weights_that_fit_float32_give_a_finite_image() -> None:
    """Weights outside [0, 1] (computational mode) are allowed as long as the image holds them."""
    spec = FrameStackSpec(0, 100, 1.0, (1.0, 1.0), np.eye(2))
    a = np.full((4, 4, 3), 50, dtype=np.uint16)
    image, _ = synthesize(a, [a + 10, a + 20], spec, np.array([1e30, -3.0]))
    assert np.all(np.isfinite(image))
    np.testing.assert_allclose(image, 50 + 1e30 * 10 - 3.0 * 20, rtol=1e-6)


@pytest.mark.parametrize(("frame", "name"), [(0, "the ambient frame"), (2, "LED frame 2")])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_float_frames_are_refused_naming_the_frame(frame: int, name: str, bad: float) -> None:
    """A NaN/inf pixel in a float (EXR) frame went into the synthesised image (msflash synthesize: exit 0,
    NaN in the EXR; garbage in the 16-bit TIFF)."""
    spec = FrameStackSpec(0, 100, 1.0, (1.0, 1.0), np.eye(2))
    frames = [np.full((4, 4, 3), 50.0, dtype=np.float32) for _ in range(3)]
    frames[frame][1, 2, 0] = bad
    with pytest.raises(SpectralDataError, match=f"synthesis: {name} holds non-finite values"):
        synthesize(frames[0], frames[1:], spec, np.array([0.5, 0.5]))


def test_a_flickering_stack_holds_the_ambient_once_with_its_offsets() -> None:
    """Frames ``m_j = g_j a + Σ L_ji f_i`` (the lamp at gain ``g_j`` in frame j): the LED images read ``f + e a``
    with ``e = U (g − 1)`` (processing/flicker.py); given ``e``, the image is ``a + Σ w_i f_i`` again."""
    rng = np.random.default_rng(3)
    k, shape = 3, (6, 5, 3)
    levels = np.array([[1.0, 0.0, 0.0], [0.5, 1.0, 0.0], [0.0, 0.5, 1.0], [1.0, 1.0, 1.0]])
    spec = FrameStackSpec(0.0, 1e9, 1.0, (1.0,) * len(levels), levels)
    a = rng.uniform(10, 20, shape)
    f = rng.uniform(0, 30, (k, *shape))
    gains = np.array([1.3, 0.7, 1.1, 0.8])  # each LED frame's ambient, relative to the ambient frame's
    frames = [g * a + np.tensordot(row, f, axes=1) for g, row in zip(gains, levels, strict=True)]
    weights = np.array([0.6, 1.5, 0.4])
    truth = a + np.tensordot(weights, f, axes=1)
    offsets = spec.unmixing @ (gains - 1.0)
    steady, _ = synthesize(a, frames, spec, weights, dtype=np.float64)
    image, _ = synthesize(a, frames, spec, weights, dtype=np.float64, ambient_offsets=offsets)
    assert np.abs(steady - truth).max() > 1.0  # without the offsets the lamp's extra share stays in
    np.testing.assert_allclose(image, truth, rtol=1e-12)
    stream = SynthesisStream(spec, weights, shape, dtype=np.float64, ambient_offsets=offsets)
    for frame in (a, *frames):
        stream.add(frame)
    np.testing.assert_array_equal(stream.result()[0], image)
    # The offsets known only after the pass (a check read from the same frames): taken out of the sum then.
    later = SynthesisStream(spec, weights, shape, dtype=np.float64)
    for frame in (a, *frames):
        later.add(frame)
    later.take_out_ambient_share(a, offsets)
    np.testing.assert_allclose(later.result()[0], image, rtol=1e-13)
    with pytest.raises(SpectralDataError, match="ambient offsets of shape"):
        frame_coefficients(spec, weights, np.ones(k + 1))
    with pytest.raises(SpectralDataError, match="ambient frame of shape"):
        later.take_out_ambient_share(a[:, :2], offsets)
