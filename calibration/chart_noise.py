"""How noisy a chart measured with the spectrometer is (``msflash calibrate chart``).

The camera fit takes the chart's reflectances as exact: noise in them is error in the
responsivities (how much: ``docs/measurements.md``). So ``calibrate chart`` measures the noise of
what it stores and warns when it is large.

Estimate: per export, the noise of one instrument pixel from second differences of neighbouring
pixels (``x[i-1] − 2x[i] + x[i+1]`` has variance 6σ² for white noise; a smooth spectrum's
curvature is negligible at a CCD's sub-nm pitch), robustly (1.4826 × the median absolute value)
within a grid step either side of each grid wavelength, since shot noise grows with the signal; the value msflash keeps at a grid
wavelength is the 1-nm bin there, so its noise is σ/√n of the pixels in that bin. A patch's relative reflectance noise at a
wavelength is ``√((σ_p/s_p)² + (σ_w/s_w)²)``, patch and white. Noise correlated between
neighbouring pixels (an export smoothed with a boxcar) is understated.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from msflash.calibration.spectrometer import SpectrometerMeasurement
from msflash.processing.spectra import WavelengthGrid

NOISE_WARNING = 0.005
"""Relative reflectance noise (RMS over the grid and the patches) above which ``calibrate chart`` warns."""


def relative_noise_on_grid(measurement: SpectrometerMeasurement, grid: WavelengthGrid) -> np.ndarray:
    """σ of the export's value at each grid wavelength divided by that value, shape (grid.size,); NaN where unknown.

    A non-uniform export's value at a grid wavelength is its 1-nm bin there
    (:meth:`processing.spectra.Spectra.from_samples`, then :meth:`~processing.spectra.Spectra.resample`),
    the mean of the pixels within ±0.5 nm: σ_pixel/√n of them (σ_pixel measured over a grid step either side).

    >>> import numpy as np
    >>> from msflash.calibration.spectrometer import SpectrometerMeasurement
    >>> from msflash.processing.spectra import WavelengthGrid
    >>> rng = np.random.default_rng(0)
    >>> w = np.arange(390.0, 711.0, 0.25)
    >>> m = SpectrometerMeasurement(w, 1000.0 + rng.normal(0.0, 10.0, w.size), "energy", "x", "x")
    >>> noise = relative_noise_on_grid(m, WavelengthGrid(400.0, 700.0, 10.0))
    >>> ratio = noise / (10.0 / 1000.0 / np.sqrt(5))  # 5 pixels within ±0.5 nm
    >>> bool(abs(np.median(ratio) - 1) < 0.1 and np.all(np.abs(ratio - 1) < 0.5))
    True
    """
    wavelengths, values = measurement.wavelengths_nm, measurement.values
    second = np.full(values.size, np.nan)
    second[1:-1] = values[:-2] - 2.0 * values[1:-1] + values[2:]
    half = grid.step_nm  # σ from the pixels within a step either side (it varies slowly, with the signal)
    out = np.full(grid.size, np.nan)
    for index, centre in enumerate(grid.wavelengths_nm):
        around = (wavelengths >= centre - half) & (wavelengths < centre + half)
        in_bin = max(int(np.count_nonzero(np.abs(wavelengths - centre) <= 0.5)), 1)
        differences = second[around]
        differences = differences[np.isfinite(differences)]
        level = float(np.mean(values[around])) if np.any(around) else 0.0
        if differences.size < 5 or not level > 0:
            continue
        sigma = 1.4826 * float(np.median(np.abs(differences))) / np.sqrt(6.0)
        out[index] = sigma / np.sqrt(in_bin) / level
    return out


def chart_noise(
    patches: Sequence[SpectrometerMeasurement], white: SpectrometerMeasurement, grid: WavelengthGrid
) -> np.ndarray:
    """Relative noise of each measured reflectance, shape (grid.size, patches); NaN where unknown."""
    reference = relative_noise_on_grid(white, grid)
    return np.column_stack([np.hypot(relative_noise_on_grid(p, grid), reference) for p in patches])


def noise_summary(noise: np.ndarray, names: Sequence[str], grid: WavelengthGrid) -> dict | None:
    """What the calibration records and the warning needs: RMS overall, per patch, the worst place.

    None when nothing could be estimated (exports too coarse to see their own noise: a few samples
    per grid step).
    """
    if not np.any(np.isfinite(noise)):
        return None
    finite = np.where(np.isfinite(noise), noise, np.nan)
    counts = np.sum(np.isfinite(finite), axis=0)
    per_patch = np.sqrt(np.where(counts > 0, np.nansum(finite**2, axis=0) / np.maximum(counts, 1), np.nan))
    worst = int(np.nanargmax(np.where(np.isfinite(per_patch), per_patch, -1.0)))
    column = np.where(np.isfinite(finite[:, worst]), finite[:, worst], -1.0)
    at = int(np.argmax(column))
    return {
        "relative_rms": float(np.sqrt(np.nanmean(finite**2))),
        "per_patch_rms": {
            name: float(value) if np.isfinite(value) else None for name, value in zip(names, per_patch, strict=True)
        },
        "worst_patch": names[worst],
        "worst_nm": float(grid.wavelengths_nm[at]),
        "worst_value": float(column[at]),
    }
