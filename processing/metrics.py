"""Accuracy metrics of the paper's evaluation (Table 1)."""

from __future__ import annotations

import numpy as np

from msflash.processing.errors import SpectralDataError


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
        raise SpectralDataError(
            f"spectrum RMSE: shapes {estimate.shape} and {truth.shape}; expected two equal 1-D spectra"
        )
    peak = np.max(np.abs(estimate))
    if peak == 0 or not np.any(truth):
        raise SpectralDataError("spectrum RMSE: an all-zero spectrum; expected light")
    normalised = estimate / peak
    scale = float(normalised @ truth) / float(truth @ truth)
    return float(np.sqrt(np.mean((normalised - scale * truth) ** 2)))


def led_fit(led_spectra: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """The best non-negative fit ``I w``, ``w = argmin ‖truth − I w‖, w ≥ 0``, of a spectrum by the LED spectra.

    The closest spectrum the LEDs can make: an estimate built from them cannot be expected to be
    closer to the truth.

    ``led_spectra`` (n_wavelengths, k) is in the unit of ``truth`` (n_wavelengths,).

    Examples
    --------
    >>> led_fit(np.eye(2), np.array([1.0, -1.0])).tolist()
    [1.0, 0.0]
    """
    from scipy.optimize import nnls

    led_spectra = np.asarray(led_spectra, dtype=float)
    truth = np.asarray(truth, dtype=float)
    if led_spectra.ndim != 2 or truth.ndim != 1 or led_spectra.shape[0] != truth.shape[0]:
        raise SpectralDataError(
            f"LED fit: LED spectra of shape {led_spectra.shape} and a truth of shape "
            f"{truth.shape}; expected (n, k) and (n,)"
        )
    weights, _ = nnls(led_spectra, truth)
    return led_spectra @ weights


def led_fit_rmse(led_spectra: np.ndarray, truth: np.ndarray) -> float:
    """Spectrum RMSE (:func:`spectrum_rmse`) of :func:`led_fit`: what the LEDs allow.

    Not a strict floor under this metric (the estimate is max-normalised and the truth scaled onto
    it; the fit minimises ‖truth − I w‖): a smoothed estimate may score a little lower.

    Raises
    ------
    SpectralDataError
        If the shapes differ, or the LEDs can make none of the truth.

    Examples
    --------
    >>> led_fit_rmse(np.eye(3), np.array([1.0, 2.0, 3.0]))
    0.0
    """
    fit = led_fit(led_spectra, truth)
    if not np.any(fit):
        raise SpectralDataError(
            "LED fit RMSE: the LEDs cannot make any of the true spectrum; expected LEDs within its range"
        )
    return spectrum_rmse(fit, truth)
