"""Dark frames and linearity on synthetic series with known black level, noise and nonlinearity."""

from __future__ import annotations

import numpy as np
import pytest

from msflash.calibration.dark import channel_planes, measure_dark, measure_linearity
from msflash.calibration.errors import CalibrationError
from msflash.processing.sensor import mosaic

BLACK = np.array([64.0, 66.0, 61.0])
READ_NOISE = 3.0
WHITE = 4095.0
FULL = WHITE - 66.0


def dark_series(n=6, shape=(48, 64), cfa=None, seed=0):
    rng = np.random.default_rng(seed)
    offsets = rng.normal(0, 0.5, shape + (3,))  # fixed pattern, the same in every frame
    frames = []
    for _ in range(n):
        rgb = BLACK + offsets + rng.normal(0, READ_NOISE, shape + (3,))
        frames.append(np.round(mosaic(rgb, cfa) if cfa else rgb))
    return frames


@pytest.mark.parametrize("cfa", [None, "RGGB", "BGGR"])
def test_black_level_and_read_noise(cfa):
    result = measure_dark(dark_series(cfa=cfa), cfa=cfa)
    np.testing.assert_allclose(result.black_level, BLACK, atol=0.15)
    np.testing.assert_allclose(result.read_noise_dn, READ_NOISE, rtol=0.06)
    assert result.n_frames == 6 and result.hot_pixel_fraction == 0.0
    assert all(p > 0.4 for p in result.fixed_pattern_dn)


def test_hot_pixels_counted():
    frames = dark_series()
    for f in frames:
        f[5, 5, :] += 500
    assert measure_dark(frames).hot_pixel_fraction == pytest.approx(3 / (48 * 64 * 3))


def linearity_series(beta=0.04, seed=1, exposures=None, cfa=None):
    """Signal s = k·t compressed as s − β s²/FULL, then clipped at WHITE."""
    rng = np.random.default_rng(seed)
    exposures = np.geomspace(1, 70, 16) if exposures is None else exposures
    gains = np.array([80.0, 100.0, 60.0])
    frames = []
    for t in exposures:
        s = gains * t
        measured = s - beta * s**2 / FULL
        rgb = BLACK + measured + rng.normal(0, 1.0, (32, 32, 3))
        rgb = np.minimum(np.round(rgb), WHITE)
        frames.append(mosaic(rgb, cfa) if cfa else rgb)
    return frames, exposures, gains


@pytest.mark.parametrize("cfa", [None, "GRBG"])
def test_linearity_recovers_compression_and_saturation(cfa):
    frames, exposures, gains = linearity_series(cfa=cfa)
    result = measure_linearity(list(reversed(frames)), list(reversed(exposures)), BLACK, cfa=cfa)
    assert result.exposures == tuple(sorted(exposures))
    assert result.saturation_level == WHITE
    assert len(result.saturated_frames) >= 1
    # The small-signal slope is the true gain (within the compression of the low points).
    np.testing.assert_allclose(result.slope_dn_per_exposure, gains, rtol=0.02)
    # Deviation at each unsaturated point ≈ −β s/FULL.
    for i, t in enumerate(result.exposures):
        if i in result.saturated_frames:
            continue
        truth = -0.04 * gains * t / FULL
        np.testing.assert_allclose(result.deviation[i], truth, atol=0.006)
    assert 0.02 < result.max_relative_deviation < 0.05
    assert result.linear_limit_dn is not None and result.linear_limit_dn < 0.5 * FULL
    # The linearisation maps measured signals back onto the line.
    for c in range(3):
        s = gains[c] * 10.0
        assert np.polyval(result.linearisation[c], s - 0.04 * s**2 / FULL) == pytest.approx(s, rel=0.01)


def test_linear_sensor_passes():
    frames, exposures, _ = linearity_series(beta=0.0)
    result = measure_linearity(frames, exposures, BLACK)
    assert result.max_relative_deviation < 0.005
    assert result.emva_nonlinearity < 0.005
    assert result.linear_limit_dn > 0.5 * FULL


@pytest.mark.parametrize(
    "frames,exposures,message",
    [
        ([np.zeros((4, 4))] * 2, [1, 2], "at least 3 exposures"),
        ([np.zeros((4, 4))] * 3, [1, 2], "2 exposures for 3 frames"),
        ([np.zeros((4, 4))] * 3, [1, 0, 2], "exposures must be finite and > 0"),
        ([np.zeros((4, 4)), np.zeros((4, 5)), np.zeros((4, 4))], [1, 2, 3], "different shapes"),
        ([np.full((4, 4), 4095.0)] * 3, [1, 2, 3], "unsaturated frames with signal"),
    ],
)
def test_bad_series(frames, exposures, message):
    with pytest.raises(CalibrationError, match=message):
        measure_linearity(frames, exposures, 64.0)


def test_bad_frames():
    with pytest.raises(CalibrationError, match="no frames"):
        measure_dark([])
    with pytest.raises(CalibrationError, match="expected \\(H, W\\)"):
        channel_planes(np.zeros(5))
    with pytest.raises(CalibrationError, match="cfa 'XYZW'"):
        channel_planes(np.zeros((4, 4)), "XYZW")


@pytest.mark.parametrize("value", [0, 64, 4095])
@pytest.mark.parametrize("cfa", [None, "RGGB"])
def test_constant_dark_frames_are_refused(value: int, cfa):
    """Dark frames clipped at saturation (every pixel 65535 on the CLI) were stored as black level
    65535 with read noise 0; any frame series of one value has no noise to measure."""
    shape = (8, 8) if cfa else (8, 8, 3)
    with pytest.raises(CalibrationError, match=f"holds the one value {value} in every pixel of every frame"):
        measure_dark([np.full(shape, value, dtype=np.uint16)] * 3, cfa)


@pytest.mark.parametrize(
    "frames,exposures,message",
    [
        (
            [np.full((4, 4), 564.0)] * 4,
            [2756.9] * 4,
            r"every unsaturated frame has exposure·gain 2756\.9; expected at least 2",
        ),
        (
            [np.full((4, 4), 564.0)] * 3 + [np.full((4, 4), 4095.0)] * 2,
            [5, 5, 5, 9, 10],
            "every unsaturated frame has exposure·gain 5;",
        ),
    ],
)
def test_series_at_one_exposure_is_refused(frames, exposures, message):
    """All frames at one exposure (msflash calibrate linearity on such a sequence): numpy RankWarnings,
    then 'max deviation 2.0, linear up to 0 DN' stored in the calibration."""
    with pytest.raises(CalibrationError, match=message):
        measure_linearity(frames, exposures, 64.0, white_level=4095.0)
