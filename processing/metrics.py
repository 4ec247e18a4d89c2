"""Accuracy metrics of the paper's evaluation (Table 1)."""

from __future__ import annotations

import numpy as np

from processing.errors import SpectralDataError


def spectrum_rmse(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Spectrum RMSE as in the paper's Table 1.

    The estimate is max-normalised, the true spectrum least-squares scaled onto it, and the RMSE
    taken over wavelengths.

    Examples
    --------
    >>> spectrum_rmse(np.array([1.0, 2.0]), np.array([2.0, 4.0]))
    0.0
    """
    estimate = np.asarray(estimate, dtype=float)
    truth = np.asarray(truth, dtype=float)
    if estimate.shape != truth.shape or estimate.ndim != 1:
        raise SpectralDataError(f"spectrum RMSE: shapes {estimate.shape} and {truth.shape}; expected two equal 1-D spectra")
    peak = np.max(np.abs(estimate))
    if peak == 0 or not np.any(truth):
        raise SpectralDataError("spectrum RMSE: an all-zero spectrum; expected light")
    normalised = estimate / peak
    scale = float(normalised @ truth) / float(truth @ truth)
    return float(np.sqrt(np.mean((normalised - scale * truth) ** 2)))
