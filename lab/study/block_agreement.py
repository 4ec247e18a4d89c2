"""Does the block path give the all-pixel answer? The reference all-pixel estimate and the agreement figures.

Why the two paths differed (issue 21, item 4)
---------------------------------------------
``msflash estimate --bin 1`` and the default 4 × 4 blocks are not the same estimator with more or
fewer samples. Even block sizes carry the half-difference noise probe (:mod:`processing.block_rows`,
module notes): their moments are *denoised* (no errors-in-variables bias) and their samples
*inverse-variance weighted*. Block size 1 — and every odd size — has no probe, so its estimate is
solved on the moments as observed: the LED-only images' noise inflates their Gram matrix and the
weights shrink and rotate (eq. 5 regressed on noisy regressors), while its band, which inverts that
inflated matrix and knows nothing of the bias, is several times too narrow. On the bench's scene
the all-pixel estimate is the biased one, not the blocks'.

The reference
-------------
A fair "all-pixel answer" uses every pixel *and* removes the noise's share of the moments. Single
pixels cannot measure their own noise without texture leaking in (the probe needs two halves of a
block), so the reference takes each frame's photon-transfer line as known — the study renders the
frames, so it knows it: raw variance ``gain · (value − black) + read`` per frame
(:class:`FrameNoise`). With the rows ``[F_1 … F_n, A, 1]`` and inverse-variance weights ``w`` (from the
ambient frame), the noise's share of the weighted raw moments is diagonal (frames have independent
noise): ``Σ w var_j = gain_j · Σ w (F_j − black) + read_j · Σ w``, taken from the moments' last column.
Mapped like the moments (:func:`processing.statistics.statistics_from_moments`), it becomes the
statistics' :attr:`~processing.statistics.SequenceStatistics.noise`, and the solvers use it as they
use the probe's. This is the best estimate the pixels allow; the block path is then judged by how far
it lies from it in units of its pixel-noise band (:func:`agreement`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from msflash.processing.ambient import AmbientEstimate
from msflash.processing.errors import SpectralDataError
from msflash.processing.moment_products import DEFAULT_CHUNK_PIXELS
from msflash.processing.statistics import FrameStackSpec, SequenceStatistics, statistics_from_moments


@dataclass(frozen=True)
class FrameNoise:
    """A frame's photon-transfer line in raw units: variance ``gain · max(value − black, 0) + read``."""

    gain: float
    """Variance per raw unit above black (the conversion gain times the analogue gain)."""
    read: float
    """Variance at black (read noise and quantisation)."""


def sensor_noise(electrons_per_dn: float, read_noise_e: float, gain: float = 1.0) -> FrameNoise:
    """The line of a sensor converting ``electrons_per_dn`` electrons per raw unit at gain 1, with read noise
    ``read_noise_e`` electrons before the analogue ``gain`` and rounding to integers.

    Examples
    --------
    >>> sensor_noise(0.5, 2.0)
    FrameNoise(gain=2.0, read=16.083333333333332)
    """
    if not (electrons_per_dn > 0 and gain > 0 and read_noise_e >= 0):
        raise SpectralDataError(
            f"sensor noise: electrons_per_dn {electrons_per_dn}, gain {gain}, read noise {read_noise_e}; "
            "expected positive values (read noise ≥ 0)"
        )
    return FrameNoise(gain / electrons_per_dn, (read_noise_e * gain / electrons_per_dn) ** 2 + 1.0 / 12.0)


def all_pixel_statistics(
    ambient: np.ndarray,
    led_frames: Sequence[np.ndarray],
    spec: FrameStackSpec,
    noise: Sequence[FrameNoise],
    chunk_pixels: int = DEFAULT_CHUNK_PIXELS,
    weighting: bool = True,
    cfa_period: int = 1,
) -> SequenceStatistics:
    """The statistics of eq. 4–6 on every pixel, inverse-variance weighted, with their noise's share known.

    Parameters
    ----------
    ambient, led_frames, spec
        As :func:`processing.accumulate.accumulate_statistics` (a mosaic as (H, W): every sample alike).
    noise
        The line of the ambient frame, then of each LED frame.
    weighting
        Inverse-variance weights from the ambient frame's line (False: every sample alike), at each
        pixel's :func:`neighbour_levels`.
    cfa_period
        2 for a Bayer mosaic (the neighbours are then the same colour's).

    Returns
    -------
    SequenceStatistics
        Weighted (mean weight 1 over the valid samples) with :attr:`~SequenceStatistics.noise` set, so the
        solvers remove the errors-in-variables bias as they do for the blocks' probe. A pixel with any
        channel at the white level in any frame is left out, as on the block path.
    """
    frames = [ambient, *led_frames]
    if len(noise) != len(frames):
        raise SpectralDataError(f"all-pixel statistics: {len(noise)} noise lines for {len(frames)} frames")
    if any(frame.shape != ambient.shape for frame in frames):
        raise SpectralDataError("all-pixel statistics: frames differ in shape; expected frames of one size")
    samples = [frame.reshape(frame.shape[0] * frame.shape[1], -1) for frame in frames]
    levels = neighbour_levels(ambient, cfa_period).reshape(samples[0].shape) if weighting else None
    n_pixels, channels = samples[0].shape
    n_led = len(led_frames)
    black, white = spec.black_level, spec.white_level
    moments = np.zeros((n_led + 2, n_led + 2))
    valid_samples = 0
    for start in range(0, n_pixels, chunk_pixels):
        stop = min(start + chunk_pixels, n_pixels)
        rows = np.empty((n_led + 2, stop - start, channels))
        for j in range(n_led):
            rows[j] = samples[j + 1][start:stop]
        rows[n_led] = samples[0][start:stop]
        rows[n_led + 1] = 1.0
        saturated: np.ndarray = np.any(rows[: n_led + 1] >= white, axis=(0, 2))
        valid = np.broadcast_to(~saturated[:, None], (stop - start, channels))
        line = noise[0]
        if levels is not None:
            weights = 1.0 / np.maximum(line.gain * np.maximum(levels[start:stop] - black, 0.0) + line.read, 1e-12)
        else:
            weights = np.ones(rows.shape[1:])
        weights[~valid] = 0.0
        flat = rows.reshape(n_led + 2, -1)
        moments += (flat * weights.reshape(-1)) @ flat.T
        valid_samples += int(np.count_nonzero(valid))
    if valid_samples == 0:
        raise SpectralDataError("all-pixel statistics: every pixel is saturated; expected unsaturated pixels")
    moments *= valid_samples / moments[-1, -1]  # mean weight 1 over the valid samples
    total_weight = moments[-1, -1]
    order = [*noise[1:], noise[0]]  # the rows' order: LED frames, then the ambient
    noise_moments = np.zeros_like(moments)
    for row, line in enumerate(order):
        noise_moments[row, row] = line.gain * (moments[row, -1] - black * total_weight) + line.read * total_weight
    return statistics_from_moments(
        moments,
        spec,
        n_pixels * channels,
        noise_moments=noise_moments,
        n_samples=valid_samples,
        weighted=weighting,
    )


def neighbour_levels(frame: np.ndarray, cfa_period: int = 1) -> np.ndarray:
    """Each pixel's level as the mean of its left and right neighbours of the same colour (one at the edges).

    The weights must not depend on the pixel's own noise: a weight ``1 / var(A)`` taken at the noisy
    value ``A`` correlates with that noise, and the moments' noise term ``Σ w n²`` then differs from
    ``Σ w var`` by about twice the noise's share — a bias of several σ when every pixel is a sample.
    Neighbours see the same surface (up to texture and edges, which only make the weights less exact).

    Examples
    --------
    >>> neighbour_levels(np.array([[1.0, 2.0, 4.0, 8.0]])).tolist()
    [[2.0, 2.5, 5.0, 4.0]]
    """
    values = np.asarray(frame, dtype=float)
    step = cfa_period
    if values.shape[1] <= step:
        return values.copy()
    out = np.empty_like(values)
    out[:, step:-step] = 0.5 * (values[:, : -2 * step] + values[:, 2 * step :])
    out[:, :step] = values[:, step : 2 * step]
    out[:, -step:] = values[:, -2 * step : -step]
    return out


@dataclass(frozen=True)
class Agreement:
    """How far one estimate lies from a reference, in units of the reference's bands."""

    worst_z: float
    """Largest ``|spectrum − reference| / reference σ`` over the wavelengths, σ the reference's pixel-noise band."""
    within_2sigma: float
    """Share of wavelengths where the estimate lies within the reference's ±2σ pixel-noise band."""
    band_ratio: float
    """Median over the wavelengths of the estimate's pixel-noise σ ÷ the reference's (the bands agree when ≈ 1)."""
    worst_z_full: float
    """As :attr:`worst_z`, σ the reference's whole band (:attr:`AmbientEstimate.spectrum_std`: pixel noise and,
    once added, the LED model's error — the band ``msflash estimate`` reports)."""


def agreement(estimate: AmbientEstimate, reference: AmbientEstimate) -> Agreement:
    """The :class:`Agreement` of ``estimate`` with ``reference`` (same LEDs, same units: no normalisation).

    Wavelengths where the reference's band is zero (no LED emits there, so both spectra are zero) are
    left out.

    Examples
    --------
    >>> from msflash.processing.spectra import Spectra, WavelengthGrid
    >>> grid = WavelengthGrid(400, 700, 100)
    >>> def made(values, std):
    ...     spectrum = Spectra(grid, np.array(values, float), ("x",), unit="photons")
    ...     return AmbientEstimate(spectrum, np.ones(1), "lstsq", 0.0, 0.0, 0.0, 1.0, np.array(std, float), 10, 0.0)
    >>> agreed = agreement(made([1, 2, 3, 4], [0.1] * 4), made([1.05, 2.3, 3, 4], [0.1] * 4))
    >>> round(agreed.worst_z, 6), agreed.within_2sigma, agreed.band_ratio
    (3.0, 0.75, 1.0)
    """
    reference_noise = reference.noise_std if reference.noise_std is not None else reference.spectrum_std
    own_noise = estimate.noise_std if estimate.noise_std is not None else estimate.spectrum_std
    used = reference_noise > 1e-9 * max(float(reference_noise.max()), 1e-300)
    if not used.any():
        raise SpectralDataError("agreement: the reference's band is zero everywhere; expected a band")
    difference = np.abs(estimate.spectrum.values[:, 0] - reference.spectrum.values[:, 0])[used]
    z = difference / reference_noise[used]
    full = np.maximum(reference.spectrum_std[used], reference_noise[used])
    return Agreement(
        float(z.max()),
        float(np.mean(z <= 2.0)),
        float(np.median(own_noise[used] / reference_noise[used])),
        float((difference / full).max()),
    )
